"""Checkpoints that load without executing code.

A checkpoint is a directory, written under a temporary name and renamed into place::

    policy.safetensors   the weights to act with (EMA weights for MADP), with metadata:
                         kind, model config, action statistics, dataset, step — self-describing,
                         so evaluation needs nothing else
    model.safetensors    the raw (non-EMA) weights, for resuming
    state.pt             optimizer, EMA shadow, data position, counters, RNG state: tensors and
                         plain containers only, read with torch.load(weights_only=True)

Loading never trusts a file: a truncated, empty or garbled file, weights of another model, a state
of the wrong structure or a pickle holding anything but tensors and plain containers is a
one-line ``ValueError`` naming the file (and never suggests loading it less safely).
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file
from torch import nn

from madp.io.atomic import temp_path
from madp.models import MADP, LPACConfig, MADPConfig

POLICY_FILE = "policy.safetensors"
#: What ``state.pt`` must hold, with the types its values must have.
STATE_KEYS = {"optimizer": dict, "ema": dict, "step": int, "epoch": int, "batches_done": int,
              "best_val": (int, float), "bad_epochs": int, "torch_rng": torch.Tensor}


def _contiguous(sd: dict) -> dict:
    return {k: v.detach().to("cpu").contiguous() for k, v in sd.items()}


def save_policy(path: Path, model: nn.Module, kind: str, meta: dict) -> None:
    """Write weights + metadata (all JSON-encoded strings) as one safetensors file."""
    config = model.config.to_dict()
    metadata = {"kind": kind, "config": json.dumps(config), **{k: json.dumps(v) for k, v in meta.items()}}
    save_file(_contiguous(model.state_dict()), str(path), metadata=metadata)


def load_policy(path: str | Path, device: str | torch.device = "cpu") -> tuple[nn.Module, dict]:
    """Build the model a policy file describes and load its weights. Returns (model in eval mode, meta).

    ``path`` may also name a checkpoint split into float16 parts (:mod:`madp.policies.parts`: its
    index or a part); weights of any float dtype load into the float32 model."""
    from madp.policies.parts import read_parts

    path = Path(path)
    joined = read_parts(path, device)  # a checkpoint split into float16 parts (index or a part), else None
    if joined is not None:
        metadata, state = joined
    else:
        if not path.is_file():
            raise FileNotFoundError(f"{path}: checkpoint not found")
        try:
            with safe_open(str(path), framework="pt") as f:
                metadata = dict(f.metadata() or {})
        except Exception as e:  # safetensors raises its own error types for truncated/garbled files
            raise ValueError(f"{path}: not a readable safetensors checkpoint ({type(e).__name__})") from None
        state = read_weights(path, device)
    kind = metadata.get("kind")
    if kind not in ("madp", "lpac") or "config" not in metadata:
        raise ValueError(f"{path}: not a madp policy checkpoint (metadata 'kind' is {kind!r})")
    try:
        config = json.loads(metadata["config"])
        if kind == "madp":
            model = MADP(MADPConfig.from_dict(config))
        else:
            from madp.models.lpac import LPAC  # torch_geometric: seconds to import, so only when needed

            model = LPAC(LPACConfig.from_dict(config))
        meta = {k: json.loads(v) for k, v in metadata.items() if k not in ("kind", "config")}
    except (ValueError, TypeError, KeyError, AttributeError) as e:
        raise ValueError(f"{path}: malformed checkpoint metadata ({type(e).__name__})") from None
    load_weights(model, state, path, f"the {kind} config it carries")
    meta["kind"], meta["config"] = kind, config
    return model.to(device).eval(), meta


def read_weights(path: Path, device: str | torch.device = "cpu") -> dict:
    """The tensors of a safetensors file; a one-line ValueError for anything unreadable."""
    try:
        return load_file(str(path), device=str(device))
    except Exception as e:  # truncated, empty or garbled: safetensors' own error types
        raise ValueError(f"{path}: not a readable safetensors file ({type(e).__name__}); the checkpoint is damaged") from None


def load_weights(model: nn.Module, state: dict, path: Path, what: str = "this run's model") -> None:
    """Load ``state`` into ``model`` after checking names and shapes; a one-line ValueError otherwise."""
    own = model.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    shape = [k for k in own if k in state and tuple(state[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or shape:
        example = (f"'{shape[0]}' is {list(state[shape[0]].shape)}, expected {list(own[shape[0]].shape)}" if shape
                   else f"'{(missing or unexpected)[0]}' is {'missing' if missing else 'unexpected'}")
        raise ValueError(f"{path}: weights of another model, not {what} ({len(missing)} missing, {len(unexpected)} "
                         f"unexpected, {len(shape)} of another shape; e.g. {example})")
    model.load_state_dict(state)


def save_checkpoint(directory: Path, model: nn.Module, policy_model: nn.Module, kind: str, meta: dict,
                    state: dict) -> None:
    """Write a checkpoint directory atomically (temporary sibling, then rename over the old one)."""
    directory = Path(directory)
    tmp = temp_path(directory)
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        tmp.mkdir(parents=True)
        save_policy(tmp / POLICY_FILE, policy_model, kind, meta)
        save_file(_contiguous(model.state_dict()), str(tmp / "model.safetensors"))
        torch.save(state, tmp / "state.pt")
        for f in tmp.iterdir():
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
    except Exception as e:  # a full disk: OSError, or torch's/safetensors' own errors
        shutil.rmtree(tmp, ignore_errors=True)
        why = e.strerror if isinstance(e, OSError) and e.strerror else str(e).splitlines()[0][-120:]
        raise OSError(f"{directory}: cannot write the checkpoint ({why}); any earlier checkpoint is intact") from None
    old = directory.with_name(directory.name + ".old")
    if directory.exists():
        if old.exists():
            shutil.rmtree(old)
        directory.rename(old)
    tmp.rename(directory)
    if old.exists():
        shutil.rmtree(old)


def recover_checkpoints(directory: Path) -> None:
    """Undo what a kill during :func:`save_checkpoint` left: a checkpoint moved aside as ``NAME.old``
    whose successor was not yet renamed into place comes back; temporary directories go."""
    directory = Path(directory)
    for ckpt in [p for p in directory.glob("*.old") if p.is_dir()]:
        final = ckpt.with_name(ckpt.name[: -len(".old")])
        if final.exists():
            shutil.rmtree(ckpt)
        else:
            ckpt.rename(final)
    for tmp in directory.glob("*.tmp"):
        if tmp.is_dir():
            shutil.rmtree(tmp)


def read_state(path: Path, device: str | torch.device = "cpu") -> dict:
    """``state.pt`` as a dict of the expected keys and types (tensors and plain containers only)."""
    try:
        state = torch.load(path, map_location=device, weights_only=True)
    except pickle.UnpicklingError:  # an object a checkpoint never holds; torch's message is not shown
        raise ValueError(f"{path}: holds objects other than tensors and plain containers; refused "
                         "(a training state is never executed)") from None
    except Exception as e:  # empty (EOFError), truncated or not a torch.save file at all
        raise ValueError(f"{path}: not a readable training state ({type(e).__name__}); the checkpoint is damaged") from None
    if not isinstance(state, dict):
        raise ValueError(f"{path}: expected a dict of training state, got {type(state).__name__}")
    for key, kind in STATE_KEYS.items():
        if key not in state:
            raise ValueError(f"{path}: training state lacks '{key}'")
        if not isinstance(state[key], kind) or isinstance(state[key], bool):
            raise ValueError(f"{path}: training state '{key}' is a {type(state[key]).__name__}")
    if min(state["step"], state["epoch"], state["batches_done"], state["bad_epochs"]) < 0:
        raise ValueError(f"{path}: training state holds negative counters")
    return state


def load_checkpoint_state(directory: Path, model: nn.Module, device: torch.device) -> dict:
    """Load raw weights into ``model`` and return the training state (weights_only, checked)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: no checkpoint to resume from; run without --resume to start")
    for name in ("model.safetensors", "state.pt"):
        if not (directory / name).is_file():
            raise FileNotFoundError(f"{directory / name}: missing; cannot resume from {directory}")
    load_weights(model, read_weights(directory / "model.safetensors", device), directory / "model.safetensors")
    return read_state(directory / "state.pt", device)
