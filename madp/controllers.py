"""Every controller by name, behind one interface: ``controller(env: CoverageEnv) -> actions [N, 2] m/s``.

=================  ==================================================================
``clairvoyant``    the expert: Lloyd's step on the full world map (:class:`ClairvoyantCVT`)
``dcvt``           decentralized CVT on each robot's own map (:class:`DecentralizedCVT`)
``lpac``           LPAC-K3 (:class:`madp.policies.LPACPolicy`)
``madp``           MADP, each robot sampling from its own neighbourhood (decentralized)
``madp_central``   MADP, one masked pass over the whole swarm (centralized)
=================  ==================================================================

``madp rollout``, ``madp eval`` and the environments in :mod:`madp.envs` all build controllers
here. Learned controllers take a checkpoint (default: the one shipped with madp); MADP's sampling
noise is seeded by ``seed`` (``madp eval`` uses the scenario's seed, so passing ``scenario.seed``
reproduces its rollouts).
"""

from __future__ import annotations

from madp.models.samplers import DEFAULT_SAMPLER, DEFAULT_SAMPLING_STEPS
from madp.sim import ClairvoyantCVT, Controller, DecentralizedCVT

CLASSICAL = ("clairvoyant", "dcvt")
LEARNED = ("lpac", "madp", "madp_central")
NAMES = CLASSICAL + LEARNED

_models: dict = {}


def checkpoint_kind(name: str) -> str | None:
    """The checkpoint kind a controller needs ("lpac" or "madp"), or None for the classical ones."""
    return None if name in CLASSICAL else ("madp" if name.startswith("madp") else "lpac")


def resolve_checkpoint(name: str, checkpoint: str | None) -> str:
    """``checkpoint`` or the shipped one for ``name``; a one-line error when there is none."""
    from madp.policies import shipped_checkpoint

    kind = checkpoint_kind(name)
    path = checkpoint or shipped_checkpoint(kind)
    if path is None:
        raise ValueError(f"controller {name}: no --checkpoint given and no {kind} checkpoint ships with this install")
    return str(path)


def load_model(kind: str, path: str, device: str = "cpu"):
    """The model of a checkpoint on ``device``, loaded once per process and device."""
    from madp.policies import load

    key = (kind, str(path), str(device))
    if key not in _models:
        _models[key] = load(path, kind, device)[0]
    return _models[key]


def make_controller(name: str, checkpoint: str | None = None, *, seed: int = 0, sampler: str = DEFAULT_SAMPLER,
                    sampling_steps: int = DEFAULT_SAMPLING_STEPS, eta: float = 0.0, fixed_noise: bool = False,
                    device: str = "cpu") -> Controller:
    """Build controller ``name`` (one of :data:`NAMES`); a learned one runs its model on ``device``
    (``"cpu"``, ``"cuda"``, ``"cuda:1"``; :func:`madp.policies.device.resolve_device` checks a user's)."""
    if name not in NAMES:
        raise ValueError(f"--controller: expected one of {', '.join(NAMES)}, got {name!r}")
    if name == "clairvoyant":
        return ClairvoyantCVT()
    if name == "dcvt":
        return DecentralizedCVT()
    from madp.policies import LPACPolicy, MADPPolicy

    model = load_model(checkpoint_kind(name), resolve_checkpoint(name, checkpoint), device)
    if name == "lpac":
        return LPACPolicy(model, device)
    mode = "decentralized" if name == "madp" else "centralized"
    return MADPPolicy(model, mode, sampling_steps, eta, seed=seed, device=device, sampler=sampler,
                      fixed_noise=fixed_noise)
