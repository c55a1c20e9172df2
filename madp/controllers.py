"""Every controller by name: the one registry of controllers, and how each is built behind one
interface, ``controller(env: CoverageEnv) -> actions [N, 2] m/s``.

=================  ==================================================================
``clairvoyant``    the expert: Lloyd's step on the full world map (:class:`madp.sim.ClairvoyantCVT`)
``dcvt``           decentralized CVT on each robot's own map (:class:`madp.sim.DecentralizedCVT`)
``lpac``           LPAC-K3 (:class:`madp.policies.lpac.LPACPolicy`)
``madp``           MADP, each robot sampling from its own neighbourhood (decentralized)
``madp_central``   MADP, one masked pass over the whole swarm (centralized)
=================  ==================================================================

:data:`CONTROLLERS` is the only list of them: their order in tables and legends, the checkpoint a
learned one needs, its display name and colour, and which settings it takes all come from here.
``madp rollout``, ``madp eval``, relabelling datagen and the environments in :mod:`madp.envs` build
controllers with :func:`make_controller`. Learned controllers take a checkpoint (default: the one
shipped with madp), loaded once per process; MADP's sampling noise is seeded by ``seed`` (``madp
eval`` uses the scenario's seed, so passing ``scenario.seed`` reproduces its rollouts).

**Named controllers.** Several checkpoints of one learned controller can run side by side: ``madp:r4``
is the controller ``madp`` with a checkpoint of its own, named ``r4`` (``KIND:NAME``, :data:`NAME_SEP`;
KIND one of :data:`LEARNED`, NAME letters, digits, ``_`` and ``-``, first a letter or digit). The name is
the controller's name everywhere (tables' ``controller`` column, legends, recordings); its display
name is the registry's with ``:NAME`` (``MADP:r4``); in file names the ``:`` becomes ``@``
(:func:`file_stem`: ``uniform-000-madp@r4.npz``). :func:`parse_controllers` reads ``madp eval
--controllers dcvt,madp,madp:r4=PATH``. A plain ``madp`` keeps its own checkpoint (``--madp``, or the
shipped one).

Importing this module is cheap (no simulator, no torch): the command line reads the names from it.
"""

from __future__ import annotations

import re
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
    ``display``: its name in tables and plot legends; ``description``: its name in prose (the reports'
    results); ``color``: its colour in plots. ``paper``: the controller of the paper whose numbers it
    is compared with, or None. ``mode``: MADP's execution (``"decentralized"`` /
    ``"centralized"``). ``default``: evaluated when ``madp eval`` is not given ``--controllers``.
    ``factory``: ``"module:Class"`` that builds it. ``oracle``: it sees what a deployed swarm cannot (the
    clairvoyant expert's whole map): shown in every table, never counted as a city's best controller.
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
    oracle: bool = False

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
                   "madp.sim.controllers:ClairvoyantCVT", oracle=True),
    ControllerInfo("dcvt", CLASSICAL_KIND, "DCVT", "DCVT", "#1f77b4", "dcvt", "madp.sim.controllers:DecentralizedCVT"),
    ControllerInfo("lpac", "lpac", "LPAC-K3", "LPAC-K3", "#ff7f0e", "lpac", "madp.policies.lpac:LPACPolicy"),
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
#: The controllers MADP is compared with in the paper (the ``scale`` suite's improvement matrices).
BASELINES: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.paper and not c.samples)
#: The controllers that sample (MADP, decentralized and centralized-masked).
SAMPLING: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.samples)
#: The oracles (the clairvoyant expert): shown beside the others, never counted as best.
ORACLES: tuple[str, ...] = tuple(n for n, c in CONTROLLERS.items() if c.oracle)
#: The checkpoint kinds, in registry order.
CHECKPOINT_KINDS: tuple[str, ...] = tuple(dict.fromkeys(CONTROLLERS[n].kind for n in LEARNED))

#: Separates a learned controller from the name of its own checkpoint: ``madp:r4``.
NAME_SEP = ":"
#: What a checkpoint's name may hold (it becomes part of file names).
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,39}")

_models: dict = {}


def split_name(name: str) -> tuple[str, str | None]:
    """``("madp", "r4")`` for the named controller ``madp:r4``; ``(name, None)`` for any other name."""
    base, sep, label = name.partition(NAME_SEP)
    return (base, label) if sep else (name, None)


def controller_info(name: str) -> ControllerInfo:
    """The registry's entry of ``name`` (of a named controller ``madp:r4``: its controller's,
    ``madp``); a one-line error naming the choices for any other name."""
    base, label = split_name(name)
    if base not in CONTROLLERS:
        extra = f" (a named one is KIND{NAME_SEP}NAME, KIND one of {', '.join(LEARNED)})" if label is not None else ""
        raise SettingError("controller", f"expected one of {', '.join(NAMES)}{extra}, got {name!r}")
    info = CONTROLLERS[base]
    if label is not None:
        if not info.learned:
            raise SettingError("controller", f"{name!r}: only a learned controller ({', '.join(LEARNED)}) has named "
                                             f"checkpoints; {base} takes none")
        if not _NAME.fullmatch(label):
            raise SettingError("controller", f"{name!r}: expected a checkpoint name of letters, digits, _ and - "
                                             f"(first a letter or digit, at most 40) after {base}{NAME_SEP}")
    return info


