"""The numpy implementations that madp's compiled kernels (madp/sim/kernels.py) replaced, kept as
the tests' oracle: Voronoi cells by a coarse column pass, packed (robot, column) pairs and
vectorised bisector envelopes; the block prefix sums' numpy refresh; the dense resize matrix products.

Moved here unchanged from madp/sim/voronoi.py, robot_maps.py, observations.py and controllers.py
(commit before "numba kernels"). tests/sim/test_kernels.py compares the kernels against them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from madp.sim.observations import resize_matrix
from madp.sim.robot_maps import RobotMaps
from madp.sim.voronoi import MASS_EPS, CellSums, delaunay_neighbours

COARSE = 16
"""Column stride of the coarse pass that brackets each cell's x-extent."""
BLOCK = 16
_OFFSETS = np.arange(BLOCK, dtype=np.float32) + np.float32(0.5)  # a row's centre within its block


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


class NumpyColumnPrefix:
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


def voronoi_sums(prefix: NumpyColumnPrefix, sites_m: np.ndarray, with_cost: bool = True) -> CellSums:
    """Masses, centroids (and costs) of every robot's Voronoi cell over a whole fixed map."""
    cells = world_cells(sites_m, prefix.width)
    robot, column = cells.column_pairs()
    lo, hi = cells.row_intervals(robot, column)
    s = prefix.interval_sums(column, lo, hi, 3 if with_cost else 2)
    return reduce_cells(cells, robot, column, s, with_cost)


def coverage_cost(prefix: NumpyColumnPrefix, sites_m: np.ndarray) -> float:
    """J(X) = Σ_k Σ_{q in V_k} Φ(q) |q_c - x_k|² over the whole map (m²·importance)."""
    cells = world_cells(sites_m, prefix.width)
    robot, column = cells.column_pairs()
    lo, hi = cells.row_intervals(robot, column)
    s = prefix.interval_sums(column, lo, hi, 3)
    return float(reduce_cells(cells, robot, column, s, True, with_centroids=False).cost.sum())


def clairvoyant_goals(positions_m: np.ndarray, prefix: NumpyColumnPrefix, world_size: int) -> tuple[np.ndarray, np.ndarray]:
    """ClairvoyantCVT.goals as numpy computed it: (goals [N, 2], masses [N])."""
    cells = world_cells(positions_m, world_size)
    robot, column = cells.column_pairs()
    lo, hi = cells.row_intervals(robot, column)
    sums = reduce_cells(cells, robot, column, prefix.interval_sums(column, lo, hi, 2), False)
    return sums.centroid_m, sums.mass


def dcvt_goals(env, maps: "NumpyRobotMaps") -> tuple[np.ndarray, np.ndarray]:
    """DecentralizedCVT.goals as numpy computed it, on ``maps`` (a NumpyRobotMaps with env's maps)."""
    p = env.params
    x = env.positions_m
    n, s, w = len(x), p.local_map_size, p.world_size
    base = env.cells() - s // 2
    boxes = np.concatenate([np.maximum(base, 0), np.minimum(base + s, w)], axis=1).astype(np.float64)
    cells = Cells(x, np.broadcast_to(x[None], (n, n, 2)), env.neighbours(), boxes)
    robot, column = cells.column_pairs()
    lo, hi = cells.row_intervals(robot, column)
    s0, s1 = maps.row_sums(robot, column, lo, hi)
    sums = reduce_cells(cells, robot, column, np.stack([s0, s1]), False)
    return sums.centroid_m, sums.mass


