"""The optimizer of ``madp train``: AdamW (or Adam) as the preset says, in the implementation
``madp bench train --ablate`` measured fastest."""

from __future__ import annotations

import torch

from .config import TrainConfig

__all__ = ["DEFAULT_OPTIMIZER_IMPL", "make_optimizer"]

#: The optimizer implementation of :func:`make_optimizer` (measured with ``madp bench train``).
DEFAULT_OPTIMIZER_IMPL = "fused"


def make_optimizer(cfg: TrainConfig, params, impl: str = "default") -> torch.optim.Optimizer:
    """AdamW (or Adam, ``cfg.optimizer``) at ``cfg.lr`` and ``cfg.weight_decay``.

    ``impl``: ``loop`` (one parameter at a time: torch's default on CPU), ``foreach`` (one op over
    all parameters per update term) or ``fused`` (one kernel per parameter group); ``default`` is
    the one ``madp train`` uses."""
    if impl == "default":
        impl = DEFAULT_OPTIMIZER_IMPL
    flags = {"loop": dict(foreach=False), "foreach": dict(foreach=True), "fused": dict(fused=True)}
    if impl not in flags:
        raise ValueError(f"optimizer implementation: expected one of {sorted(flags)} or default, got {impl!r}")
    opt_cls = torch.optim.AdamW if cfg.optimizer == "adamw" else torch.optim.Adam
    return opt_cls(params, lr=cfg.lr, weight_decay=cfg.weight_decay, **flags[impl])
