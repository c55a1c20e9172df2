"""Voronoi masses, centroids and coverage cost on a gridded importance map.

Rasterisation follows the Coverage Control Library (``voronoi.cpp``, ``CellNavigator``): map cell
(i, j) covers [i, i+1) x [j, j+1) m and belongs to robot k's Voronoi cell when its centre
(i + 0.5, j + 0.5) lies in k's convex cell polygon (clipped to a rectangular box). The library walks
each polygon column by column; at column centre x it takes the rows ``round(y_lower) <= j <
round(y_upper)``. We do the same without polygons: at every column centre, each neighbour's
half-plane bounds y from above or below, so a cell's extent in a column is one interval of rows

    lo = floor(y_lower + 0.5),  hi = floor(y_upper + 0.5)        (rows lo .. hi-1)

and a sum of the map over that interval is a difference of two prefix sums along y. The whole cell
is one lookup per column it spans: no per-cell work and no Python loop over map cells.

Sums over a *fixed* map (the world map, used by the clairvoyant expert and by J) use
:class:`ColumnPrefix`; sums over maps that change while robots explore use the block prefix sums
of :class:`madp.sim.robot_maps.RobotMaps`.

When a cell has (almost) no importance mass the library falls back to CGAL's ``centroid`` of the
polygon's vertex range, i.e. the mean of the clipped polygon's vertices;
:func:`polygon_vertex_means` reproduces that with a batched Sutherland-Hodgman clip.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

MASS_EPS = 1e-10
"""Below this mass a cell's goal is its polygon's vertex mean (library's ``kEps``)."""


@dataclass(frozen=True)
class CellSums:
    """Per-robot sums over each Voronoi cell, all float64.

    mass [N]: sum of the map over the cell; centroid_m [N, 2]: map-weighted centroid, or the
    polygon's vertex mean where mass < MASS_EPS; cost [N]: sum of map * |q - x_k|^2 (m^2), or None
    when not requested.
    """

    mass: np.ndarray
    centroid_m: np.ndarray
    cost: np.ndarray | None


def delaunay_neighbours(sites_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delaunay neighbours of each site, padded: (index [N, M] int, valid [N, M] bool).

    The Voronoi cell of a site is the intersection of the half-planes of its Delaunay neighbours
    alone. Degenerate layouts (fewer than 3 sites, all collinear) fall back to every other site.
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


def column_intervals(
    sites_m: np.ndarray,
    others_m: np.ndarray,
    valid: np.ndarray,
    columns: np.ndarray,
    row_lo: np.ndarray | int,
    row_hi: np.ndarray | int,
) -> tuple[np.ndarray, np.ndarray]:
    """Row interval [lo, hi) of each robot's cell in each column.

    sites_m [R, 2]; others_m [R, M, 2] competing sites (ignored where ``valid`` [R, M] is False);
    columns [R, C] or [C] integer column indices; row_lo/row_hi [R] or scalars: the box's rows.
    Returns lo, hi [R, C] int64 with hi >= lo (an empty interval where the cell misses a column).
    """
    columns = np.asarray(columns)
    xc = (columns + 0.5).astype(np.float64)
    if xc.ndim == 1:
        xc = xc[None, :]
    d = others_m - sites_m[:, None, :]  # [R, M, 2]
    mid = 0.5 * (others_m + sites_m[:, None, :])
    dx, dy = d[..., 0], d[..., 1]
    # Half-plane d . (q - mid) <= 0. At column centre x: dy * y <= dy * mid_y - dx * (x - mid_x).
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(dy != 0, -dx / dy, 0.0)  # [R, M]
    intercept = mid[..., 1] - slope * mid[..., 0]
    bound = intercept[..., None] + slope[..., None] * xc[:, None, :]  # [R, M, C]
    upper_mask = (valid & (dy > 0))[..., None]
    lower_mask = (valid & (dy < 0))[..., None]
    y_upper = np.min(np.where(upper_mask, bound, np.inf), axis=1)
    y_lower = np.max(np.where(lower_mask, bound, -np.inf), axis=1)
    # Neighbours level with the site (dy == 0) cut whole columns: keep x on the site's side.
    flat = valid & (dy == 0) & (dx != 0)
    if flat.any():
        side = dx[..., None] * (xc[:, None, :] - mid[..., 0][..., None])  # must be <= 0
        cut = np.any(flat[..., None] & (side > 0), axis=1)
        y_upper = np.where(cut, -np.inf, y_upper)
    row_lo = np.asarray(row_lo)[..., None] if np.ndim(row_lo) else row_lo
    row_hi = np.asarray(row_hi)[..., None] if np.ndim(row_hi) else row_hi
    lo = np.clip(np.floor(np.clip(y_lower, -1e9, 1e9) + 0.5), row_lo, row_hi).astype(np.int64)
    hi = np.clip(np.floor(np.clip(y_upper, -1e9, 1e9) + 0.5), row_lo, row_hi).astype(np.int64)
    return lo, np.maximum(hi, lo)


class ColumnPrefix:
    """Prefix sums along y of a fixed map: Φ, Φ·y and Φ·y² per column, [W, H + 1] float64 each.

    Built once per map (an episode's world map never changes); afterwards the sum of Φ over rows
    lo..hi-1 of column c is ``p0[c, hi] - p0[c, lo]``.
    """

    def __init__(self, map_xy: np.ndarray):
        m = np.asarray(map_xy, dtype=np.float64)
        self.width, self.height = m.shape
        y = np.arange(self.height, dtype=np.float64) + 0.5
        self.p = np.zeros((3, self.width, self.height + 1))
        np.cumsum(m, axis=1, out=self.p[0, :, 1:])
        np.cumsum(m * y, axis=1, out=self.p[1, :, 1:])
        np.cumsum(m * (y * y), axis=1, out=self.p[2, :, 1:])

    def interval_sums(self, columns: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Sums of (Φ, Φ·y, Φ·y²) over rows [lo, hi) of the given columns: [3, *lo.shape]."""
        cols = np.broadcast_to(columns, lo.shape)
        return self.p[:, cols, hi] - self.p[:, cols, lo]


def moments_to_sums(
    sites_m: np.ndarray,
    xc: np.ndarray,
    s0: np.ndarray,
    s1: np.ndarray,
    s2: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Reduce per-column moments [R, C] to (mass [R], weighted-position sums [R, 2], cost [R]).

    xc [R, C] or [C]: column centres (m); s0, s1, s2: per-column sums of Φ, Φ·y, Φ·y².
    """
    xc = np.broadcast_to(xc, s0.shape)
    mass = s0.sum(axis=1)
    first = np.stack([(s0 * xc).sum(axis=1), s1.sum(axis=1)], axis=1)
    cost = None
    if s2 is not None:
        sx, sy = sites_m[:, 0:1], sites_m[:, 1:2]
        cost = (s0 * (xc - sx) ** 2 + s2 - 2.0 * sy * s1 + sy * sy * s0).sum(axis=1)
    return mass, first, cost


def polygon_vertex_means(
    sites_m: np.ndarray, others_m: np.ndarray, valid: np.ndarray, boxes: np.ndarray
) -> np.ndarray:
    """Mean of the vertices of each Voronoi cell clipped to its box: [R, 2].

    sites_m [R, 2]; others_m [R, M, 2]; valid [R, M]; boxes [R, 4] = (x0, y0, x1, y1).
    All R polygons are clipped at once (Sutherland-Hodgman, one half-plane per step). Consecutive
    vertices closer than 1e-9 m are merged, as CGAL's exact arrangement would.
    """
    r, m = valid.shape
    cap = 4 + m + 1
    poly = np.zeros((r, cap, 2))
    x0, y0, x1, y1 = boxes.T
    poly[:, 0] = np.stack([x0, y0], 1)
    poly[:, 1] = np.stack([x1, y0], 1)
    poly[:, 2] = np.stack([x1, y1], 1)
    poly[:, 3] = np.stack([x0, y1], 1)
    count = np.full(r, 4)
    slot = np.arange(cap)
    rows = np.arange(r)[:, None]
    for k in range(m):
        d = others_m[:, k] - sites_m
        mid = 0.5 * (others_m[:, k] + sites_m)
        s = np.einsum("rvc,rc->rv", poly - mid[:, None], d)
        in_range = slot[None] < count[:, None]
        inside = (s <= 0) | ~valid[:, k : k + 1]
        nxt = (slot[None] + 1) % np.maximum(count[:, None], 1)
        s_next = np.take_along_axis(s, nxt, 1)
        inside_next = np.take_along_axis(inside, nxt, 1)
        p_next = np.take_along_axis(poly, nxt[..., None], 1)
        keep = inside & in_range
        cross = (inside != inside_next) & in_range
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(cross, s / (s - s_next), 0.0)
        inter = poly + t[..., None] * (p_next - poly)
        emitted = keep.astype(np.int64) + cross
        start = np.cumsum(emitted, 1) - emitted
        new = np.zeros_like(poly)
        rr = np.broadcast_to(rows, keep.shape)
        new[rr[keep], start[keep]] = poly[keep]
        new[rr[cross], (start + keep)[cross]] = inter[cross]
        poly, count = new, emitted.sum(1)
    in_range = slot[None] < count[:, None]
    prev = np.take_along_axis(poly, ((slot[None] - 1) % np.maximum(count[:, None], 1))[..., None], 1)
    distinct = in_range & (np.linalg.norm(poly - prev, axis=2) > 1e-9)
    distinct[:, 0] |= in_range[:, 0] & (count == 1)
    n = np.maximum(distinct.sum(1), 1)
    return (poly * distinct[..., None]).sum(1) / n[:, None]


def voronoi_sums(
    prefix: ColumnPrefix, sites_m: np.ndarray, with_cost: bool = True
) -> CellSums:
    """Masses, centroids (and costs) of every robot's Voronoi cell over a whole fixed map."""
    sites_m = np.asarray(sites_m, dtype=np.float64)
    nbr, valid = delaunay_neighbours(sites_m)
    others = sites_m[nbr]
    columns = np.arange(prefix.width)
    lo, hi = column_intervals(sites_m, others, valid, columns, 0, prefix.height)
    sums = prefix.interval_sums(columns, lo, hi)
    xc = columns + 0.5
    mass, first, cost = moments_to_sums(sites_m, xc, sums[0], sums[1], sums[2] if with_cost else None)
    return CellSums(mass, finish_centroids(mass, first, sites_m, others, valid,
                                           np.array([0.0, 0.0, prefix.width, prefix.height])), cost)


def finish_centroids(
    mass: np.ndarray,
    first: np.ndarray,
    sites_m: np.ndarray,
    others_m: np.ndarray,
    valid: np.ndarray,
    boxes: np.ndarray,
) -> np.ndarray:
    """Centroid = first moment / mass, or the clipped polygon's vertex mean where mass < MASS_EPS."""
    with np.errstate(divide="ignore", invalid="ignore"):
        centroid = first / mass[:, None]
    empty = mass < MASS_EPS
    if empty.any():
        boxes = np.broadcast_to(boxes, (len(mass), 4))
        centroid[empty] = polygon_vertex_means(
            sites_m[empty], others_m[empty], valid[empty], boxes[empty]
        )
    return centroid


def coverage_cost(prefix: ColumnPrefix, sites_m: np.ndarray) -> float:
    """J(X) = Σ_k Σ_{q in V_k} Φ(q) |q_c - x_k|² over the whole map (m²·importance)."""
    sites_m = np.asarray(sites_m, dtype=np.float64)
    nbr, valid = delaunay_neighbours(sites_m)
    columns = np.arange(prefix.width)
    lo, hi = column_intervals(sites_m, sites_m[nbr], valid, columns, 0, prefix.height)
    s = prefix.interval_sums(columns, lo, hi)
    return float(moments_to_sums(sites_m, columns + 0.5, s[0], s[1], s[2])[2].sum())
