"""What one robot computes to choose among its K samples (:mod:`madp.selection` has the rules):
what it knows (:func:`map_views`, with the ``explore`` prior :func:`map_prior`: row i from robot i's
own map and neighbours alone; :func:`local_views` and :func:`explore_prior` compute them for every
robot of an environment at once, :class:`madp.robot.RobotAgent` for itself), the local
cell cost of each candidate (:func:`local_cell_costs`), the copy of a neighbourhood (:func:`joint_copy`) and what
a robot that hears no one does (:func:`lone_steps`). numpy and numba only (no torch): the robot
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

__all__ = ["GRID_M", "LocalViews", "explore_prior", "local_cell_costs", "local_views", "LONE_PRIOR_SHARE", "joint_copy",
           "lone_radius_m", "lone_steps", "map_prior", "map_views", "unexplored_blocks"]

#: Spacing (m) of the grid the local cell cost is summed on: 4 × 4 cells of a robot's map per point.
GRID_M = 4


@dataclass(frozen=True)
class LocalViews:
    """What each robot knows, one row per robot (R rows):

    ``start_m``, ``offset_m`` [R, 2]: its own position, as the motion rule integrates it;
    ``weights`` [R, G, G]: its own sensed map inside its local window, summed over blocks of
    GRID_M × GRID_M cells (float64); ``origin_m`` [R, 2]: the window's lower corner, so block (a, b)
    has its centre at ``origin_m + GRID_M * (a, b) + GRID_M / 2``;
    ``neighbours_m`` [R, M, 2]: the latest positions of its neighbours within r_c, padded;
    ``valid`` [R, M]: which of them are real; ``anchor_m`` [R, 2]: where it last heard a neighbour
    (its position estimate at that step; its first one until then), around which a robot that hears
    no one covers (:func:`lone_steps`). None: its own position. ``sensed`` [R, G, G]: the weights
    before a prior was added to its unexplored blocks (None: no prior was added). ``unexplored``
    [R, G, G] bool: its window's blocks inside the world it has not explored (:func:`unexplored_blocks`;
    None unless its rule reads them)."""

    start_m: np.ndarray
    offset_m: np.ndarray
    weights: np.ndarray
    origin_m: np.ndarray
    neighbours_m: np.ndarray
    valid: np.ndarray
    anchor_m: np.ndarray | None = None
    sensed: np.ndarray | None = None
    unexplored: np.ndarray | None = None

    def row(self, i: int) -> "LocalViews":
        """Robot i's row alone (R = 1)."""
        return LocalViews(*(None if v is None else v[i:i + 1] for v in
                            (self.start_m, self.offset_m, self.weights, self.origin_m, self.neighbours_m, self.valid,
                             self.anchor_m, self.sensed, self.unexplored)))


#: The share of a prior's mass on its unexplored blocks that a robot that hears no one counts
#: (:func:`lone_steps`): enough to go and look around its anchor, little enough not to sit there.
LONE_PRIOR_SHARE = 0.1


def lone_radius_m(params: SimParams) -> float:
    """The radius (m) of the disc a robot that hears no one covers: r_c, so that it stays where it
    could hear the neighbours it last heard if they are still about."""
    return float(params.comm_radius_m)


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
    return map_views(env.maps, own, start_m, offset_m, known, held_m, true_map, env.anchor_m)


