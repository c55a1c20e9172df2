"""Voronoi masses, centroids and coverage cost on a gridded importance map.

Rasterisation follows the Coverage Control Library (``voronoi.cpp``, ``CellNavigator``): map cell
(i, j) covers [i, i+1) x [j, j+1) m and belongs to robot k's Voronoi cell when its centre
(i + 0.5, j + 0.5) lies in k's convex cell polygon (clipped to a rectangular box). The library walks
each polygon column by column; at column centre x it takes the rows ``round(y_lower) <= j <
round(y_upper)``. We do the same without building polygons: at a column centre each competing
site's half-plane bounds y from above or below, so a cell's extent in a column is one interval

    lo = floor(y_lower + 0.5),  hi = floor(y_upper + 0.5)        (rows lo .. hi-1)

and a sum of the map over it is a difference of two prefix sums along y: one lookup per column the
cell spans, no per-cell work, no Python loop over map cells.

Only the columns a cell can span are evaluated: a coarse pass every ``COARSE`` columns finds, for
each cell, the nearest coarse columns on either side of its site that the polygon does not reach
(the polygon's x-extent is an interval containing the site), and the fine pass evaluates the packed
list of (robot, column) pairs in between.

When a cell has (almost) no importance mass the library falls back to CGAL's ``centroid`` of the
polygon's vertex range, i.e. the mean of the clipped polygon's vertices; :func:`polygon_vertex_means`
enumerates those vertices exactly (every pairwise line intersection that satisfies all constraints).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

MASS_EPS = 1e-10
"""Below this mass a cell's goal is its polygon's vertex mean (library's ``kEps``)."""
COARSE = 16
"""Column stride of the coarse pass that brackets each cell's x-extent."""


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


@dataclass(frozen=True)
class Cells:
    """Convex cells: sites [R, 2], competitors [R, M, 2] (``valid`` [R, M]) and boxes [R, 4].

    Each competitor m adds the half-plane d·(q - mid) <= 0 (d = other - site, mid = midpoint);
    at column centre x it reads y <= icpt_up + slope·x (d_y > 0) or y >= icpt_lo + slope·x (d_y < 0).
    Boxes (x0, y0, x1, y1) are in whole cells.
    """

    sites: np.ndarray
    others: np.ndarray
    valid: np.ndarray
    boxes: np.ndarray
    shared: np.ndarray | None = None
    """[R] bool, or None: robots standing on the same point as a lower-indexed robot (two robots
    put back into one corner, say). They share that robot's cell: its centroid is their goal too,
    but its mass and cost count once, for the lowest index."""

    def __post_init__(self) -> None:
        # Drop competitors whose half-plane holds the whole box (they cannot shape the cell), then
        # pack the remaining ones to the front so M shrinks to the largest count that matters.
        d = self.others - self.sites[:, None, :]
        mid = 0.5 * (self.others + self.sites[:, None, :])
        x0, y0, x1, y1 = (self.boxes[:, k : k + 1] for k in range(4))
        reach = (np.maximum(d[..., 0] * (x0 - mid[..., 0]), d[..., 0] * (x1 - mid[..., 0]))
                 + np.maximum(d[..., 1] * (y0 - mid[..., 1]), d[..., 1] * (y1 - mid[..., 1])))
        valid = self.valid & (reach > 0)
        order = np.argsort(~valid, axis=1, kind="stable")[:, : max(int(valid.sum(1).max()), 1)]
        object.__setattr__(self, "valid", np.take_along_axis(valid, order, 1))
        object.__setattr__(self, "others", np.take_along_axis(self.others, order[..., None], 1))
        d = self.others - self.sites[:, None, :]
        mid = 0.5 * (self.others + self.sites[:, None, :])
        dx, dy = d[..., 0], d[..., 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(self.valid & (dy != 0), -dx / dy, 0.0)
        icpt = mid[..., 1] - slope * mid[..., 0]
        # Upper bounds (d_y > 0) and lower bounds (d_y < 0) packed separately, each with the box
        # edge as one more (flat) bound, so evaluating a column needs no masking.
        r = len(self.sites)
        zero = np.zeros((r, 1))
        for name, mask, edge, fill in (("up", self.valid & (dy > 0), self.boxes[:, 3:4], np.inf),
                                       ("lo", self.valid & (dy < 0), self.boxes[:, 1:2], -np.inf)):
            k = max(int(mask.sum(1).max()), 0)
            order = np.argsort(~mask, axis=1, kind="stable")[:, :k]
            keep = np.take_along_axis(mask, order, 1)
            sl = np.where(keep, np.take_along_axis(slope, order, 1), 0.0)
            ic = np.where(keep, np.take_along_axis(icpt, order, 1), fill)
            object.__setattr__(self, f"slope_{name}", np.concatenate([sl, zero], 1))
            object.__setattr__(self, f"icpt_{name}", np.concatenate([ic, edge], 1))
        # Competitors level with the site (d_y = 0) bound x instead.
        flat = self.valid & (dy == 0) & (dx != 0)
        x_hi = np.where(flat & (dx > 0), mid[..., 0], np.inf).min(axis=1)
        x_lo = np.where(flat & (dx < 0), mid[..., 0], -np.inf).max(axis=1)
        object.__setattr__(self, "x_lo", np.maximum(x_lo, self.boxes[:, 0]))
        object.__setattr__(self, "x_hi", np.minimum(x_hi, self.boxes[:, 2]))

    def y_bounds(self, xc: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Continuous (y_lower, y_upper) [Q, C] at column centres xc [Q, C] (Q = R, or the robots
        ``rows`` [Q] when given), clipped to the boxes; y_lower >= y_upper where the cell is absent."""
        r = slice(None) if rows is None else rows
        x = xc[:, None, :]
        y_up = np.min(self.icpt_up[r][..., None] + self.slope_up[r][..., None] * x, axis=1)
        y_lo = np.max(self.icpt_lo[r][..., None] + self.slope_lo[r][..., None] * x, axis=1)
        outside = (xc < self.x_lo[r][:, None]) | (xc > self.x_hi[r][:, None])
        return y_lo, np.where(outside, -np.inf, y_up)

    def column_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Packed (robot [P], column [P]) pairs covering every column each cell can reach."""
        r = len(self.sites)
        x0, x1 = self.boxes[:, 0].astype(np.int64), self.boxes[:, 2].astype(np.int64)
        ncoarse = int(((x1 - x0 + COARSE - 1) // COARSE).max())
        coarse = x0[:, None] + COARSE * np.arange(ncoarse)[None]  # [R, K]
        y_lo, y_up = self.y_bounds(coarse + 0.5)
        absent = (y_lo >= y_up) | (coarse >= x1[:, None])
        site_col = self.sites[:, 0:1] - 0.5
        left = np.max(np.where(absent & (coarse < site_col), coarse, x0[:, None] - 1), axis=1)
        right = np.min(np.where(absent & (coarse > site_col), coarse, x1[:, None]), axis=1)
        counts = np.maximum(right - left - 1, 0)
        robot = np.repeat(np.arange(r), counts)
        starts = np.cumsum(counts) - counts
        column = left[robot] + 1 + (np.arange(counts.sum()) - starts[robot])
        return robot, column

    def row_intervals(self, robot: np.ndarray, column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows [lo, hi) of each (robot, column) pair, as the library rounds them: int64 [P].

        ``robot`` must be sorted (as :meth:`column_pairs` returns it): each robot's bounds are then
        repeated over its block of pairs instead of gathered pair by pair."""
        counts = np.bincount(robot, minlength=len(self.sites))
        rep = lambda a: np.repeat(a, counts, axis=0)  # noqa: E731
        x = (column + 0.5)[:, None]
        y_up = np.min(rep(self.icpt_up) + rep(self.slope_up) * x, axis=1)
        y_lo = np.max(rep(self.icpt_lo) + rep(self.slope_lo) * x, axis=1)
        outside = (x[:, 0] < rep(self.x_lo)) | (x[:, 0] > rep(self.x_hi))
        box = rep(self.boxes)
        lo = np.clip(np.floor(np.clip(y_lo, -1e9, 1e9) + 0.5), box[:, 1], box[:, 3])
        hi = np.clip(np.floor(np.clip(y_up, -1e9, 1e9) + 0.5), box[:, 1], box[:, 3])
        hi = np.where(outside, lo, np.maximum(hi, lo))
        return lo.astype(np.int64), hi.astype(np.int64)


class ColumnPrefix:
    """Prefix sums along y of a fixed map: Φ, Φ·y and Φ·y² per column, [3, W·(H + 1)] float64.

    Built once per map (an episode's world map never changes); afterwards the sum of Φ over rows
    lo..hi-1 of column c is ``p[0, c·(H+1) + hi] - p[0, c·(H+1) + lo]``.
    """

    def __init__(self, map_xy: np.ndarray):
        m = np.asarray(map_xy, dtype=np.float64)
        self.width, self.height = m.shape
        y = np.arange(self.height, dtype=np.float64) + 0.5
        p = np.zeros((3, self.width, self.height + 1))
        np.cumsum(m, axis=1, out=p[0, :, 1:])
        np.cumsum(m * y, axis=1, out=p[1, :, 1:])
        np.cumsum(m * (y * y), axis=1, out=p[2, :, 1:])
        self.p = p.reshape(3, -1)

    def interval_sums(self, column: np.ndarray, lo: np.ndarray, hi: np.ndarray, moments: int = 3) -> np.ndarray:
        """Sums of (Φ, Φ·y, Φ·y²)[:moments] over rows [lo, hi) of each column: [moments, P]."""
        base = column * (self.height + 1)
        p = self.p[:moments]
        return np.take(p, base + hi, axis=1) - np.take(p, base + lo, axis=1)


def reduce_cells(
    cells: Cells, robot: np.ndarray, column: np.ndarray, s: np.ndarray, with_cost: bool,
    with_centroids: bool = True,
) -> CellSums:
    """Reduce per-pair moments s [2 or 3, P] (Σ Φ, Σ Φ·y, Σ Φ·y²) to per-cell sums."""
    r = len(cells.sites)
    xc = column + 0.5
    mass = np.bincount(robot, s[0], minlength=r)
    first = np.stack([np.bincount(robot, s[0] * xc, minlength=r), np.bincount(robot, s[1], minlength=r)], 1)
    cost = None
    if with_cost:
        sx, sy = cells.sites[robot, 0], cells.sites[robot, 1]
        per = s[0] * (xc - sx) ** 2 + s[2] - 2.0 * sy * s[1] + sy * sy * s[0]
        cost = np.bincount(robot, per, minlength=r)
    with np.errstate(divide="ignore", invalid="ignore"):
        centroid = first / mass[:, None]
    empty = mass < MASS_EPS
    if with_centroids and empty.any():
        centroid[empty] = polygon_vertex_means(cells, np.nonzero(empty)[0])
    if cells.shared is not None:
        mass[cells.shared] = 0.0
        if cost is not None:
            cost[cells.shared] = 0.0
    return CellSums(mass, centroid, cost)


def polygon_vertex_means(cells: Cells, which: np.ndarray) -> np.ndarray:
    """Mean of the distinct vertices of the cells ``which`` (clipped polygons): [len(which), 2].

    Vertices are the pairwise intersections of the cell's lines (competitor bisectors and box
    edges) that satisfy every constraint; duplicates (several lines through one point) count once.
    """
    sites = cells.sites[which]
    others = cells.others[which]
    valid = cells.valid[which]
    boxes = cells.boxes[which]
    q = len(which)
    d = others - sites[:, None]
    a = np.where(valid[..., None], d, 0.0)  # a·v <= b
    b = np.where(valid, np.einsum("qmc,qmc->qm", d, 0.5 * (others + sites[:, None])), 1.0)
    box_a = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
    box_b = np.stack([-boxes[:, 0], boxes[:, 2], -boxes[:, 1], boxes[:, 3]], 1)
    a = np.concatenate([a, np.broadcast_to(box_a, (q, 4, 2))], 1)  # [Q, L, 2]
    b = np.concatenate([b, box_b], 1)
    live = np.concatenate([valid, np.ones((q, 4), bool)], 1)
    i, j = np.triu_indices(a.shape[1], 1)
    a1, a2, b1, b2 = a[:, i], a[:, j], b[:, i], b[:, j]
    det = a1[..., 0] * a2[..., 1] - a1[..., 1] * a2[..., 0]
    ok = live[:, i] & live[:, j] & (np.abs(det) > 1e-12 * np.linalg.norm(a1, axis=2) * np.linalg.norm(a2, axis=2))
    with np.errstate(divide="ignore", invalid="ignore"):
        vx = (b1 * a2[..., 1] - b2 * a1[..., 1]) / det
        vy = (a1[..., 0] * b2 - a2[..., 0] * b1) / det
    v = np.where(ok[..., None], np.stack([vx, vy], -1), 0.0)  # [Q, pairs, 2]
    slack = np.einsum("qlc,qpc->qpl", a, v) - b[:, None, :]
    tol = 1e-9 * (1.0 + np.abs(b)[:, None, :] + np.linalg.norm(a, axis=2)[:, None, :] * np.abs(v).sum(-1, keepdims=True))
    feasible = ok & np.all((slack <= tol) | ~live[:, None, :], axis=2)
    # Distinct vertices per cell, all cells at once: sort (cell, x, y), keep changes.
    vr = np.round(v, 7)
    cell = np.broadcast_to(np.arange(q)[:, None], feasible.shape)
    cell_f, x_f, y_f = cell[feasible], vr[..., 0][feasible], vr[..., 1][feasible]
    order = np.lexsort((y_f, x_f, cell_f))
    cell_f, x_f, y_f = cell_f[order], x_f[order], y_f[order]
    new = np.ones(len(cell_f), bool)
    new[1:] = (cell_f[1:] != cell_f[:-1]) | (x_f[1:] != x_f[:-1]) | (y_f[1:] != y_f[:-1])
    count = np.bincount(cell_f[new], minlength=q)
    sums = np.stack([np.bincount(cell_f[new], x_f[new], minlength=q), np.bincount(cell_f[new], y_f[new], minlength=q)], 1)
    out = sites.copy()  # a cell with no vertex cannot occur; keep the site if it ever does
    has = count > 0
    out[has] = sums[has] / count[has, None]
    return out


def world_cells(sites_m: np.ndarray, world_size: int) -> Cells:
    """Voronoi cells of all robots over the whole world (Delaunay neighbours as competitors).

    Robots on one point share one cell (see :attr:`Cells.shared`), so J stays the integral of the
    squared distance to the nearest robot: without this, Qhull leaves a duplicate site without
    neighbours and its "cell" would be the whole world."""
    sites_m = np.asarray(sites_m, dtype=np.float64)
    boxes = np.broadcast_to(np.array([0.0, 0.0, world_size, world_size]), (len(sites_m), 4))
    s = sites_m[np.lexsort(sites_m.T)]  # a cheap test first: this runs every control step
    if not (s[1:] == s[:-1]).all(axis=1).any():
        nbr, valid = delaunay_neighbours(sites_m)
        return Cells(sites_m, sites_m[nbr], valid, boxes)
    uniq, first, inverse = np.unique(sites_m, axis=0, return_index=True, return_inverse=True)
    rep = inverse.reshape(-1)  # robot -> its point in uniq
    nbr, valid = delaunay_neighbours(uniq)
    others = uniq[nbr][rep]
    return Cells(sites_m, others, valid[rep], boxes, shared=np.arange(len(sites_m)) != first[rep])


def voronoi_sums(prefix: ColumnPrefix, sites_m: np.ndarray, with_cost: bool = True) -> CellSums:
    """Masses, centroids (and costs) of every robot's Voronoi cell over a whole fixed map."""
    cells = world_cells(sites_m, prefix.width)
    robot, column = cells.column_pairs()
    lo, hi = cells.row_intervals(robot, column)
    s = prefix.interval_sums(column, lo, hi, 3 if with_cost else 2)
    return reduce_cells(cells, robot, column, s, with_cost)


def coverage_cost(prefix: ColumnPrefix, sites_m: np.ndarray) -> float:
    """J(X) = Σ_k Σ_{q in V_k} Φ(q) |q_c - x_k|² over the whole map (m²·importance)."""
    cells = world_cells(sites_m, prefix.width)
    robot, column = cells.column_pairs()
    lo, hi = cells.row_intervals(robot, column)
    s = prefix.interval_sums(column, lo, hi, 3)
    return float(reduce_cells(cells, robot, column, s, True, with_centroids=False).cost.sum())
