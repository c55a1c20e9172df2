"""Checkpoints that load without executing code.

A checkpoint is a directory, written under a temporary name and renamed into place::

    policy.safetensors   the weights to act with (EMA weights for MADP), with metadata:
                         kind, model config, action statistics, dataset, step — self-describing,
                         so evaluation needs nothing else
    model.safetensors    the raw (non-EMA) weights, for resuming
    state.pt             optimizer, EMA shadow, data position, counters, RNG state: tensors and
                         plain containers only, read with torch.load(weights_only=True)
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file
from torch import nn

from madp.models import LPAC, MADP, LPACConfig, MADPConfig

POLICY_FILE = "policy.safetensors"


def _contiguous(sd: dict) -> dict:
    return {k: v.detach().to("cpu").contiguous() for k, v in sd.items()}


def save_policy(path: Path, model: nn.Module, kind: str, meta: dict) -> None:
    """Write weights + metadata (all JSON-encoded strings) as one safetensors file."""
    config = model.config.to_dict()
    metadata = {"kind": kind, "config": json.dumps(config), **{k: json.dumps(v) for k, v in meta.items()}}
    save_file(_contiguous(model.state_dict()), str(path), metadata=metadata)


def load_policy(path: str | Path, device: str | torch.device = "cpu") -> tuple[nn.Module, dict]:
    """Build the model a policy file describes and load its weights. Returns (model in eval mode, meta)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        with safe_open(str(path), framework="pt") as f:
            metadata = dict(f.metadata() or {})
        state = load_file(str(path), device=str(device))
    except Exception as e:  # safetensors raises its own error types for truncated/garbled files
        raise ValueError(f"{path}: not a readable safetensors checkpoint ({type(e).__name__})") from None
    kind = metadata.get("kind")
    if kind not in ("madp", "lpac") or "config" not in metadata:
        raise ValueError(f"{path}: not a madp policy checkpoint (metadata 'kind' is {kind!r})")
    config = json.loads(metadata["config"])
    model = MADP(MADPConfig.from_dict(config)) if kind == "madp" else LPAC(LPACConfig.from_dict(config))
    try:
        model.load_state_dict(state)
    except RuntimeError as e:
        raise ValueError(f"{path}: weights do not fit the {kind} config it carries ({str(e).splitlines()[0]})") from None
    meta = {k: json.loads(v) for k, v in metadata.items() if k not in ("kind", "config")}
    meta["kind"], meta["config"] = kind, config
    return model.to(device).eval(), meta


def save_checkpoint(directory: Path, model: nn.Module, policy_model: nn.Module, kind: str, meta: dict,
                    state: dict) -> None:
    """Write a checkpoint directory atomically (temporary sibling, then rename over the old one)."""
    directory = Path(directory)
    tmp = directory.with_name(directory.name + ".tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    save_policy(tmp / POLICY_FILE, policy_model, kind, meta)
    save_file(_contiguous(model.state_dict()), str(tmp / "model.safetensors"))
    torch.save(state, tmp / "state.pt")
    for f in tmp.iterdir():
        with open(f, "rb") as fh:
            os.fsync(fh.fileno())
    old = directory.with_name(directory.name + ".old")
    if directory.exists():
        if old.exists():
            shutil.rmtree(old)
        directory.rename(old)
    tmp.rename(directory)
    if old.exists():
        shutil.rmtree(old)


def load_checkpoint_state(directory: Path, model: nn.Module, device: torch.device) -> dict:
    """Load raw weights into ``model`` and return the training state (weights_only)."""
    directory = Path(directory)
    for name in ("model.safetensors", "state.pt"):
        if not (directory / name).is_file():
            raise FileNotFoundError(f"{directory / name}: missing; cannot resume from {directory}")
    model.load_state_dict(load_file(str(directory / "model.safetensors"), device=str(device)))
    return torch.load(directory / "state.pt", map_location=device, weights_only=True)
