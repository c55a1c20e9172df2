"""A robot's learned prior on the importance it has not sensed: the map the ``value`` selection rule
scores its candidates on (:mod:`madp.policies.select`).

The ``explore`` rule gives every block of a robot's window that its sensor has not covered the mean
importance of the blocks it has. :class:`MapPrior` predicts it instead, from the same window: a small
convolutional network over the window coarsened to cells of :data:`COARSE_M` metres
(``[R, 3, 16, 16]`` for the 256 m window), whose three channels are each cell's sensed importance per
m² over its explored part, its explored fraction and its fraction inside the world
(:func:`madp.robot.prior.prior_inputs`). It returns each cell's importance per m² (``[R, 16, 16]``, ≥ 0).
:func:`prior_weights` adds that prediction to the window's unexplored blocks, as ``explore`` adds
its mean. Trained against the true map (``madp value train``, :mod:`madp.training.map_prior`).

numpy in, numpy out for the rule; the network itself is torch. What the rule computes around it lives
in :mod:`madp.robot.prior` (no torch), which the robot runtime shares with the exported network.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor, nn

from madp.robot.prior import COARSE_M, PRIOR_CHANNELS, coarse_sum, fill_prior, prior_inputs, window_masks

__all__ = ["COARSE_M", "PRIOR_CHANNELS", "MapPrior", "MapPriorConfig", "predictor", "prior_inputs", "prior_targets",
           "prior_weights", "window_masks"]


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


def prior_targets(true_weights: np.ndarray, inside: np.ndarray, block_m: int) -> np.ndarray:
    """What the network is trained to predict ``[R, G/f, G/f]`` float32: each coarse cell's true
    importance per m² over its blocks inside the world (0 where none), from the world map's block
    masses ``true_weights [R, G, G]`` in the same windows."""
    f = COARSE_M // block_m
    n_in = coarse_sum(inside.astype(np.float64), f)
    mass = coarse_sum(np.where(inside, true_weights, 0.0), f)
    return np.divide(mass, n_in * block_m ** 2, out=np.zeros_like(mass), where=n_in > 0).astype(np.float32)


def predictor(net: MapPrior):
    """``net`` as the rule's ``predict``: ``x [R, 3, H, W]`` float32 numpy -> ``[R, H, W]`` float64 numpy,
    on the network's device and dtype, without gradients."""
    p = next(net.parameters())

    @torch.inference_mode()
    def predict(x: np.ndarray) -> np.ndarray:
        return net(torch.from_numpy(np.ascontiguousarray(x)).to(p.device, p.dtype)).float().cpu().numpy().astype(np.float64)

    return predict


def prior_weights(net: MapPrior, weights: np.ndarray, unexplored: np.ndarray, inside: np.ndarray,
                  block_m: int, floor: np.ndarray | None = None) -> np.ndarray:
    """``weights [R, G, G]`` (float64 block masses) with each unexplored block inside the world given
    the predicted importance of its coarse cell times the block's area (``explore``'s rule with the
    network's prediction in place of the explored blocks' mean), or ``floor [R, G, G]`` (a mass per
    block) where that is more (:func:`madp.robot.prior.fill_prior`)."""
    if len(weights) == 0:
        return weights
    density = predictor(net)(prior_inputs(weights, unexplored, inside, block_m))
    return fill_prior(weights, unexplored, inside, block_m, density, floor)
