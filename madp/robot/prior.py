"""The ``value`` rules' learned map prior, on the robot's side: the network's input from a robot's own
window and the map its prediction makes, in numpy (no torch). The network itself
(:class:`madp.models.map_prior.MapPrior`) runs in PyTorch in madp's policy and as the ``map_prior``
graph of ``madp export`` in the robot runtime (:class:`madp.robot.RobotRuntime`); both call
:func:`value_view` with their own ``predict``.

The prior predicts over the window coarsened to cells of :data:`COARSE_M` metres (``[R, 3, 16, 16]`` for
the 256 m window): each cell's sensed importance per m² over its explored part, its explored fraction
and its fraction inside the world (:func:`prior_inputs`). It returns each cell's importance per m²
(``[R, 16, 16]``, ≥ 0), which :func:`fill_prior` puts on the window's unexplored blocks, as
``explore`` puts its mean.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Callable

import numpy as np

from .choice import GRID_M, LocalViews, map_prior, unexplored_blocks

if TYPE_CHECKING:
    from madp.sim.robot_maps import RobotMaps

__all__ = ["COARSE_M", "PRIOR_CHANNELS", "coarse_sum", "fill_prior", "prior_inputs", "value_view", "window_inputs",
           "window_masks"]

#: Side (m) of the coarse cells the prior predicts: 4 × 4 of the selection rules' 4 m blocks.
COARSE_M = 16
#: Input channels: sensed importance per m² over the explored part, explored fraction, inside fraction.
PRIOR_CHANNELS = 3

#: ``predict(x [R, 3, H, W] float32) -> [R, H, W]``: the prior's importance per m² of each coarse cell.
Predict = Callable[[np.ndarray], np.ndarray]


def window_masks(origin_m: np.ndarray, blocks: int, block_m: int, world_size: int) -> np.ndarray:
    """``[R, G, G]`` bool: the blocks of each window (lower corner ``origin_m [R, 2]``, G = ``blocks``
    blocks of ``block_m`` m) whose every cell is inside the world."""
    lo = origin_m[:, :, None] + block_m * np.arange(blocks)[None, None]  # [R, 2, G]: each block's first cell
    ok = (lo >= 0) & (lo + block_m - 1 < world_size)
    return ok[:, 0, :, None] & ok[:, 1, None, :]


def coarse_sum(x: np.ndarray, f: int) -> np.ndarray:
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
    n_known = coarse_sum(known.astype(np.float32), f)
    mass = coarse_sum(weights.astype(np.float32) * known, f)
    density = np.divide(mass, n_known * block_m ** 2, out=np.zeros_like(mass), where=n_known > 0)
    return np.stack([density, n_known / f ** 2, coarse_sum(inside.astype(np.float32), f) / f ** 2], 1)


def fill_prior(weights: np.ndarray, unexplored: np.ndarray, inside: np.ndarray, block_m: int, density: np.ndarray,
               floor: np.ndarray | None = None) -> np.ndarray:
    """``weights [R, G, G]`` (float64 block masses) with each unexplored block inside the world given
    ``density [R, G/f, G/f]`` (the prior's importance per m² of its coarse cell) times the block's area,
    or ``floor [R, G, G]`` (a mass per block) where that is more."""
    r, g, f = weights.shape[0], weights.shape[1], COARSE_M // block_m
    density = np.asarray(density, np.float64)
    fill = ((unexplored & inside).reshape(r, g // f, f, g // f, f) * density[:, :, None, :, None] * block_m ** 2
            ).reshape(r, g, g)
    return weights + (fill if floor is None else np.maximum(fill, floor))


def window_inputs(maps: RobotMaps, views: LocalViews) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the prior reads of each robot's window (rows of the robots of ``maps``): its input
    ``[R, 3, H, W]`` (:func:`prior_inputs`), the window's unexplored blocks and its blocks inside the
    world (both ``[R, G, G]`` bool)."""
    inside = window_masks(views.origin_m, views.weights.shape[1], GRID_M, maps.world_size)
    unexplored = unexplored_blocks(maps, views)
    return prior_inputs(views.weights, unexplored, inside, GRID_M), unexplored, inside


def value_view(maps: RobotMaps, views: LocalViews, predict: Predict, floor: bool = False) -> LocalViews:
    """``views`` (rows of the robots of ``maps``) with the ``value`` rule's weights: each robot's
    unexplored blocks inside the world given ``predict``'s importance (:func:`fill_prior`);
    ``floor``: at least ``explore``'s mean (``value_explore``). ``sensed`` keeps the weights before."""
    if len(views.weights) == 0:
        return replace(views, sensed=views.weights)
    x, unexplored, inside = window_inputs(maps, views)
    mean = map_prior(maps, views).weights - views.weights if floor else None  # explore's mass on unexplored blocks
    return replace(views, weights=fill_prior(views.weights, unexplored, inside, GRID_M, predict(x), mean),
                   sensed=views.weights)
