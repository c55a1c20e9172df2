"""Learned policies behind the simulator's controller interface: ``policy(env) -> actions [N, 2] m/s``.

- :mod:`.lpac`: :class:`LPACPolicy`, LPAC-K3 (one forward pass).
- :mod:`.madp`: :class:`MADPPolicy`, MADP with a sampler (:class:`SamplingSettings`), decentralized or
  centralized-masked.
- :mod:`.checkpoint`: reading ``policy.safetensors`` files (:func:`load`) and the checkpoints shipped
  with madp in ``madp/checkpoints/`` (:func:`shipped_checkpoint`).
- :mod:`.select`: MADP's choice among K samples per robot (numpy and numba only).

Controllers are built by name in :mod:`madp.controllers`. The names below load on first use, so
importing a torch-free submodule (:mod:`.select`, which the robot runtime :mod:`madp.robot` uses)
does not import torch.
"""

from importlib import import_module

_WHERE = {"SHIPPED": "checkpoint", "load": "checkpoint", "load_policy": "checkpoint",
          "shipped_checkpoint": "checkpoint", "LPACPolicy": "lpac", "MADPPolicy": "madp",
          "SamplingSettings": "madp", "noise_generator": "madp"}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