def map_views(maps: RobotMaps, own_m: np.ndarray, start_m: np.ndarray, offset_m: np.ndarray, known: np.ndarray,
              held_m: np.ndarray, true_map: bool = False, anchor_m: np.ndarray | None = None) -> LocalViews:
    """The :class:`LocalViews` rows of the R robots of ``maps`` (one row each, from that robot's map
    alone): its map in the ``local_size`` window around its position estimate ``own_m [R, 2]`` (zero
    outside the world), its position as the motion rule integrates it, ``start_m + offset_m`` [R, 2],
    and the neighbours it knows of: ``held_m [R, M, 2]`` where ``known [R, M]``, kept in their order.
    ``true_map``: the maps' world map in the same window instead. ``anchor_m [R, 2]``: where each
    robot last heard a neighbour (None: its position estimate)."""
    s = maps.local_size
    g = s // GRID_M
    cells = robot_cells(own_m)
    starts = cells - s // 2 + maps.pad  # each window's lower corner in the padded maps
    if true_map:  # the world's map, non-zero anywhere
        grids, box = maps.world_padded[None], np.array([[0, maps.world_padded.shape[0]] * 2])
    else:  # each robot's own, zero outside its sensed box
        grids = maps.maps_padded
        box = np.stack([maps.seen_lo[:, 0], maps.seen_hi[:, 0], maps.seen_lo[:, 1], maps.seen_hi[:, 1]], 1)
    weights = _block_sums(grids, not true_map, starts, g, GRID_M, box)
    known, held_m = np.asarray(known, bool), np.asarray(held_m, np.float64).reshape(len(own_m), -1, 2)
    if known.shape[1] == 0:  # no neighbour held: one invalid slot
        known, held_m = np.zeros((len(own_m), 1), bool), np.zeros((len(own_m), 1, 2))
    m = max(int(known.sum(1).max()), 1)
    order = np.argsort(~known, axis=1, kind="stable")[:, :m]  # each robot's neighbours first
    valid = np.take_along_axis(known, order, 1)
    neighbours_m = np.take_along_axis(held_m, order[:, :, None], 1)
    anchor_m = np.array(own_m if anchor_m is None else anchor_m, dtype=np.float64).reshape(len(own_m), 2)
    return LocalViews(start_m, offset_m, weights, (cells - s // 2).astype(np.float64), neighbours_m, valid, anchor_m)


@numba.njit(cache=True, nogil=True)
def _block_sums(maps, own, starts, g, b, box):  # pragma: no cover (compiled)
    """[R, g, g] float64: the b × b block sums of robot r's window of ``maps[r if own else 0]``
    from padded corner ``starts[r]``; each block summed over its rows, then its columns (numpy's
    ``reshape(...).sum(2).sum(3)`` order: the same bits). ``box[r if own else 0]`` = (x0, x1, y0, y1)
    bounds, in the maps' coordinates, where that map may be non-zero (a robot's sensed box): the
    +0.0 cells outside it are not added (adding +0.0 to a sum that starts at +0.0 changes no bit).

    A block row's b map rows are added into one float64 sum per window column (whole contiguous
    rows, in row order; four rows side by side where b = 4), then each block adds its b column sums
    in column order."""
    s = g * b
    out = np.zeros((len(starts), g, g))
    col = np.empty(s)
    for r in range(len(starts)):
        m = maps[r if own else 0]
        k = r if own else 0
        x0, y0 = starts[r, 0], starts[r, 1]
        ya = min(max(box[k, 2] - y0, 0), s)  # the window's columns [ya, yb) that may be non-zero
        yb = min(max(box[k, 3] - y0, ya), s)
        if ya == yb:
            continue
        a0 = min(max(box[k, 0] - x0, 0), s) // b  # and its block rows [a0, a1)
        a1 = -(-min(max(box[k, 1] - x0, 0), s) // b)
        for a in range(a0, a1):
            xa = x0 + a * b
            part = col[ya:yb]
            if b == 4 and xa >= box[k, 0] and xa + 4 <= box[k, 1]:
                r0 = m[xa, y0 + ya : y0 + yb]
                r1 = m[xa + 1, y0 + ya : y0 + yb]
                r2 = m[xa + 2, y0 + ya : y0 + yb]
                r3 = m[xa + 3, y0 + ya : y0 + yb]
                for y in range(yb - ya):
                    part[y] = (((0.0 + r0[y]) + r1[y]) + r2[y]) + r3[y]
            else:
                part[:] = 0.0
                for x in range(max(xa, box[k, 0]), min(xa + b, box[k, 1])):
                    row = m[x, y0 + ya : y0 + yb]
                    for y in range(yb - ya):
                        part[y] += row[y]
            for c in range(ya // b, (yb - 1) // b + 1):
                total = 0.0
                for j in range(max(c * b, ya), min(c * b + b, yb)):
                    total += col[j]
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
    corner = views.origin_m.astype(np.int64) + maps.pad  # [N, 2]: each window's first cell, padded
    return replace(views, weights=_prior_weights(maps.explored, corner, views.weights, maps.pad, maps.world_size),
                   sensed=views.weights)


def unexplored_blocks(maps: RobotMaps, views: LocalViews) -> np.ndarray:
    """``[R, G, G]`` bool: the blocks of each robot's window inside the world that it has not explored
    (:func:`map_prior`'s rule: not every cell of the block explored)."""
    corner = views.origin_m.astype(np.int64) + maps.pad
    return _prior_weights(maps.explored, corner, np.zeros_like(views.weights), maps.pad, maps.world_size) > 0


@numba.njit(cache=True, nogil=True)
def _prior_weights(explored, corner, weights, pad, w):  # pragma: no cover (compiled)
    """:func:`map_prior`'s weights [R, G, G] float64 of the windows with corners ``corner [R, 2]``
    (padded cells) and block sums ``weights [R, G, G]``, from the explored maps ``explored [R, B, B]``.

    A window block is explored when every cell of it is: when the explored blocks of its four corner
    cells are. Window block a starts in explored block corner // 4 + a (GRID_M = EXPLORED_BLOCK_M) and
    reaches into the next one when the window's corner is not on the explored grid (per robot and
    axis); explored blocks past the map's last are read as its last. Inside: every cell of the block
    in the world. The mean mass of the explored blocks inside is their weights' sum (with +0.0 for
    every other block, summed as numpy's ``np.where(seen, weights, 0.0).sum((1, 2))``:
    :func:`_numpy_sum`) over their count (1 when that is not > 0)."""
    n, g = weights.shape[0], weights.shape[1]
    last = explored.shape[1] - 1
    out = np.empty_like(weights)
    seen = np.empty(g * g)  # robot r's weights of explored blocks inside, +0.0 elsewhere, row-major
    unexplored = np.empty(g * g, np.bool_)
    span_y = np.empty(g + 1, np.int64)
    in_y = np.empty(g, np.bool_)
    rows = np.empty(g + 1, np.bool_)  # explored along x, per explored block along y of the window
    for r in range(n):
        cx, cy = corner[r, 0], corner[r, 1]
        bx, by = cx // EXPLORED_BLOCK_M, cy // EXPLORED_BLOCK_M
        whole_x, whole_y = cx % EXPLORED_BLOCK_M == 0, cy % EXPLORED_BLOCK_M == 0  # not straddling
        for t in range(g + 1):
            span_y[t] = min(by + t, last)
        for c in range(g):
            in_y[c] = (cy + GRID_M * c >= pad) & (cy + GRID_M * c + GRID_M - 1 < pad + w)
        e = explored[r]
        count = 0
        for a in range(g):
            fx = cx + GRID_M * a
            in_x = (fx >= pad) & (fx + GRID_M - 1 < pad + w)
            ex0, ex1 = e[min(bx + a, last)], e[min(bx + a + 1, last)]
            for t in range(g + 1):
                rows[t] = ex0[span_y[t]] & (ex1[span_y[t]] | whole_x)
            for c in range(g):
                inside = in_x & in_y[c]
                done = rows[c] & (rows[c + 1] | whole_y)
                seen[a * g + c] = weights[r, a, c] if inside & done else 0.0
                count += inside & done
                unexplored[a * g + c] = inside & (not done)
        mass = (0.0 + _numpy_sum(seen, 0, g * g)) / max(count, 1)
        if not mass > 0:
            mass = 1.0
        for a in range(g):
            for c in range(g):
                out[r, a, c] = weights[r, a, c] + (mass if unexplored[a * g + c] else 0.0)
    return out


@numba.njit(cache=True, nogil=True)
def _numpy_sum(x, lo, n):  # pragma: no cover (compiled)
    """Σ x[lo : lo + n] (float64) as numpy's add.reduce sums a contiguous run, its pairwise summation
    (numpy's sum is 0.0 plus this): a run of at most 128 in eight running sums, a longer one as the
    sum of its two halves (the first a multiple of 8 long). Without recursion (numba's cache does not
    keep recursive functions): a stack of runs, whose sums are added two by two as they complete."""
    run_lo = np.empty(128, np.int64)
    run_n = np.empty(128, np.int64)
    split = np.zeros(128, np.bool_)  # the run on the stack was split: its two halves' sums are on `sums`
    sums = np.empty(128)
    runs, nsums = 1, 0
    run_lo[0], run_n[0] = lo, n
    while runs > 0:
        t = runs - 1
        start, size = run_lo[t], run_n[t]
        if split[t]:  # both halves done
            split[t] = False
            nsums -= 1
            sums[nsums - 1] = sums[nsums - 1] + sums[nsums]
            runs -= 1
        elif size > 128:
            half = size // 2
            half -= half % 8
            split[t] = True
            run_lo[runs], run_n[runs] = start + half, size - half
            run_lo[runs + 1], run_n[runs + 1] = start, half
            runs += 2
        else:
            sums[nsums] = _pairwise_run(x, start, size)
            nsums += 1
            runs -= 1
    return sums[0]


@numba.njit(cache=True, nogil=True, inline="always")
def _pairwise_run(x, lo, n):  # pragma: no cover (compiled)
    """numpy's pairwise sum of a run of at most 128: eight running sums, added in a tree, then the rest."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += x[lo + i]
        return res
    r0, r1, r2, r3 = x[lo], x[lo + 1], x[lo + 2], x[lo + 3]
    r4, r5, r6, r7 = x[lo + 4], x[lo + 5], x[lo + 6], x[lo + 7]
    i = 8
    while i < n - n % 8:
        r0 += x[lo + i]
        r1 += x[lo + i + 1]
        r2 += x[lo + i + 2]
        r3 += x[lo + i + 3]
        r4 += x[lo + i + 4]
        r5 += x[lo + i + 5]
        r6 += x[lo + i + 6]
        r7 += x[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += x[lo + i]
        i += 1
    return res


@numba.njit(cache=True, nogil=True)
def _cell_costs(y, weights, origin, nbr, valid, b):  # pragma: no cover (compiled)
    """[R, K]: Σ over the blocks of robot r's window closer to y[r, k] than to every valid neighbour
    (ties: its own) of weight · distance² to the block's centre (:func:`local_cell_costs`).

    Distances are ``(qx - px)**2 + (qy - py)**2``, the squares along y taken once per robot; a block
    row's distances to the nearest neighbour are taken for all its blocks at once. Each cost adds its
    blocks in row-major order, four costs side by side (four independent running sums); a block
    outside the cell adds +0.0 (which changes no bit of a sum that starts at +0.0), a block of zero
    weight nothing, and a row of zero weights is not visited."""
    r_n, k_n, g = y.shape[0], y.shape[1], weights.shape[1]
    m_n = nbr.shape[1]
    k4 = -(-k_n // 4) * 4  # K rounded up to fours: the costs past K are sums nobody reads
    out = np.zeros((r_n, k_n))
    px = np.empty(m_n)  # the valid neighbours' x
    ey = np.empty((m_n, g))  # (qy_c - py_m)² of the valid neighbours
    kx = np.zeros(k4)  # (qx - y_k,x)² of this block row
    ky = np.zeros((k4, g))  # (qy_c - y_k,y)²
    nearest = np.empty(g)  # this block row's squared distance to the nearest neighbour
    acc = np.empty(k4)
    for r in range(r_n):
        n = 0
        for m in range(m_n):
            if valid[r, m]:
                for c in range(g):
                    ey[n, c] = (origin[r, 1] + b * c + b / 2 - nbr[r, m, 1]) ** 2
                px[n] = nbr[r, m, 0]
                n += 1
        for k in range(k_n):
            for c in range(g):
                ky[k, c] = (origin[r, 1] + b * c + b / 2 - y[r, k, 1]) ** 2
        acc[:] = 0.0
        for a in range(g):
            w_row = weights[r, a]
            c = 0
            while c < g and w_row[c] == 0.0:
                c += 1
            if c == g:
                continue
            qx = origin[r, 0] + b * a + b / 2
            nearest[:] = np.inf
            for m in range(n):
                e = (qx - px[m]) ** 2
                row = ey[m]
                for c in range(g):
                    v = e + row[c]
                    nearest[c] = v if v < nearest[c] else nearest[c]
            for k in range(k_n):
                kx[k] = (qx - y[r, k, 0]) ** 2
            for k in range(0, k4, 4):
                s0, s1, s2, s3 = acc[k], acc[k + 1], acc[k + 2], acc[k + 3]
                x0, x1, x2, x3 = kx[k], kx[k + 1], kx[k + 2], kx[k + 3]
                y0, y1, y2, y3 = ky[k], ky[k + 1], ky[k + 2], ky[k + 3]
                for c in range(g):
                    w = w_row[c]
                    if w == 0.0:
                        continue
                    nr = nearest[c]
                    d = x0 + y0[c]
                    s0 += w * d if d <= nr else 0.0
                    d = x1 + y1[c]
                    s1 += w * d if d <= nr else 0.0
                    d = x2 + y2[c]
                    s2 += w * d if d <= nr else 0.0
                    d = x3 + y3[c]
                    s3 += w * d if d <= nr else 0.0
                acc[k], acc[k + 1], acc[k + 2], acc[k + 3] = s0, s1, s2, s3
        for k in range(k_n):
            out[r, k] = acc[k]
    return out


def local_cell_costs(views: LocalViews, actions_mps: np.ndarray, params: SimParams) -> np.ndarray:
    """Each robot's local cell cost of each of its candidates ``actions_mps [R, K, 2]`` (m/s): ``[R, K]``.

    Robot r moves to y = :func:`madp.sim.env.move` of its own position; its cell is the set of
    grid points of its window closer to y than to every valid neighbour (ties: its own); the cost is
    ``sum over the cell of weight · |q − y|²`` (J restricted to its own cell, on its own map,
    on a grid of GRID_M m: each block's mass at the block's centre). Uses ``views`` and the motion
    constants of ``params`` only."""
    y, _ = move(views.start_m[:, None], views.offset_m[:, None], actions_mps, params)  # [R, K, 2]
    return _cell_costs(np.ascontiguousarray(y, dtype=np.float64), views.weights, views.origin_m,
                       np.ascontiguousarray(views.neighbours_m, dtype=np.float64), views.valid, GRID_M)


def lone_steps(views: LocalViews, params: SimParams, radius_m: float | None = None,
               prior_share: float = LONE_PRIOR_SHARE) -> tuple[np.ndarray, np.ndarray]:
    """What a robot that holds no valid neighbour does instead of choosing among its samples:
    ``lone [R]`` bool (which robots hold none) and ``steps_mps [R, 2]`` (their rows only; the others
    0). Nothing bounds such a robot's cell but what it expects: the disc of ``radius_m`` (None:
    :func:`lone_radius_m`) around its ``anchor_m``, where it last heard a neighbour. It takes the Lloyd
    step toward the centroid of that disc's mass (block centres) on its sensed map plus ``prior_share``
    of the rule's prior on its unexplored blocks (``views.sensed`` and ``views.weights``; the weights alone where the
    rule adds no prior), ``min(|g − x| / Δt, u_max)`` from its position x as the motion rule
    integrates it, and stays where the disc holds no mass. Alone, a robot then covers what is around
    the place it last held, rather than follow the importance the whole swarm is after."""
    lone = ~views.valid.any(1)
    steps = np.zeros((len(lone), 2))
    if views.anchor_m is None or not lone.any():
        return lone, steps
    g = views.weights.shape[1]
    centre = np.arange(g) * GRID_M + GRID_M / 2  # [G]: block centres relative to the window's corner
    qx = views.origin_m[lone, 0, None] + centre[None]  # [L, G]
    qy = views.origin_m[lone, 1, None] + centre[None]
    ax, ay = views.anchor_m[lone, 0], views.anchor_m[lone, 1]
    d2 = (qx - ax[:, None])[:, :, None] ** 2 + (qy - ay[:, None])[:, None, :] ** 2  # [L, G, G]
    w = views.weights[lone]
    if views.sensed is not None:
        w = views.sensed[lone] + prior_share * (w - views.sensed[lone])
    radius_m = lone_radius_m(params) if radius_m is None else radius_m
    w = np.where(d2 <= radius_m ** 2, w, 0.0)
    mass = w.sum((1, 2))
    x = views.start_m[lone] + views.offset_m[lone]
    with np.errstate(invalid="ignore", divide="ignore"):
        goal = np.stack([(w.sum(2) * qx).sum(1), (w.sum(1) * qy).sum(1)], 1) / mass[:, None]
    goal = np.where((mass > 0)[:, None], goal, x)
    diff = goal - x
    dist = np.linalg.norm(diff, axis=1)
    speed = np.minimum(dist / params.dt_s, params.max_speed_mps)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where((dist > 0)[:, None], diff / dist[:, None] * speed[:, None], 0.0)
    steps[lone] = u
    return lone, steps


def joint_copy(costs: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Per robot, the copy k of least summed cost over its neighbourhood: ``costs [R, K]`` (each
    robot's own cost of its copy k), ``neighbours [R, R]`` bool (robot i holds robot j's costs of
    this step; the diagonal is counted whether set or not) -> ``[R]`` indices. Copy k of every
    neighbourhood starts from the same noise of each robot, so robots whose neighbourhoods agree on k
    keep actions of one joint sample (ties: the lowest k)."""
    near = np.asarray(neighbours, dtype=bool) | np.eye(len(costs), dtype=bool)
    return (near.astype(np.float64) @ np.asarray(costs, dtype=np.float64)).argmin(1)
