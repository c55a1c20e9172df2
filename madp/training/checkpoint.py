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
one-line ``ValueError`` naming the file (and never suggests loading it less safely). Reading a
policy file is :mod:`madp.policies.checkpoint` (re-exported here for training's use).
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from pathlib import Path

import torch
from safetensors.torch import save_file
from torch import nn

from madp.errors import InputError
from madp.io.atomic import temp_path
from madp.policies.checkpoint import load_policy, load_weights, read_weights

__all__ = ["POLICY_FILE", "STATE_KEYS", "load_checkpoint_state", "load_policy", "load_weights", "read_state",
           "read_weights", "recover_checkpoints", "save_checkpoint", "save_policy"]

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
        raise InputError(f"{path}: holds objects other than tensors and plain containers; refused "
                         "(a training state is never executed)") from None
    except Exception as e:  # empty (EOFError), truncated or not a torch.save file at all
        raise InputError(f"{path}: not a readable training state ({type(e).__name__}); the checkpoint is damaged") from None
    if not isinstance(state, dict):
        raise InputError(f"{path}: expected a dict of training state, got {type(state).__name__}")
    for key, kind in STATE_KEYS.items():
        if key not in state:
            raise InputError(f"{path}: training state lacks '{key}'")
        if not isinstance(state[key], kind) or isinstance(state[key], bool):
            raise InputError(f"{path}: training state '{key}' is a {type(state[key]).__name__}")
    if min(state["step"], state["epoch"], state["batches_done"], state["bad_epochs"]) < 0:
        raise InputError(f"{path}: training state holds negative counters")
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