def is_named(name: str) -> bool:
    """Whether ``name`` is a named controller (``madp:r4``), which brings a checkpoint of its own."""
    return split_name(name)[1] is not None


def display_name(name: str) -> str:
    """The name of a controller in tables and plot legends: the registry's (``MADP``), with ``:NAME`` for
    a named one (``MADP:r4``); a name not in the registry as it is."""
    base, label = split_name(name)
    if base not in CONTROLLERS:
        return name
    return CONTROLLERS[base].display + (f"{NAME_SEP}{label}" if label is not None else "")


def file_stem(name: str) -> str:
    """A controller's name in file names (job files, recordings, videos): ``madp@r4`` for ``madp:r4``
    (a ``:`` is not allowed in Windows file names or CI artifacts); a registry name as it is."""
    return name.replace(NAME_SEP, "@")


def parse_controllers(text: str) -> tuple[tuple[str, ...], dict[str, str]]:
    """``madp eval --controllers``: comma-separated names, a named controller with its checkpoint as
    ``KIND:NAME=PATH`` (``dcvt,madp,madp:r4=runs/r4/policy.safetensors``). Returns the names in the
    order given and ``{named controller: checkpoint path}``. One-line errors (setting ``controllers``)
    for an empty list, an unknown controller, a bad or duplicate name, a name without ``=PATH`` and a
    path given to a controller that is not named; whether the file is a checkpoint is checked on loading."""
    names: list[str] = []
    paths: dict[str, str] = {}
    for item in (t.strip() for t in text.split(",")):
        if not item:
            raise SettingError("controllers", f"expected comma-separated controller names, got {text!r}")
        name, sep, path = (x.strip() for x in item.partition("="))
        try:
            info = controller_info(name)
        except SettingError as e:
            raise SettingError("controllers", str(e).partition(": ")[2]) from None
        if sep and not info.learned:
            raise SettingError("controllers", f"{item!r}: {name} takes no checkpoint")
        if sep and not is_named(name):
            raise SettingError("controllers", f"{item!r}: a checkpoint path goes with a named controller, "
                                              f"{name}{NAME_SEP}NAME=PATH (or --{info.kind} PATH for the plain {name})")
        if is_named(name) and not (sep and path):
            raise SettingError("controllers", f"{item!r}: expected {name}=PATH, the checkpoint of {name}")
        if name in names:
            raise SettingError("controllers", f"{name!r} is given twice")
        names.append(name)
        if sep:
            paths[name] = path
    return tuple(names), paths


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
    """The model of a checkpoint on ``device``, loaded once per process and device (and again when the
    file at ``path`` is replaced: its size and modification time are part of the key)."""
    import os

    from madp.policies import load

    try:
        st = os.stat(path)
        stamp = (st.st_size, st.st_mtime_ns)
    except OSError:
        stamp = None  # load() names the missing file
    key = (kind, str(path), str(device), stamp)
    if key not in _models:
        _models[key] = load(path, kind, device)[0]
    return _models[key]


def _factory(info: ControllerInfo):
    module, _, attr = info.factory.partition(":")
    return getattr(import_module(module), attr)


def make_controller(name: str, checkpoint: str | None = None, *, seed: int = 0, sampling=None,
                    device: str = "cpu"):
    """Build controller ``name`` (one of :data:`NAMES`, or a named one, ``madp:r4``, with its ``checkpoint``).

    ``checkpoint``: a learned controller's policy file (default: the shipped one); ``seed``: MADP's
    sampling noise; ``sampling``: MADP's :class:`madp.policies.SamplingSettings` (default: the
    evaluation default); a rule whose learned network the file lacks runs its fallback
    (:meth:`madp.policies.SamplingSettings.fitted`), one without is refused."""
    info = controller_info(name)
    if is_named(name) and checkpoint is None:
        raise SettingError("checkpoint", f"controller {name} is a named checkpoint; expected its path")
    build = _factory(info)
    if not info.learned:
        return build()
    path = resolve_checkpoint(name, checkpoint)
    model = load_model(info.kind, path, device)
    if not info.samples:
        return build(model, device)
    from madp.policies import SamplingSettings
    from madp.selection import RULES

    sampling = sampling or SamplingSettings()
    needs = RULES[sampling.select].needs
    if needs:
        from madp.policies.checkpoint import load_learned
        from madp.selection import NEEDS

        network = load_learned(path, needs, device)
        if network is None and not RULES[sampling.select].fallback:  # with one, the policy runs its fallback
            raise SettingError("select", f"{sampling.select} reads a learned {needs}, and {path} carries none "
                                         f"({NEEDS[needs].made_by} adds one)")
        return build(model, info.mode, sampling, seed=seed, device=device, network=network)
    return build(model, info.mode, sampling, seed=seed, device=device)
