"""Every controller by name: the one registry of controllers, and how each is built behind one
interface, ``controller(env: CoverageEnv) -> actions [N, 2] m/s``.

=================  ==================================================================
``clairvoyant``    the expert: Lloyd's step on the full world map (:class:`madp.sim.ClairvoyantCVT`)
``dcvt``           decentralized CVT on each robot's own map (:class:`madp.sim.DecentralizedCVT`)
``lpac``           LPAC-K3 (:class:`madp.policies.LPACPolicy`)
``madp``           MADP, each robot sampling from its own neighbourhood (decentralized)
``madp_central``   MADP, one masked pass over the whole swarm (centralized)
=================  ==================================================================

:data:`CONTROLLERS` is the only list of them: their order in tables and legends, the checkpoint a
learned one needs, its display name and colour, and which settings it takes all come from here.
``madp rollout``, ``madp eval``, relabelling datagen and the environments in :mod:`madp.envs` build
controllers with :func:`make_controller`. Learned controllers take a checkpoint (default: the one
shipped with madp), loaded once per process; MADP's sampling noise is seeded by ``seed`` (``madp
eval`` uses the scenario's seed, so passing ``scenario.seed`` reproduces its rollouts).

Importing this module is cheap (no simulator, no torch): the command line reads the names from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module

from madp.errors import SettingError

#: ``kind`` of the controllers that need no checkpoint; a learned controller's kind is the kind of
#: checkpoint it loads (``"lpac"`` or ``"madp"``, :func:`madp.policies.load`).
CLASSICAL_KIND = "classical"


@dataclass(frozen=True)
class ControllerInfo:
    """One controller of the registry.

    ``kind``: :data:`CLASSICAL_KIND`, or the checkpoint kind a learned controller loads.
    ``display``: its name in tables and plot legends; ``description``: its name in prose (the README's
    results); ``color``: its colour in plots. ``paper``: the controller of the paper whose numbers it
    is compared with (SPEC §5), or None. ``mode``: MADP's execution (``"decentralized"`` /
    ``"centralized"``). ``default``: evaluated when ``madp eval`` is not given ``--controllers``.
    ``factory``: ``"module:Class"`` that builds it.
    """

    name: str
    kind: str
    display: str
    description: str
    color: str
    paper: str | None
    factory: str
    mode: str | None = None
    default: bool = True

    @property
    def learned(self) -> bool:
        return self.kind != CLASSICAL_KIND

    @property
    def samples(self) -> bool:
        """Whether it samples (MADP): it then takes sampler settings and draws noise."""
        return self.kind == "madp"

    def settings(self, sampling) -> dict:
        """The settings that name this controller's runs in tables and recordings: the sampler
        settings (:class:`madp.policies.SamplingSettings`) of a controller that samples, else {}."""
        return sampling.as_dict() if self.samples else {}


#: The registry, in the canonical order of every table and legend.
CONTROLLERS: dict[str, ControllerInfo] = {c.name: c for c in (
    ControllerInfo("clairvoyant", CLASSICAL_KIND, "Clairvoyant", "clairvoyant CVT", "#444444", None,
                   "madp.sim.controllers:ClairvoyantCVT"),
    ControllerInfo("dcvt", CLASSICAL_KIND, "DCVT", "DCVT", "#1f77b4", "dcvt", "madp.sim.controllers:DecentralizedCVT"),
    ControllerInfo("lpac", "lpac", "LPAC-K3", "LPAC-K3", "#ff7f0e", "lpac", "madp.policies:LPACPolicy"),
    ControllerInfo("madp", "madp", "MADP", "MADP (decentralized)", "#d62728", "madp", "madp.policies:MADPPolicy",
                   mode="decentralized"),
    ControllerInfo("madp_central", "madp", "MADP (central)", "MADP (centralized-masked)", "#9467bd", "madp",
                   "madp.policies:MADPPolicy", mode="centralized", default=False),
)}
NAMES: tuple[str, ...] = tuple(CONTROLLERS)
CLASSICAL: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if not c.learned)
LEARNED: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.learned)
#: What ``madp eval`` runs without ``--controllers`` (those of them that have a checkpoint).
DEFAULT: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.default)
#: The controllers MADP is compared with in the paper (SPEC §5: the ``scale`` suite's improvement matrices).
BASELINES: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.paper and not c.samples)
#: The controllers that sample (MADP, decentralized and centralized-masked).
SAMPLING: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.samples)
#: The checkpoint kinds, in registry order.
CHECKPOINT_KINDS: tuple[str, ...] = tuple(dict.fromkeys(CONTROLLERS[n].kind for n in LEARNED))

_models: dict = {}


def controller_info(name: str) -> ControllerInfo:
    """The registry's entry of ``name``; a one-line error naming the choices for any other name."""
    if name not in CONTROLLERS:
        raise SettingError("controller", f"expected one of {', '.join(NAMES)}, got {name!r}")
    return CONTROLLERS[name]


def display_name(name: str) -> str:
    """The name of a controller in tables and plot legends (a name not in the registry as it is)."""
    return CONTROLLERS[name].display if name in CONTROLLERS else name


def checkpoint_kind(name: str) -> str | None:
    """The checkpoint kind a controller needs ("lpac" or "madp"), or None for the classical ones."""
    info = controller_info(name)
    return info.kind if info.learned else None


def resolve_checkpoint(name: str, checkpoint: str | None) -> str:
    """``checkpoint`` or the shipped one for ``name``; a one-line error when there is none."""
    from madp.policies import shipped_checkpoint

    kind = checkpoint_kind(name)
    path = checkpoint or shipped_checkpoint(kind)
    if path is None:
        raise SettingError("checkpoint", f"controller {name} needs one, and no {kind} checkpoint ships with this install")
    return str(path)


def load_model(kind: str, path: str, device: str = "cpu"):
    """The model of a checkpoint on ``device``, loaded once per process and device."""
    from madp.policies import load

    key = (kind, str(path), str(device))
    if key not in _models:
        _models[key] = load(path, kind, device)[0]
    return _models[key]


def _factory(info: ControllerInfo):
    module, _, attr = info.factory.partition(":")
    return getattr(import_module(module), attr)


def make_controller(name: str, checkpoint: str | None = None, *, seed: int = 0, sampling=None,
                    device: str = "cpu"):
    """Build controller ``name`` (one of :data:`NAMES`).

    ``checkpoint``: a learned controller's policy file (default: the shipped one); ``seed``: MADP's
    sampling noise; ``sampling``: MADP's :class:`madp.policies.SamplingSettings` (default: the
    measured best sampler)."""
    info = controller_info(name)
    build = _factory(info)
    if not info.learned:
        return build()
    model = load_model(info.kind, resolve_checkpoint(name, checkpoint), device)
    if not info.samples:
        return build(model, device)
    return build(model, info.mode, sampling, seed=seed, device=device)
