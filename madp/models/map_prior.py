"""A robot's learned prior on the importance it has not sensed: the map the ``value`` selection rule
scores its candidates on (:mod:`madp.policies.select`).

The ``explore`` rule gives every block of a robot's window that its sensor has not covered the mean
importance of the blocks it has. :class:`MapPrior` predicts it instead, from the same window: a small
convolutional network over the window coarsened to cells of :data:`COARSE_M` metres
(``[R, 3, 16, 16]`` for the 256 m window), whose three channels are each cell's sensed importance per
m² over its explored part, its explored fraction and its fraction inside the world
(:func:`prior_inputs`). It returns each cell's importance per m² (``[R, 16, 16]``, ≥ 0).
:func:`prior_weights` adds that prediction to the window's unexplored blocks, as ``explore`` adds
its mean. Trained against the true map (``madp value train``, :mod:`madp.training.map_prior`).

numpy in, numpy out for the rule; the network itself is torch.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor, nn

#: Side (m) of the coarse cells the prior predicts: 4 × 4 of the selection rules' 4 m blocks.
COARSE_M = 16
#: Input channels: sensed importance per m² over the explored part, explored fraction, inside fraction.
PRIOR_CHANNELS = 3


@dataclass(frozen=True)
class MapPriorConfig:
    """The network's width (channels of every hidden layer) and its dilations (one 3 × 3 layer each,
    with a residual connection; the receptive field spans the window at the defaults)."""

    channels: int = 16
    dilations: tuple[int, ...] = (1, 2, 4, 8, 1)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "MapPriorConfig":
        return cls(int(d["channels"]), tuple(int(x) for x in d["dilations"]))


class MapPrior(nn.Module):
    """``[R, 3, H, W]`` (:func:`prior_inputs`) -> ``[R, H, W]``: each coarse cell's predicted
    importance per m² (softplus, ≥ 0)."""

    def __init__(self, config: MapPriorConfig | None = None):
        super().__init__()
        self.config = cfg = config or MapPriorConfig()
        self.stem = nn.Conv2d(PRIOR_CHANNELS, cfg.channels, 3, padding=1)
        self.blocks = nn.ModuleList(nn.Conv2d(cfg.channels, cfg.channels, 3, padding=d, dilation=d)
                                    for d in cfg.dilations)
        self.head = nn.Conv2d(cfg.channels, 1, 1)
        self.act = nn.LeakyReLU(0.01)

    def forward(self, x: Tensor) -> Tensor:
        h = self.act(self.stem(x))
        for conv in self.blocks:
            h = h + self.act(conv(h))
        return nn.functional.softplus(self.head(h)[:, 0])


def window_masks(origin_m: np.ndarray, blocks: int, block_m: int, world_size: int) -> np.ndarray:
    """``[R, G, G]`` bool: the blocks of each window (lower corner ``origin_m [R, 2]``, G = ``blocks``
    blocks of ``block_m`` m) whose every cell is inside the world."""
    lo = origin_m[:, :, None] + block_m * np.arange(blocks)[None, None]  # [R, 2, G]: each block's first cell
    ok = (lo >= 0) & (lo + block_m - 1 < world_size)
    return ok[:, 0, :, None] & ok[:, 1, None, :]


def _coarse_sum(x: np.ndarray, f: int) -> np.ndarray:
    """``[R, G, G]`` -> ``[R, G/f, G/f]``: sums over f × f blocks."""
    r, g = x.shape[0], x.shape[1]
    rows = x.reshape(r, g // f, f, g).sum(2)  # [R, G/f, G]: contiguous runs of G
    return rows.reshape(r, g // f, g // f, f).sum(3)


def prior_inputs(weights: np.ndarray, unexplored: np.ndarray, inside: np.ndarray, block_m: int) -> np.ndarray:
    """The network's input ``[R, 3, G/f, G/f]`` float32 (f = COARSE_M / block_m) from a window's block
    masses ``weights [R, G, G]`` (its own sensed map), its unexplored blocks and its blocks inside the
    world (both ``[R, G, G]`` bool): per coarse cell, the sensed importance per m² over its explored
    blocks inside (0 where none), the fraction of its blocks explored and inside, and the fraction inside."""
    f = COARSE_M // block_m
    known = inside & ~unexplored
    n_known = _coarse_sum(known.astype(np.float32), f)
    mass = _coarse_sum(weights.astype(np.float32) * known, f)
    density = np.divide(mass, n_known * block_m ** 2, out=np.zeros_like(mass), where=n_known > 0)
    return np.stack([density, n_known / f ** 2, _coarse_sum(inside.astype(np.float32), f) / f ** 2], 1)


def prior_targets(true_weights: np.ndarray, inside: np.ndarray, block_m: int) -> np.ndarray:
    """What the network is trained to predict ``[R, G/f, G/f]`` float32: each coarse cell's true
    importance per m² over its blocks inside the world (0 where none), from the world map's block
    masses ``true_weights [R, G, G]`` in the same windows."""
    f = COARSE_M // block_m
    n_in = _coarse_sum(inside.astype(np.float64), f)
    mass = _coarse_sum(np.where(inside, true_weights, 0.0), f)
    return np.divide(mass, n_in * block_m ** 2, out=np.zeros_like(mass), where=n_in > 0).astype(np.float32)


@torch.inference_mode()
def prior_weights(net: MapPrior, weights: np.ndarray, unexplored: np.ndarray, inside: np.ndarray,
                  block_m: int, floor: np.ndarray | None = None) -> np.ndarray:
    """``weights [R, G, G]`` (float64 block masses) with each unexplored block inside the world given
    the predicted importance of its coarse cell times the block's area (``explore``'s rule with the
    network's prediction in place of the explored blocks' mean), or ``floor [R, G, G]`` (a mass per
    block) where that is more."""
    if len(weights) == 0:
        return weights
    x = torch.from_numpy(prior_inputs(weights, unexplored, inside, block_m))
    p = next(net.parameters())
    density = net(x.to(p.device, p.dtype)).float().cpu().numpy().astype(np.float64)  # [R, G/f, G/f]
    r, g, f = weights.shape[0], weights.shape[1], COARSE_M // block_m
    fill = ((unexplored & inside).reshape(r, g // f, f, g // f, f) * density[:, :, None, :, None] * block_m ** 2
            ).reshape(r, g, g)
    return weights + (fill if floor is None else np.maximum(fill, floor))
