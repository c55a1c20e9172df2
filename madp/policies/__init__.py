"""Learned policies behind the simulator's controller interface: ``policy(env) -> actions [N, 2] m/s``.

- :mod:`.lpac`: :class:`LPACPolicy`, LPAC-K3 (one forward pass).
- :mod:`.madp`: :class:`MADPPolicy`, MADP with a sampler (:class:`SamplingSettings`), decentralized or
  centralized-masked.
- :mod:`.checkpoint`: reading ``policy.safetensors`` files (:func:`load`) and the checkpoints shipped
  with madp in ``madp/checkpoints/`` (:func:`shipped_checkpoint`).

Controllers are built by name in :mod:`madp.controllers`.
"""

from .checkpoint import SHIPPED, load, load_policy, shipped_checkpoint
from .lpac import LPACPolicy
from .madp import MADPPolicy, SamplingSettings, noise_generator

__all__ = ["LPACPolicy", "MADPPolicy", "SHIPPED", "SamplingSettings", "load", "load_policy", "noise_generator",
           "shipped_checkpoint"]
