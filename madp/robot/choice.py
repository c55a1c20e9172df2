"""What one robot computes to choose among its K samples (:mod:`madp.policies.select` has the rules):
what it knows (:func:`map_views`, with the ``explore`` prior :func:`map_prior`: row i from robot i's
own map and neighbours alone; :func:`local_views` and :func:`explore_prior` compute them for every
robot of an environment at once, :class:`madp.robot.RobotAgent` for itself), the local
cell cost of each candidate (:func:`local_cell_costs`), MPPI's weights and the medoid. numpy and numba only (no torch): the robot
runtime (:mod:`madp.robot.runtime`) and MADP's PyTorch policy run the same code.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numba
import numpy as np

from madp.sim.env import move
from madp.sim.params import SimParams
from madp.sim.robot_maps import EXPLORED_BLOCK_M, RobotMaps, robot_cells

if TYPE_CHECKING:
    from madp.sim.env import CoverageEnv

__all__ = ["GRID_M", "MAP_RULES", "MPPI_TEMPERATURE", "LocalViews", "explore_prior", "local_cell_costs", "local_views",
           "map_prior", "map_views", "medoid_index", "mppi_weights"]

#: Spacing (m) of the grid the local cell cost is summed on: 4 × 4 cells of a robot's map per point.
GRID_M = 4
#: MPPI's λ in units of the standard deviation of a robot's K local costs.
MPPI_TEMPERATURE = 1.0
#: The selection rules a robot runs that read its own map (they need its :class:`LocalViews` row).
MAP_RULES = ("cell", "explore", "mppi")


@dataclass(frozen=True)
class LocalViews:
    """What each robot knows, one row per robot (R rows):

    ``start_m``, ``offset_m`` [R, 2]: its own position, as the motion rule integrates it;
    ``weights`` [R, G, G]: its own sensed map inside its local window, summed over blocks of
    GRID_M × GRID_M cells (float64); ``origin_m`` [R, 2]: the window's lower corner, so block (a, b)
    has its centre at ``origin_m + GRID_M * (a, b) + GRID_M / 2``;
    ``neighbours_m`` [R, M, 2]: the latest positions of its neighbours within r_c, padded;
    ``valid`` [R, M]: which of them are real."""

    start_m: np.ndarray
    offset_m: np.ndarray
    weights: np.ndarray
    origin_m: np.ndarray
    neighbours_m: np.ndarray
    valid: np.ndarray


def local_views(env: CoverageEnv, true_map: bool = False) -> LocalViews:
    """Every robot's :class:`LocalViews` row (:func:`map_views` of the environment's maps): its own map
    (``env.maps``, what it sensed) in its window around its own position estimate, that position (as
    the motion rule integrates it: its start and offset when its estimate is exact, else the estimate
    itself), and the neighbours it knows of (:meth:`madp.sim.CoverageEnv.neighbour_view`: its inbox
    when the environment has a network). ``true_map``: the world map in the same window instead
    (``oracle_cell``: not what a robot knows)."""
    own = env.estimates_m()
    exact = own is env.positions_m  # no position noise: the motion rule's own start and offset
    start_m, offset_m = (env.start_m, env.offset_m) if exact else (own, np.zeros_like(own))
    known, held_m = env.neighbour_view()
    return map_views(env.maps, own, start_m, offset_m, known, held_m, true_map)


def map_views(maps: RobotMaps, own_m: np.ndarray, start_m: np.ndarray, offset_m: np.ndarray, known: np.ndarray,
              held_m: np.ndarray, true_map: bool = False) -> LocalViews:
    """The :class:`LocalViews` rows of the R robots of ``maps`` (one row each, from that robot's map
    alone): its map in the ``local_size`` window around its position estimate ``own_m [R, 2]`` (zero
    outside the world), its position as the motion rule integrates it, ``start_m + offset_m`` [R, 2],
    and the neighbours it knows of: ``held_m [R, M, 2]`` where ``known [R, M]``, kept in their order.
    ``true_map``: the maps' world map in the same window instead."""
    s = maps.local_size
    g = s // GRID_M
    cells = robot_cells(own_m)
    starts = cells - s // 2 + maps.pad  # each window's lower corner in the padded maps
    grids = maps.world_padded[None] if true_map else maps.maps_padded  # the world's, or each robot's own
    weights = _block_sums(grids, not true_map, starts, g, GRID_M)
    known, held_m = np.asarray(known, bool), np.asarray(held_m, np.float64).reshape(len(own_m), -1, 2)
    if known.shape[1] == 0:  # no neighbour held: one invalid slot
        known, held_m = np.zeros((len(own_m), 1), bool), np.zeros((len(own_m), 1, 2))
    m = max(int(known.sum(1).max()), 1)
    order = np.argsort(~known, axis=1, kind="stable")[:, :m]  # each robot's neighbours first
    valid = np.take_along_axis(known, order, 1)
    neighbours_m = np.take_along_axis(held_m, order[:, :, None], 1)
    return LocalViews(start_m, offset_m, weights, (cells - s // 2).astype(np.float64), neighbours_m, valid)


@numba.njit(cache=True, nogil=True)
def _block_sums(maps, own, starts, g, b):  # pragma: no cover (compiled)
    """[R, g, g] float64: the b × b block sums of robot r's window of ``maps[r if own else 0]``
    from padded corner ``starts[r]``; each block summed over its rows, then its columns (numpy's
    ``reshape(...).sum(2).sum(3)`` order: the same bits)."""
    out = np.zeros((len(starts), g, g))
    for r in range(len(starts)):
        m = maps[r if own else 0]
        x0, y0 = starts[r, 0], starts[r, 1]
        for a in range(g):
            for c in range(g):
                total = 0.0
                for j in range(b):
                    col = 0.0
                    for i in range(b):
                        col += m[x0 + a * b + i, y0 + c * b + j]
                    total += col
                out[r, a, c] = total
    return out


def explore_prior(env: CoverageEnv, views: LocalViews) -> LocalViews:
    """``views`` (every robot's row) with the ``explore`` prior of each robot's explored map
    (:func:`map_prior` of ``env.maps``)."""
    return map_prior(env.maps, views)


def map_prior(maps: RobotMaps, views: LocalViews) -> LocalViews:
    """``views`` with each robot's unexplored blocks of its window (inside the world) given the mean
    mass of its explored ones (1 when those hold none): the weights ``explore`` uses. Row r reads
    robot r's own explored map (``maps.explored[r]``): a window block is explored when every cell of it is (the explored
    blocks of its four corner cells), and inside when every cell of it is in the world; both rules
    are kept by the world's 8 symmetries, so the choice is exactly equivariant."""
    g = views.weights.shape[1]
    pad, w = maps.pad, maps.world_size
    corner = views.origin_m.astype(np.int64) + pad  # [N, 2]: each window's first cell, padded
    first = corner[:, :, None] + GRID_M * np.arange(g)  # [N, 2, G]: each window block's first cell
    last = first + GRID_M - 1
    # A window block is explored when every cell of it is: when the explored blocks of its four corner
    # cells are. Window block a starts in explored block corner // 4 + a (GRID_M = EXPLORED_BLOCK_M) and
    # reaches into the next one when the window's corner is not on the explored grid (per robot and axis).
    lo = corner // EXPLORED_BLOCK_M
    straddles = (corner % EXPLORED_BLOCK_M != 0)[:, :, None, None]  # [N, 2, 1, 1]
    span = np.minimum(lo[:, :, None] + np.arange(g + 1), maps.explored.shape[1] - 1)  # [N, 2, G + 1]
    n = np.arange(len(corner))[:, None, None]
    slab = maps.explored[n, span[:, 0, :, None], span[:, 1, None, :]]  # [N, G + 1, G + 1]
    rows = slab[:, :-1] & (slab[:, 1:] | ~straddles[:, 0])  # [N, G, G + 1]
    explored = rows[:, :, :-1] & (rows[:, :, 1:] | ~straddles[:, 1])  # [N, G, G]
    inside = (first >= pad) & (last < pad + w)  # every cell of the block in the world
    inside = inside[:, 0, :, None] & inside[:, 1, None, :]
    seen = explored & inside
    mass = np.where(seen, views.weights, 0.0).sum((1, 2)) / np.maximum(seen.sum((1, 2)), 1)
    mass = np.where(mass > 0, mass, 1.0)
    prior = np.where(inside & ~explored, mass[:, None, None], 0.0)
    return replace(views, weights=views.weights + prior)


@numba.njit(cache=True, nogil=True)
def _cell_costs(y, weights, origin, nbr, valid, b):  # pragma: no cover (compiled)
    """[R, K]: Σ over the blocks of robot r's window closer to y[r, k] than to every valid neighbour
    (ties: its own) of weight · distance² to the block's centre (:func:`local_cell_costs`)."""
    r_n, k_n, g = y.shape[0], y.shape[1], weights.shape[1]
    out = np.zeros((r_n, k_n))
    for r in range(r_n):
        for a in range(g):
            qx = origin[r, 0] + b * a + b / 2
            for c in range(g):
                w = weights[r, a, c]
                if w == 0.0:
                    continue
                qy = origin[r, 1] + b * c + b / 2
                nearest = np.inf
                for m in range(nbr.shape[1]):
                    if valid[r, m]:
                        d = (qx - nbr[r, m, 0]) ** 2 + (qy - nbr[r, m, 1]) ** 2
                        nearest = min(nearest, d)
                for k in range(k_n):
                    d = (qx - y[r, k, 0]) ** 2 + (qy - y[r, k, 1]) ** 2
                    if d <= nearest:
                        out[r, k] += w * d
    return out


def local_cell_costs(views: LocalViews, actions_mps: np.ndarray, params: SimParams) -> np.ndarray:
    """Each robot's local cell cost of each of its candidates ``actions_mps [R, K, 2]`` (m/s): ``[R, K]``.

    Robot r moves to y = :func:`madp.sim.env.move` of its own position; its cell is the set of
    grid points of its window closer to y than to every valid neighbour (ties: its own); the cost is
    ``sum over the cell of weight · |q − y|²`` (SPEC's J restricted to its own cell, on its own map,
    on a grid of GRID_M m: each block's mass at the block's centre). Uses ``views`` and the motion
    constants of ``params`` only."""
    y, _ = move(views.start_m[:, None], views.offset_m[:, None], actions_mps, params)  # [R, K, 2]
    return _cell_costs(np.ascontiguousarray(y, dtype=np.float64), views.weights, views.origin_m,
                       np.ascontiguousarray(views.neighbours_m, dtype=np.float64), views.valid, GRID_M)


def mppi_weights(costs: np.ndarray, temperature: float = MPPI_TEMPERATURE) -> np.ndarray:
    """Weights ``[R, K]`` (each row sums to 1) ``∝ exp(−(c_k − min c) / λ)`` with λ = ``temperature`` ×
    the standard deviation of the row's K costs: invariant to the costs' scale and offset. A row
    whose costs are all equal gets equal weights; ``temperature → 0`` puts all weight on the lowest
    cost, ``temperature → ∞`` gives equal weights."""
    c = np.asarray(costs, dtype=np.float64)
    spread = c.std(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        z = np.where(spread > 0, (c - c.min(axis=1, keepdims=True)) / (temperature * spread), 0.0)
    w = np.exp(-z)
    return w / w.sum(axis=1, keepdims=True)


def medoid_index(candidates_mps: np.ndarray) -> np.ndarray:
    """Per row of ``candidates_mps [R, K, 2]``, the index of the candidate of least summed Euclidean
    distance to the row's K candidates: ``[R]`` (ties: the lowest index)."""
    diff = candidates_mps[:, :, None] - candidates_mps[:, None]  # [R, K, K, 2]
    return np.sqrt((diff ** 2).sum(-1)).sum(2).argmin(1)