class NumpyRobotMaps(RobotMaps):
    """RobotMaps whose block prefix sums are refreshed and read by the numpy code (the oracle)."""

    def block_sums(self):
        return self._refresh()

    def _running_sums(self, robots: np.ndarray, cols: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        """Within-block running sums of (map, map·(t + 0.5)), t the row's offset in its block, for
        the consecutive blocks first[R] .. first + B - 1 of columns [R, C]: [R, C, B, 16, 2] float32;
        entry t sums rows 0..t of its block."""
        wp = self.maps_padded.shape[1]
        nrows = blocks.shape[1] * BLOCK
        start = (robots[:, None] * wp + cols + self.pad) * wp + self.pad + blocks[:, :1] * BLOCK  # [R, C]
        vals = np.take(self.maps_padded.reshape(-1), start[:, :, None] + np.arange(nrows))
        vals = vals.reshape(*cols.shape, blocks.shape[1], BLOCK)
        out = np.empty(vals.shape + (2,), np.float32)
        np.cumsum(vals, axis=-1, out=out[..., 0])
        np.cumsum(vals * _OFFSETS, axis=-1, out=out[..., 1])
        return out

    def _refresh(self) -> tuple[np.ndarray, np.ndarray]:
        n, w = len(self.maps_padded), self.world_size
        nb = w // BLOCK
        if self._cum is None:
            self._within = np.empty((n, w, nb, BLOCK, 2), np.float32)
            self._tot = np.empty((n, w, nb, 2))
            all_cols = np.arange(w)
            for r in range(n):  # once per episode
                self._within[r] = self._within_of(r, all_cols)
                self._tot[r] = self._block_totals(self._within[r], 0)
            self._cum = np.zeros((n, w, nb + 1, 2))
            np.cumsum(self._tot, axis=2, out=self._cum[:, :, 1:])
            self._stale.clear()
        within = self._within.reshape(-1, BLOCK, 2)
        tot, cum = self._tot.reshape(-1, nb, 2), self._cum.reshape(-1, nb + 1, 2)
        for cells in self._stale:
            robots = np.flatnonzero(cells[:, 0] > -(1 << 39))
            c = cells[robots]
            cols = np.clip(c[:, 0:1] - self.sensor_half + np.arange(2 * self.sensor_half), 0, w - 1)  # [R, 64]
            first = np.clip(c[:, 1] - self.sensor_half, 0, w - 1) // BLOCK
            nblk = min(2 * self.sensor_half // BLOCK + 1, nb)  # a sensor square may span the whole world
            first = np.minimum(first, nb - nblk)  # keep the 5 consecutive blocks inside the map
            blocks = first[:, None] + np.arange(nblk)  # [R, 5]
            line = robots[:, None] * w + cols  # [R, 64]
            rs = self._running_sums(robots, cols, blocks)
            within[(line[:, :, None] * nb + blocks[:, None, :]).reshape(-1)] = rs.reshape(-1, BLOCK, 2)
            tot_lines = tot[line.reshape(-1)]  # [R·64, nb, 2]
            tl = tot_lines.reshape(*line.shape, nb, 2)
            np.put_along_axis(tl, blocks[:, None, :, None], self._block_totals(rs, blocks[:, None, :]), axis=2)
            tot[line.reshape(-1)] = tot_lines
            cum[line.reshape(-1), 1:] = np.cumsum(tot_lines, axis=1)
        self._stale.clear()
        return self._cum, self._within

    def _within_of(self, r: int, cols: np.ndarray) -> np.ndarray:
        nb = self.world_size // BLOCK
        m = self.robot_map(r)[cols].reshape(len(cols), nb, BLOCK)
        out = np.empty((len(cols), nb, BLOCK, 2), np.float32)
        np.cumsum(m, axis=-1, out=out[..., 0])
        np.cumsum(m * _OFFSETS, axis=-1, out=out[..., 1])
        return out

    @staticmethod
    def _block_totals(running: np.ndarray, blocks) -> np.ndarray:
        """Per-block totals [..., B, 2] float64 of (map, map·(y + 0.5)) from running sums
        [..., B, 16, 2]; ``blocks`` (broadcastable to [..., B]) are the blocks' indices (0: all from 0)."""
        tot = running[..., BLOCK - 1, :].astype(np.float64)
        if np.isscalar(blocks):
            blocks = np.arange(tot.shape[-2])
        tot[..., 1] += np.asarray(blocks) * BLOCK * tot[..., 0]
        return tot

    def row_sums(self, robot: np.ndarray, column: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Σ robot's map over world rows [lo, hi) of world column, and Σ map·(y + 0.5): float64 [P] each.

        Prefix at row h = (whole blocks below h) + (running sum inside h's block up to row h - 1)."""
        cum, within = self._refresh()
        p = len(robot)
        r, c, h = np.concatenate([robot, robot]), np.concatenate([column, column]), np.concatenate([hi, lo])
        b, t = np.divmod(h, BLOCK)
        nb = within.shape[2]
        line = r * within.shape[1] + c
        cell = (line * nb + np.minimum(b, nb - 1)) * BLOCK + np.maximum(t - 1, 0)
        part = np.take(within.reshape(-1, 2), cell, axis=0).astype(np.float64)
        part[:, 1] += b * BLOCK * part[:, 0]  # block-local offsets → world rows
        part[t == 0] = 0.0
        total = np.take(cum.reshape(-1, 2), line * (nb + 1) + b, axis=0) + part
        d = total[:p] - total[p:]
        return d[:, 0], d[:, 1]



def resize_maps(maps: np.ndarray, out_size: int = 32) -> np.ndarray:
    """Antialiased bilinear resize of [..., S, S] maps to [..., out, out] (float32)."""
    r = resize_matrix(maps.shape[-1], out_size)
    lead, s = maps.shape[:-2], maps.shape[-1]
    # One large GEMM over every row of every map (y direction), then the small x-direction products.
    half = (maps.astype(np.float32, copy=False).reshape(-1, s) @ r.T).reshape(-1, s, out_size)
    return (r @ half).reshape(*lead, out_size, out_size)


