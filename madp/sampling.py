"""One spec for how MADP samples, wherever a policy is sampled: ``--sampling
sampler=dpm++,steps=3,k=4,rule=explore,frame=d4,precision=fp32`` on ``madp rollout``, ``eval``,
``datagen --policy``, ``export``, ``swarm`` and ``madp-robot``, parsed once here (as ``--network`` is
by :meth:`madp.sim.network.NetworkSettings.parse`). Torch-free: the robot parses it too.

The spec names only what it sets; the rest keeps each command's default. Where a command keeps single
flags for the common cases (``--select``, ``--candidates``, ``--sampling-steps``, ``--sampler``,
``--frame``, ``--precision``), they are the same names everywhere, and a flag that says otherwise than
the spec is a one-line error (:func:`merge_sampling`).

Also here: how MADP runs (:data:`RUNTIMES`) and where its starting noise comes from (:data:`NOISES`),
which every result file records beside the sampling settings.
"""

from __future__ import annotations

from typing import Any, Mapping, Optional

from madp.errors import SettingError

__all__ = ["KEYS", "NOISES", "ONNX_MODULES", "RUNTIMES", "SPEC_EXAMPLE", "merge_sampling", "parse_sampling", "sampling_help",
           "spec_text"]

#: The spec's keys, each with its type and the setting of :class:`madp.policies.SamplingSettings` it sets.
KEYS: dict[str, tuple[type, str]] = {
    "sampler": (str, "sampler"), "steps": (int, "sampling_steps"), "k": (int, "candidates"),
    "rule": (str, "select"), "frame": (str, "frame"), "precision": (str, "precision"), "eta": (float, "eta"),
    "fixed_noise": (bool, "fixed_noise"),
}
#: How decentralized MADP runs: the PyTorch policy, or robot by robot through ``madp export``'s files.
RUNTIMES = ("torch", "onnx")
#: What the ``onnx`` runtime imports (the export and the robot runtime): madp's ``onnx`` extra.
ONNX_MODULES = ("onnx", "onnxruntime", "onnxscript")
#: Where the starting noise of MADP's samples comes from: ``torch``, one generator per environment seeded
#: by its scenario's seed (``madp eval``, ``madp rollout``, ``madp datagen --policy``; ``madp eval --runtime
#: onnx`` draws the same); ``robot``, each robot's own from the episode's seed, the step and its id, as a
#: robot process draws it (``madp rollout --runtime onnx``, ``madp swarm``, ``madp-robot``).
NOISES = ("torch", "robot")
#: An example of the spec, for the help.
SPEC_EXAMPLE = "sampler=dpm++,steps=3,k=4,rule=explore,frame=d4,precision=fp32"
#: The single flags a command may keep, by the setting each sets.
FLAGS = {"select": "--select", "candidates": "--candidates", "sampling_steps": "--sampling-steps",
         "sampler": "--sampler", "frame": "--frame", "precision": "--precision", "eta": "--eta",
         "fixed_noise": "--fixed-noise"}


def _value(key: str, text: str) -> Any:
    kind = KEYS[key][0]
    try:
        if kind is bool:
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError
            return text.lower() in ("true", "1", "yes")
        return kind(text)
    except ValueError:
        raise SettingError("sampling", f"{key}: expected {kind.__name__}, got {text!r}") from None


def parse_sampling(text: Optional[str]) -> dict[str, Any]:
    """``NAME=VALUE`` items, comma-separated, each at most once -> ``{setting: value}`` with the
    settings' names of :class:`madp.policies.SamplingSettings` (``steps`` -> ``sampling_steps``, ``k`` ->
    ``candidates``, ``rule`` -> ``select``); None or "" -> {}. Values are checked where they are used
    (``SamplingSettings``); here their form: a one-line :class:`SettingError` naming ``sampling``."""
    out: dict[str, Any] = {}
    for item in (text or "").split(","):
        item = item.strip()
        if not item:
            continue
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in KEYS:
            raise SettingError("sampling", f"expected NAME=VALUE items with NAME one of {', '.join(KEYS)} "
                                           f"(e.g. {SPEC_EXAMPLE}), got {item!r}")
        setting = KEYS[key][1]
        if setting in out:
            raise SettingError("sampling", f"{key} is given twice")
        out[setting] = _value(key, value.strip())
    return out


def merge_sampling(spec: Optional[str], **flags: Any) -> dict[str, Any]:
    """The settings of ``spec`` (:func:`parse_sampling`) with the single ``flags`` that were given (not
    None, keyed by setting: ``select``, ``candidates``, ``sampling_steps``, ...): a flag and the spec
    that set one setting to different values is a one-line error naming both."""
    out = parse_sampling(spec)
    for setting, value in flags.items():
        if value is None:
            continue
        if setting in out and out[setting] != value:
            key = next(k for k, (_, s) in KEYS.items() if s == setting)
            raise SettingError("sampling", f"{key}={out[setting]} says otherwise than {FLAGS.get(setting, setting)} "
                                           f"{value}; give it once")
        out[setting] = value
    return out


def spec_text(settings: Mapping[str, Any]) -> str:
    """The spec that gives ``settings`` (keyed by setting, as :meth:`SamplingSettings.as_dict`), in
    :data:`KEYS`' order: what a result file or a message names a run's sampling by."""
    items = []
    for key, (kind, setting) in KEYS.items():
        if setting in settings:
            value = settings[setting]
            items.append(f"{key}={str(value).lower() if kind is bool else value}")
    return ",".join(items)


def sampling_help(fixed: str = "") -> str:
    """The help of ``--sampling`` (``fixed``: what the command's export or defaults fix, said after)."""
    return (f"How MADP samples, as NAME=VALUE items: {', '.join(KEYS)}, e.g. {SPEC_EXAMPLE} (rule: as --select; "
            "k: as --candidates; steps: as --sampling-steps); what it leaves out keeps its default, and a single "
            f"flag may not say otherwise.{(' ' + fixed) if fixed else ''}")
