"""Reading policy files: ``policy.safetensors`` (weights + metadata) into a model, without executing
code, and the checkpoints shipped with madp (``madp/checkpoints/``).

A policy file is self-describing: its metadata holds the kind (``madp`` / ``lpac``), the model config,
the action statistics, the dataset and the step, so acting needs nothing else. Loading never trusts
a file: a truncated, empty or garbled file, metadata of another kind, or weights of another model is
a one-line :class:`madp.errors.InputError` naming the file. Writing checkpoints is training's job; training reads
policy files through this module, never the reverse.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import load_file
from torch import nn

from madp.errors import InputError
from madp.models import MADP, LPACConfig, MADPConfig
from madp.selection import NEEDS

from .parts import read_parts

SHIPPED = {"madp": "madp-cpu.safetensors", "lpac": "lpac-cpu.safetensors"}
#: The learned networks a policy file may carry beside the policy, by what a selection rule needs
#: (:data:`madp.selection.NEEDS`): each one's weight names start with its key plus ".", its config is
#: the metadata key, how it was trained the key plus "_training".
LEARNED = {name: n.key for name, n in NEEDS.items()}
#: Names of the weights of a policy file's map prior (the ``value`` rules' network) start with this.
MAP_PRIOR_PREFIX = f"{LEARNED['map prior']}."


def shipped_checkpoint(kind: str) -> Path | None:
    """Path of the checkpoint that ships with the package, or None if this install has none."""
    p = Path(str(resources.files("madp") / "checkpoints" / SHIPPED[kind]))
    return p if p.is_file() else None


def load(path: str | Path, expect: str, device: str = "cpu"):
    """Load a policy checkpoint and check its kind; one-line errors for missing/incompatible files."""
    model, meta = load_policy(path, device)
    torch.set_flush_denormal(True)  # subnormal weights (training flushes them too) would slow every step
    if meta["kind"] != expect:
        raise InputError(f"{path}: is a {meta['kind']} checkpoint, expected {expect}")
    return model, meta


def load_policy(path: str | Path, device: str | torch.device = "cpu") -> tuple[nn.Module, dict]:
    """Build the model a policy file describes and load its weights. Returns (model in eval mode, meta).

    ``path`` may also name a checkpoint split into float16 parts (:mod:`madp.policies.parts`: its
    index or a part); weights of any float dtype load into the float32 model."""
    path = Path(path)
    joined = read_parts(path, device)  # a checkpoint split into float16 parts (index or a part), else None
    if joined is not None:
        metadata, state = joined
    else:
        metadata, state = read_metadata(path), read_weights(path, device)
    kind = metadata.get("kind")
    if kind not in ("madp", "lpac") or "config" not in metadata:
        raise InputError(f"{path}: not a madp policy checkpoint (metadata 'kind' is {kind!r})")
    try:
        config = json.loads(metadata["config"])
        if kind == "madp":
            model = MADP(MADPConfig.from_dict(config))
        else:
            from madp.models.lpac import LPAC  # torch_geometric: seconds to import, so only when needed

            model = LPAC(LPACConfig.from_dict(config))
        meta = {k: json.loads(v) for k, v in metadata.items() if k not in ("kind", "config")}
    except (ValueError, TypeError, KeyError, AttributeError) as e:
        raise InputError(f"{path}: malformed checkpoint metadata ({type(e).__name__})") from None
    state = {k: v for k, v in state.items() if not k.startswith(tuple(f"{key}." for key in LEARNED.values()))}
    for key in LEARNED.values():  # load_learned's
        meta.pop(key, None)
    load_weights(model, state, path, f"the {kind} config it carries")
    meta["kind"], meta["config"] = kind, model.config.to_dict()  # today's names, whatever the file's age
    return model.to(device).eval(), meta


def load_map_prior(path: str | Path, device: str | torch.device = "cpu"):
    """The map prior a MADP policy file carries (:class:`madp.models.map_prior.MapPrior`, in eval
    mode), or None when it carries none; one-line errors for a damaged file or prior."""
    from madp.models.map_prior import MapPrior, MapPriorConfig

    path = Path(path)
    text = read_metadata(path).get("map_prior")
    if text is None:
        return None
    try:
        net = MapPrior(MapPriorConfig.from_dict(json.loads(text)))
    except (ValueError, TypeError, KeyError) as e:
        raise InputError(f"{path}: malformed map_prior metadata ({type(e).__name__})") from None
    state = {k[len(MAP_PRIOR_PREFIX):]: v for k, v in read_weights(path, device).items() if k.startswith(MAP_PRIOR_PREFIX)}
    if not all(torch.isfinite(v).all() for v in state.values()):
        raise InputError(f"{path}: the map prior's weights hold NaN or infinity")
    load_weights(net, state, path, "the map prior its metadata describes")
    return net.to(device).eval()


def carried(path: str | Path) -> tuple[str, ...]:
    """The learned networks (keys of :data:`LEARNED`) the policy file ``path`` carries beside its policy,
    by its metadata; one-line errors for a missing or unreadable file."""
    joined = read_parts(path)  # a checkpoint split into float16 parts (index or a part), else None
    metadata = joined[0] if joined is not None else read_metadata(Path(path))
    return tuple(name for name, key in LEARNED.items() if key in metadata)


def load_learned(path: str | Path, needs: str, device: str | torch.device = "cpu"):
    """The learned network ``needs`` (a key of :data:`LEARNED`) that the policy file ``path`` carries:
    its map prior (:func:`load_map_prior`) or its critic (:func:`madp.models.critic.load_critic`), in eval
    mode; None when it carries none."""
    if needs not in carried(path):
        return None
    if needs == "map prior":
        return load_map_prior(path, device)
    from madp.models.critic import load_critic

    net = load_critic(path, required=False)
    return None if net is None else net.to(device)


def attach(policy: Path, out: Path, needs: str, net: nn.Module, config: dict, record: dict) -> None:
    """``policy``'s tensors and metadata with the learned network ``net`` (``needs``, a key of
    :data:`LEARNED`; its ``config`` and how it was trained, ``record``) added in place of any it carried,
    written to ``out`` under a temporary name."""
    from safetensors.torch import save_file

    from madp.io.atomic import atomic_path

    key = LEARNED[needs]
    with safe_open(str(policy), framework="pt") as f:
        metadata = dict(f.metadata() or {})
        tensors = {k: f.get_tensor(k) for k in f.keys() if not k.startswith(f"{key}.")}
    tensors.update({f"{key}.{k}": v.detach().cpu().contiguous() for k, v in net.state_dict().items()})
    metadata[key] = json.dumps(config)
    metadata[f"{key}_training"] = json.dumps(record)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(Path(out), ".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata=metadata)


def read_metadata(path: Path) -> dict[str, str]:
    """The metadata of the safetensors file ``path``; one-line errors for a missing or unreadable file."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        with safe_open(str(path), framework="pt") as f:
            return dict(f.metadata() or {})
    except Exception as e:  # safetensors raises its own error types for truncated/garbled files
        raise InputError(f"{path}: not a readable safetensors checkpoint ({type(e).__name__})") from None


def read_weights(path: Path, device: str | torch.device = "cpu") -> dict:
    """The tensors of a safetensors file; a one-line ValueError for anything unreadable."""
    try:
        return load_file(str(path), device=str(device))
    except Exception as e:  # truncated, empty or garbled: safetensors' own error types
        raise InputError(f"{path}: not a readable safetensors file ({type(e).__name__}); the checkpoint is damaged") from None


def load_weights(model: nn.Module, state: dict, path: Path, what: str = "this run's model") -> None:
    """Load ``state`` into ``model`` after checking names and shapes; a one-line ValueError otherwise."""
    own = model.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    shape = [k for k in own if k in state and tuple(state[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or shape:
        example = (f"'{shape[0]}' is {list(state[shape[0]].shape)}, expected {list(own[shape[0]].shape)}" if shape
                   else f"'{(missing or unexpected)[0]}' is {'missing' if missing else 'unexpected'}")
        raise InputError(f"{path}: weights of another model, not {what} ({len(missing)} missing, {len(unexpected)} "
                         f"unexpected, {len(shape)} of another shape; e.g. {example})")
    model.load_state_dict(state)
