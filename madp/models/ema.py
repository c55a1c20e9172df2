"""Exponential moving average of a model's parameters (for evaluating diffusion policies).

``decay_t = min(decay, (1 + t) / (10 + t))`` after t updates: early averages forget the random
init quickly, later ones settle to ``decay``. Floating-point parameters are averaged; buffers (e.g.
BatchNorm running statistics, action statistics) are copied from the live model at each update,
so ``copy_to`` yields a self-consistent model.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import torch
from torch import Tensor, nn

__all__ = ["EMA"]


class EMA:
    """Shadow copy of ``model``'s parameters and buffers.

    Usage::

        ema = EMA(model, decay=0.999)
        ...; optimizer.step(); ema.update(model)
        with ema.average_parameters(model):   # temporarily swap in the averaged weights
            evaluate(model)
        torch.save(ema.state_dict(), ...)     # or ema.shadow_state_dict() for a plain model state dict
    """

    def __init__(self, model: nn.Module, decay: float = 0.999, warmup: bool = True):
        if not 0.0 <= decay <= 1.0:
            raise ValueError("decay must be in [0, 1]")
        self.decay = float(decay)
        self.warmup = bool(warmup)
        self.num_updates = 0
        self.shadow: dict[str, Tensor] = {
            name: p.detach().clone() for name, p in model.named_parameters() if p.is_floating_point()
        }
        self.buffers: dict[str, Tensor] = {name: b.detach().clone() for name, b in model.named_buffers()}
        self._backup: dict[str, Tensor] | None = None

    def current_decay(self) -> float:
        if not self.warmup:
            return self.decay
        t = self.num_updates
        return min(self.decay, (1.0 + t) / (10.0 + t))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        """``shadow = d * shadow + (1 - d) * param``; buffers copied."""
        d = self.current_decay()
        params = dict(model.named_parameters())
        names = list(self.shadow)
        shadow = [self.shadow[k] for k in names]
        live = [params[k].detach().to(self.shadow[k].dtype) for k in names]
        torch._foreach_lerp_(shadow, live, 1.0 - d)
        for name, b in model.named_buffers():
            if name in self.buffers:
                self.buffers[name].copy_(b)
        self.num_updates += 1

    @torch.no_grad()
    def copy_to(self, model: nn.Module) -> None:
        """Load the averaged parameters (and tracked buffers) into ``model``."""
        params = dict(model.named_parameters())
        for name, s in self.shadow.items():
            params[name].copy_(s)
        bufs = dict(model.named_buffers())
        for name, b in self.buffers.items():
            bufs[name].copy_(b)

    @torch.no_grad()
    def store(self, model: nn.Module) -> None:
        """Remember the live parameters/buffers (to :meth:`restore` after evaluating with the EMA)."""
        self._backup = {k: v.detach().clone() for k, v in model.state_dict().items()}

    @torch.no_grad()
    def restore(self, model: nn.Module) -> None:
        if self._backup is None:
            raise RuntimeError("restore() without store()")
        model.load_state_dict(self._backup)
        self._backup = None

    @contextmanager
    def average_parameters(self, model: nn.Module) -> Iterator[nn.Module]:
        """Context manager: the model holds the averaged weights inside, its own weights after."""
        self.store(model)
        self.copy_to(model)
        try:
            yield model
        finally:
            self.restore(model)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "EMA":
        for d in (self.shadow, self.buffers):
            for k, v in d.items():
                d[k] = v.to(device=device, dtype=dtype if (dtype is not None and v.is_floating_point()) else v.dtype)
        return self

    def shadow_state_dict(self) -> dict[str, Tensor]:
        """The averaged weights as a plain model state dict (parameters + buffers), e.g. for
        ``safetensors.torch.save_file``."""
        out = {k: v.clone() for k, v in self.shadow.items()}
        out.update({k: v.clone() for k, v in self.buffers.items()})
        return out

    def state_dict(self) -> dict:
        return {"decay": self.decay, "warmup": self.warmup, "num_updates": self.num_updates,
                "shadow": dict(self.shadow), "buffers": dict(self.buffers)}

    def load_state_dict(self, state: dict) -> None:
        self.decay = float(state["decay"])
        self.warmup = bool(state["warmup"])
        self.num_updates = int(state["num_updates"])
        for src, dst in ((state["shadow"], self.shadow), (state["buffers"], self.buffers)):
            missing = set(dst) - set(src)
            if missing:
                raise KeyError(f"EMA state lacks {sorted(missing)}")
            for k in dst:
                dst[k] = src[k].detach().clone().to(device=dst[k].device, dtype=dst[k].dtype)
