"""The device a learned policy runs on, from what a user typed (``--device``)."""

from __future__ import annotations

import torch

from madp.errors import SettingError


def resolve_device(name: str) -> str:
    """``"auto"`` -> ``"cuda"`` when torch sees a CUDA GPU, else ``"cpu"``; ``"cpu"``, ``"cuda"`` and
    ``"cuda:I"`` are checked against this machine. A :class:`madp.errors.SettingError` for anything else."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError):
        raise SettingError("device", f"expected auto, cpu, cuda or cuda:I, got {name!r}") from None
    if dev.type == "cpu" and dev.index is None:
        return "cpu"
    if dev.type != "cuda":
        raise SettingError("device", f"expected auto, cpu, cuda or cuda:I, got {name!r}")
    if not torch.cuda.is_available():
        raise SettingError("device", message=f"device {name}: torch sees no CUDA GPU (torch {torch.__version__}, "
                         f"built with CUDA {torch.version.cuda or 'none'})")
    if dev.index is not None and dev.index >= torch.cuda.device_count():
        raise SettingError("device", message=f"device {name}: this machine has {torch.cuda.device_count()} CUDA GPU(s)")
    return str(dev)
