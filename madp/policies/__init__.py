"""Learned policies behind the simulator's controller interface: ``policy(env) -> actions [N, 2] m/s``.

- :mod:`.lpac`: ``LPACPolicy``, LPAC-K3 (one forward pass). It imports torch_geometric, which takes
  seconds, so it is imported from its module (``from madp.policies.lpac import LPACPolicy``), not
  re-exported here: the commands that never run LPAC-K3 do not pay for it.
- :mod:`.madp`: :class:`MADPPolicy`, MADP with a sampler (:class:`SamplingSettings`), decentralized or
  centralized-masked.
- :mod:`.checkpoint`: reading ``policy.safetensors`` files (:func:`load`) and the checkpoints shipped
  with madp in ``madp/checkpoints/`` (:func:`shipped_checkpoint`).

Controllers are built by name in :mod:`madp.controllers`.
"""

from .checkpoint import SHIPPED, load, load_policy, shipped_checkpoint
from .madp import MADPPolicy, SamplingSettings, noise_generator

__all__ = ["MADPPolicy", "SHIPPED", "SamplingSettings", "load", "load_policy", "noise_generator",
           "shipped_checkpoint"]
