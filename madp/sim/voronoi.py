"""Voronoi masses, centroids and coverage cost on a gridded importance map.

Rasterisation follows the Coverage Control Library (``voronoi.cpp``, ``CellNavigator``): map cell
(i, j) covers [i, i+1) x [j, j+1) m and belongs to robot k's Voronoi cell when its centre
(i + 0.5, j + 0.5) lies in k's convex cell polygon (clipped to a rectangular box). The library walks
each polygon column by column; at column centre x it takes the rows ``round(y_lower) <= j <
round(y_upper)``. We do the same without building polygons: at a column centre each competing
site's half-plane bounds y from above or below, so a cell's extent in a column is one interval

    lo = floor(y_lower + 0.5),  hi = floor(y_upper + 0.5)        (rows lo .. hi-1)

and a sum of the map over it is a difference of two prefix sums along y: one lookup per column the
cell spans, no per-cell work.

A cell is convex, so the columns it reaches are one interval around its site: the compiled kernel
(:func:`madp.sim.kernels.cell_sums`) walks outward from the site's column until the cell is empty
(continuous bounds y_lower >= y_upper, or beyond a level competitor's bisector), then sums the
columns in ascending order. This module prepares its arguments (competitors, boxes, the prefix
table) and applies the shared-point rule.

When a cell has (almost) no importance mass the library falls back to CGAL's ``centroid`` of the
polygon's vertex range, i.e. the mean of the clipped polygon's vertices; the kernel enumerates
those vertices exactly (every pairwise line intersection that satisfies all constraints).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

from . import kernels

MASS_EPS = 1e-10
"""Below this mass a cell's goal is its polygon's vertex mean (library's ``kEps``)."""


@dataclass(frozen=True)
class CellSums:
    """Per-robot sums over each Voronoi cell, all float64.

    mass [N]: Σ Φ over the cell; centroid_m [N, 2]: Φ-weighted centroid, or the polygon's vertex
    mean where mass < MASS_EPS; cost [N] (m²): Σ Φ |q - x_k|², or None when not requested.
    """

    mass: np.ndarray
    centroid_m: np.ndarray
    cost: np.ndarray | None


def delaunay_neighbours(sites_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delaunay neighbours of each site, padded: (index [N, M] int, valid [N, M] bool).

    The Voronoi cell of a site is the intersection of the half-planes of its Delaunay neighbours
    alone. Degenerate layouts (fewer than 4 sites, all collinear) fall back to every other site.
    """
    n = len(sites_m)
    try:
        if n < 4:
            raise QhullError("too few sites")
        indptr, indices = Delaunay(sites_m).vertex_neighbor_vertices
    except QhullError:
        idx = np.broadcast_to(np.arange(n), (n, n))
        valid = ~np.eye(n, dtype=bool)
        return np.where(valid, idx, 0), valid
    counts = np.diff(indptr)
    m = max(int(counts.max()), 1)
    slot = np.arange(m)
    valid = slot[None, :] < counts[:, None]
    pos = np.minimum(indptr[:-1, None] + slot[None, :], len(indices) - 1)
    return np.where(valid, indices[pos], 0), valid


class ColumnPrefix:
    """Prefix sums along y of a fixed map: Φ, Φ·y and Φ·y² per column, ``table`` [W, H + 1, 4] float64.

    Built once per map (an episode's world map never changes); afterwards the sum of Φ over rows
    lo..hi-1 of column c is ``table[c, hi, 0] - table[c, lo, 0]``. The three moments of a row share
    one 32-byte slot (the fourth is padding), so a lookup reads one cache line, not three.
    """

    def __init__(self, map_xy: np.ndarray):
        m = np.ascontiguousarray(map_xy, dtype=np.float64)
        self.width, self.height = m.shape
        # numpy allocates it (in 2 MiB pages where the system offers them: the kernel fills it whole)
        self.table = np.empty((self.width, self.height + 1, 4))
        kernels.column_prefix(m, self.table)  # numpy's cumsums of Φ, Φ·y, Φ·y², bit for bit


_NO_TABLE = np.zeros((0, 1, 4))
_NO_WITHIN = np.zeros((1, 1, 1, 1, 2), np.float32)
_NO_CUM = np.zeros((1, 1, 1, 2))


def cell_sums(sites_m: np.ndarray, points_m: np.ndarray, idx: np.ndarray, valid: np.ndarray, boxes: np.ndarray, *,
              prefix: ColumnPrefix | None = None, block_sums: tuple[np.ndarray, np.ndarray] | None = None,
              with_cost: bool = False, with_centroids: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses [R], centroids [R, 2] and costs [R] of convex cells (:func:`madp.sim.kernels.cell_sums`).

    Robot r's cell: site ``sites_m[r]`` against the competitors ``points_m[idx[r, m]]`` where
    ``valid[r, m]``, clipped to ``boxes[r]`` (x0, y0, x1, y1, whole cells). Summed over the world
    map (``prefix``) or over each robot's own map (``block_sums`` = RobotMaps' (cum, within)).
    Cells with mass < MASS_EPS get their polygon's vertex mean when ``with_centroids``."""
    if (prefix is None) == (block_sums is None):
        raise ValueError("give exactly one of prefix and block_sums")
    cum, within = block_sums if block_sums is not None else (_NO_CUM, _NO_WITHIN)
    table = prefix.table if prefix is not None else _NO_TABLE
    return kernels.cell_sums(
        np.ascontiguousarray(sites_m, dtype=np.float64), np.ascontiguousarray(points_m, dtype=np.float64),
        np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(valid, dtype=np.bool_),
        np.ascontiguousarray(boxes, dtype=np.float64), table, within, cum, with_cost, with_centroids, MASS_EPS)


#: How many layouts :func:`world_competitors` keeps the answer for (a batch's environments, each
#: asked twice per step: the expert's goals, then J after the step, of the same positions).
COMPETITORS_KEPT = 64
_competitors: OrderedDict[tuple, tuple] = OrderedDict()
_competitors_lock = threading.Lock()


def world_competitors(sites_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Each robot's competitors over the whole world: (points [P, 2], idx [N, M], valid [N, M],
    shared [N] bool or None), the Delaunay neighbours of its point.

    Robots on one point share one cell (``shared`` marks every robot standing on the point of a
    lower-indexed one): its centroid is their goal too, but its mass and cost count once, for the
    lowest index. So J stays the integral of the squared distance to the nearest robot: without
    this, Qhull leaves a duplicate site without neighbours and its "cell" would be the whole world.

    The answers for the last :data:`COMPETITORS_KEPT` layouts are kept: a layout asked for again is
    not triangulated again, and gets the same arrays (which no caller writes to)."""
    sites_m = np.asarray(sites_m, dtype=np.float64)
    key = (sites_m.shape, sites_m.tobytes())
    with _competitors_lock:
        kept = _competitors.get(key)
        if kept is not None:
            _competitors.move_to_end(key)
            return kept
    answer = _world_competitors(sites_m.copy())  # a copy: the caller may move its robots in place
    with _competitors_lock:
        _competitors[key] = answer
        if len(_competitors) > COMPETITORS_KEPT:
            _competitors.popitem(last=False)
    return answer


def _world_competitors(sites_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    s = sites_m[np.lexsort(sites_m.T)]  # a cheap test first: this runs every control step
    if not (s[1:] == s[:-1]).all(axis=1).any():
        nbr, valid = delaunay_neighbours(sites_m)
        return sites_m, nbr, valid, None
    uniq, first, inverse = np.unique(sites_m, axis=0, return_index=True, return_inverse=True)
    rep = inverse.reshape(-1)  # robot -> its point in uniq
    nbr, valid = delaunay_neighbours(uniq)
    return uniq, nbr[rep], valid[rep], np.arange(len(sites_m)) != first[rep]


def world_sums(prefix: ColumnPrefix, sites_m: np.ndarray, with_cost: bool, with_centroids: bool = True) -> CellSums:
    """Masses, centroids (and costs) of every robot's Voronoi cell over a whole fixed map; robots
    sharing a point share its cell (:func:`world_competitors`)."""
    sites_m = np.asarray(sites_m, dtype=np.float64)
    points, idx, valid, shared = world_competitors(sites_m)
    boxes = np.broadcast_to(np.array([0.0, 0.0, prefix.width, prefix.height]), (len(sites_m), 4))
    mass, centroid, cost = cell_sums(sites_m, points, idx, valid, boxes, prefix=prefix, with_cost=with_cost,
                                     with_centroids=with_centroids)
    if shared is not None:
        mass[shared] = 0.0
        cost[shared] = 0.0
    return CellSums(mass, centroid, cost if with_cost else None)


def voronoi_sums(prefix: ColumnPrefix, sites_m: np.ndarray, with_cost: bool = True) -> CellSums:
    """Masses, centroids (and costs) of every robot's Voronoi cell over a whole fixed map."""
    return world_sums(prefix, sites_m, with_cost)


def coverage_cost(prefix: ColumnPrefix, sites_m: np.ndarray) -> float:
    """J(X) = Σ_k Σ_{q in V_k} Φ(q) |q_c - x_k|² over the whole map (m²·importance)."""
    return float(world_sums(prefix, sites_m, True, with_centroids=False).cost.sum())
