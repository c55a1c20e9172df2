"""Compiled kernels of the simulator's hot paths (numba, single-threaded, ``fastmath`` off).

Its kernels (docs/reports/2026-12-02-sim-speed.md):

- :func:`cell_sums` — each robot's Voronoi cell among its competitors, clipped to its box, walked
  column by column outward from the site (a convex cell's columns are one interval around it). Per
  column the cell's rows [lo, hi) are the library's rounding of the bisector envelopes, and the
  map's moments over them are two lookups in the world's column prefix table (clairvoyant goals,
  J) or four in a robot's block prefix sums (DCVT goals). Cells without importance fall back to
  the mean of their clipped polygon's vertices.
- :func:`refresh_blocks` — the block prefix sums of the robots' own maps, recomputed under the
  sensor squares of the robots that moved (and the whole map once per episode).
- :func:`column_prefix` — the world map's column prefix sums (ColumnPrefix), once per episode.
- :func:`resize_windows` — the antialiased bilinear resize of 256² windows of the robots' padded
  maps to 32², as a banded separable filter read straight from the maps.

Every kernel computes the same float64 (float32 for the maps) operations as the numpy code it
replaced, in the same order where that order decides the bits: the masses, centroids and costs are
sums over the cell's columns in ascending order (numpy's ``bincount`` order), the block sums are
sequential (numpy's ``cumsum``). Only the resize sums its taps in another order than the dense
products did (tests/sim/numpy_oracle.py keeps that numpy code as the tests' oracle).

The Python glue (argument preparation, dtypes, the shared-point rule) stays in the modules that call
these kernels: ``voronoi.py``, ``controllers.py``, ``robot_maps.py`` and ``observations.py``.
Compiled code is cached on disk (``cache=True``): in ``__pycache__`` beside this file, or under
``NUMBA_CACHE_DIR`` where the package directory is read-only.
"""

from __future__ import annotations

import numba
import numpy as np

BLOCK = 16  # rows per block of the robots' block prefix sums (robot_maps.BLOCK)

_jit = numba.njit(cache=True, error_model="numpy", nogil=True)
_inline = numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")  # small helpers: 20% faster walk


# --- the Voronoi cell of one robot ----------------------------------------------------------------
@_jit
def _cell_lines(r, sites, points, idx, valid, boxes, sl_up, ic_up, sl_lo, ic_lo, live):
    """Bisector lines of robot r's cell, as ``Cells`` built them: competitors whose half-plane does
    not hold the whole box, upper bounds (d_y > 0) and lower bounds (d_y < 0) of y at a column, the
    box's top and bottom edges as one more bound each, and the x-limits of level competitors
    (d_y = 0). Returns (n_up, n_lo, x_lo, x_hi, n_live); ``live`` gets the competitors kept."""
    sx, sy = sites[r, 0], sites[r, 1]
    x0, y0, x1, y1 = boxes[r, 0], boxes[r, 1], boxes[r, 2], boxes[r, 3]
    nu = 0
    nl = 0
    nlive = 0
    xhi = np.inf
    xlo = -np.inf
    for m in range(idx.shape[1]):
        if not valid[r, m]:
            continue
        o = idx[r, m]
        ox, oy = points[o, 0], points[o, 1]
        dx = ox - sx
        dy = oy - sy
        mx = 0.5 * (ox + sx)
        my = 0.5 * (oy + sy)
        reach = max(dx * (x0 - mx), dx * (x1 - mx)) + max(dy * (y0 - my), dy * (y1 - my))
        if not reach > 0:
            continue
        live[nlive] = o
        nlive += 1
        if dy != 0:
            slope = -dx / dy
        else:
            slope = 0.0
        icpt = my - slope * mx
        if dy > 0:
            sl_up[nu] = slope
            ic_up[nu] = icpt
            nu += 1
        elif dy < 0:
            sl_lo[nl] = slope
            ic_lo[nl] = icpt
            nl += 1
        elif dx > 0:
            xhi = min(xhi, mx)
        elif dx < 0:
            xlo = max(xlo, mx)
    sl_up[nu] = 0.0
    ic_up[nu] = y1
    sl_lo[nl] = 0.0
    ic_lo[nl] = y0
    return nu + 1, nl + 1, max(xlo, x0), min(xhi, x1), nlive


@_inline
def _round_row(y, b0, b1):
    """floor(y + 0.5) clipped to the box's rows [b0, b1], as the library rounds a row bound."""
    v = np.floor(min(max(y, -1e9), 1e9) + 0.5)
    return int(min(max(v, b0), b1))


@_inline
def _block_prefix(within, cum, r, c, h, nb):
    """Σ (map, map·(y + 0.5)) of robot r's map over rows [0, h) of column c: whole blocks from
    ``cum``, the rest from the running sums inside h's block (RobotMaps.row_sums' lookups)."""
    b = h // BLOCK
    t = h - b * BLOCK
    p0 = 0.0
    p1 = 0.0
    if t != 0:
        bb = min(b, nb - 1)
        p0 = np.float64(within[r, c, bb, t - 1, 0])
        p1 = np.float64(within[r, c, bb, t - 1, 1])
        p1 = p1 + np.float64(b * BLOCK) * p0
    return cum[r, c, b, 0] + p0, cum[r, c, b, 1] + p1


@_jit
def _vertex_mean(r, sites, points, live, nlive, boxes):
    """Mean of the distinct vertices of robot r's clipped cell polygon (``polygon_vertex_means``):
    every pairwise intersection of its lines (live bisectors, then the box's four edges) that
    satisfies all of them, rounded to 1e-7 m, duplicates once; summed in (x, y) order."""
    sx, sy = sites[r, 0], sites[r, 1]
    nlines = nlive + 4
    ax = np.empty(nlines)
    ay = np.empty(nlines)
    bb = np.empty(nlines)
    for k in range(nlive):
        o = live[k]
        dx = points[o, 0] - sx
        dy = points[o, 1] - sy
        ax[k] = dx
        ay[k] = dy
        bb[k] = dx * (0.5 * (points[o, 0] + sx)) + dy * (0.5 * (points[o, 1] + sy))
    ax[nlive], ay[nlive], bb[nlive] = -1.0, 0.0, -boxes[r, 0]
    ax[nlive + 1], ay[nlive + 1], bb[nlive + 1] = 1.0, 0.0, boxes[r, 2]
    ax[nlive + 2], ay[nlive + 2], bb[nlive + 2] = 0.0, -1.0, -boxes[r, 1]
    ax[nlive + 3], ay[nlive + 3], bb[nlive + 3] = 0.0, 1.0, boxes[r, 3]
    norm = np.empty(nlines)
    for k in range(nlines):
        norm[k] = np.sqrt(ax[k] * ax[k] + ay[k] * ay[k])
    vx = np.empty(nlines * (nlines - 1) // 2)
    vy = np.empty_like(vx)
    nv = 0
    for i in range(nlines):
        for j in range(i + 1, nlines):
            det = ax[i] * ay[j] - ay[i] * ax[j]
            if not (abs(det) > 1e-12 * norm[i] * norm[j]):
                continue
            px = (bb[i] * ay[j] - bb[j] * ay[i]) / det
            py = (ax[i] * bb[j] - ax[j] * bb[i]) / det
            sabs = abs(px) + abs(py)
            ok = True
            for k in range(nlines):
                slack = (ax[k] * px + ay[k] * py) - bb[k]
                if not (slack <= 1e-9 * ((1.0 + abs(bb[k])) + norm[k] * sabs)):
                    ok = False
                    break
            if not ok:
                continue
            # np.round(v, 7), then insertion into the (x, y)-sorted list
            qx = np.rint(px * 1e7) / 1e7
            qy = np.rint(py * 1e7) / 1e7
            k = nv
            while k > 0 and (vx[k - 1] > qx or (vx[k - 1] == qx and vy[k - 1] > qy)):
                vx[k] = vx[k - 1]
                vy[k] = vy[k - 1]
                k -= 1
            vx[k] = qx
            vy[k] = qy
            nv += 1
    count = 0
    sumx = 0.0
    sumy = 0.0
    for k in range(nv):
        if k > 0 and vx[k] == vx[k - 1] and vy[k] == vy[k - 1]:
            continue
        count += 1
        sumx += vx[k]
        sumy += vy[k]
    if count == 0:  # a cell with no vertex cannot occur; keep the site if it ever does
        return sx, sy
    return sumx / count, sumy / count


WALK = 16  # columns whose bounds one pass of _walk takes at once


@_inline
def _walk(c, step, cx0, cx1, sl_up, ic_up, nu, sl_lo, ic_lo, nl, xlo, xhi, b0, b1, rows, env_up, env_lo):
    """The cell's columns from column c on in direction ``step`` (±1) inside the box's [cx0, cx1):
    returns the first one it does not reach (or the box's end), each one it reaches having its
    rounded rows [lo, hi) in ``rows[c]``. The cell reaches column c when its centre x = c + 0.5 lies
    in [xlo, xhi] and its bounds there are not empty: y_lower < y_upper, the highest lower bound
    and the lowest upper one (``icpt + slope * x``). The bounds are taken WALK columns at a time
    (``env_up``, ``env_lo``: WALK each), bound by bound, then the columns are checked in order."""
    while cx0 <= c < cx1:
        n = min(WALK, cx1 - c if step > 0 else c - cx0 + 1)
        for i in range(n):
            env_up[i] = np.inf
            env_lo[i] = -np.inf
        for k in range(nu):
            a, b = ic_up[k], sl_up[k]
            for i in range(n):
                v = a + b * ((c + step * i) + 0.5)
                env_up[i] = v if v < env_up[i] else env_up[i]
        for k in range(nl):
            a, b = ic_lo[k], sl_lo[k]
            for i in range(n):
                v = a + b * ((c + step * i) + 0.5)
                env_lo[i] = v if v > env_lo[i] else env_lo[i]
        for i in range(n):
            col = c + step * i
            xc = col + 0.5
            if xc < xlo or xc > xhi or env_lo[i] >= env_up[i]:
                return col
            lo = _round_row(env_lo[i], b0, b1)
            rows[col, 0] = lo
            rows[col, 1] = max(_round_row(env_up[i], b0, b1), lo)
        c += step * n
    return c


@_jit
def cell_sums(sites, points, idx, valid, boxes, table, within, cum, with_cost, with_centroids, mass_eps):
    """Per-robot sums over Voronoi cells: (mass [R], centroid [R, 2], cost [R]) float64.

    Robot r's cell: the points ``points[idx[r, m]]`` where ``valid[r, m]`` compete with
    ``sites[r]``; the cell is clipped to ``boxes[r]`` = (x0, y0, x1, y1), whole cells.
    Map: with a non-empty ``table`` [W, H + 1, 4] (ColumnPrefix: prefix sums along y of Φ, Φ·y,
    Φ·y² per column) the world map; otherwise robot r's own map through ``within`` and ``cum``
    (RobotMaps' block prefix sums; ``cost`` is then 0). ``with_cost``: also Σ Φ |q - x_r|².
    ``with_centroids``: cells with mass < ``mass_eps`` get their polygon's vertex mean (otherwise
    mass/first moments, NaN for an empty cell)."""
    nr = sites.shape[0]
    m = idx.shape[1]
    world = table.shape[0] > 0
    nb = within.shape[2]
    mass = np.zeros(nr)
    centroid = np.empty((nr, 2))
    cost = np.zeros(nr)
    sl_up = np.empty(m + 1)
    ic_up = np.empty(m + 1)
    sl_lo = np.empty(m + 1)
    ic_lo = np.empty(m + 1)
    live = np.empty(m, np.int64)
    ncol = 0
    for r in range(nr):
        ncol = max(ncol, int(boxes[r, 2]) + 1)
    rows = np.empty((max(ncol, 1), 2), np.int64)
    env_up = np.empty(WALK)
    env_lo = np.empty(WALK)
    for r in range(nr):
        nu, nl, xlo, xhi, nlive = _cell_lines(r, sites, points, idx, valid, boxes, sl_up, ic_up, sl_lo, ic_lo, live)
        sx, sy = sites[r, 0], sites[r, 1]
        cx0 = int(boxes[r, 0])
        cx1 = int(boxes[r, 2])
        b0, b1 = boxes[r, 1], boxes[r, 3]
        # the cell's columns: one interval around the site's column, walked outward
        c = int(np.floor(sx - 0.5))
        left = _walk(c, -1, cx0, cx1, sl_up, ic_up, nu, sl_lo, ic_lo, nl, xlo, xhi, b0, b1, rows, env_up, env_lo)
        right = _walk(c + 1, 1, cx0, cx1, sl_up, ic_up, nu, sl_lo, ic_lo, nl, xlo, xhi, b0, b1, rows, env_up, env_lo)
        left, right = max(left + 1, cx0), min(right, cx1)
        # then summed in ascending column order (numpy's bincount order)
        s_m = 0.0
        s_x = 0.0
        s_y = 0.0
        s_c = 0.0
        sy2 = 2.0 * sy
        syy = sy * sy
        for c in range(left, right):
            xc = c + 0.5
            lo = rows[c, 0]
            hi = rows[c, 1]
            if world:
                s0 = table[c, hi, 0] - table[c, lo, 0]
                s1 = table[c, hi, 1] - table[c, lo, 1]
                s_m += s0
                s_x += s0 * xc
                s_y += s1
                if with_cost:
                    s2 = table[c, hi, 2] - table[c, lo, 2]
                    d = xc - sx
                    s_c += s0 * (d * d) + s2 - sy2 * s1 + syy * s0
            else:
                h0, h1 = _block_prefix(within, cum, r, c, hi, nb)
                l0, l1 = _block_prefix(within, cum, r, c, lo, nb)
                s0 = h0 - l0
                s_m += s0
                s_x += s0 * xc
                s_y += h1 - l1
        mass[r] = s_m
        cost[r] = s_c
        if with_centroids and s_m < mass_eps:
            centroid[r, 0], centroid[r, 1] = _vertex_mean(r, sites, points, live, nlive, boxes)
        else:
            centroid[r, 0] = s_x / s_m
            centroid[r, 1] = s_y / s_m
    return mass, centroid, cost


@_jit
def block_row_sums(within, cum, robot, column, lo, hi):
    """RobotMaps.row_sums: Σ robot's map over rows [lo, hi) of a column, and Σ map·(y + 0.5)."""
    p = robot.shape[0]
    nb = within.shape[2]
    s0 = np.empty(p)
    s1 = np.empty(p)
    for k in range(p):
        h0, h1 = _block_prefix(within, cum, robot[k], column[k], hi[k], nb)
        l0, l1 = _block_prefix(within, cum, robot[k], column[k], lo[k], nb)
        s0[k] = h0 - l0
        s1[k] = h1 - l1
    return s0, s1


# --- the world map's column prefix sums -----------------------------------------------------------
@_jit
def column_prefix(map_xy, table):
    """ColumnPrefix.table of a float64 map [W, H] into ``table [W, H + 1, 4]`` float64: slot k of row
    j + 1 the sum of Φ·y^k (k = 0, 1, 2; y = j' + 0.5) over rows j' <= j of the column, row 0 and
    slot 3 zero. Sequential sums from the first term, as numpy's ``cumsum`` of ``m``, ``m * y`` and
    ``m * (y * y)`` (the same bits), all three in one pass."""
    w, h = map_xy.shape
    for c in range(w):
        m = map_xy[c]
        t = table[c]
        t[0, :] = 0.0
        s0 = s1 = s2 = 0.0
        for j in range(h):
            y = j + 0.5
            v0 = m[j]
            v1 = m[j] * y
            v2 = m[j] * (y * y)
            if j == 0:  # cumsum's first sum is its first term (-0.0 stays -0.0)
                s0, s1, s2 = v0, v1, v2
            else:
                s0, s1, s2 = s0 + v0, s1 + v1, s2 + v2
            t[j + 1, 0] = s0
            t[j + 1, 1] = s1
            t[j + 1, 2] = s2
            t[j + 1, 3] = 0.0


# --- sensing and the block prefix sums of the robots' own maps ----------------------------------------------------
@_jit
def sense_squares(maps_padded, sources, origins, lo, hi, last_lo, last_hi):
    """Copy into each robot n's map its square [x0, x1) × [y0, y1), (x0, y0) = lo[n], (x1, y1) = hi[n]
    (clipped to the padded maps), cell (x, y) from ``sources[n]`` (or ``sources[0]`` when there is
    one source for all: the padded world) at (x, y) − ``origins[n]``: only the cells outside its
    previous square [last_lo[n], last_hi[n]), which the previous call already copied (the world does
    not change), so a robot one cell on copies one new row and one new column of its square, not all of it."""
    for n in range(lo.shape[0]):
        x0, y0, x1, y1 = lo[n, 0], lo[n, 1], hi[n, 0], hi[n, 1]
        px0, py0, px1, py1 = last_lo[n, 0], last_lo[n, 1], last_hi[n, 0], last_hi[n, 1]
        if x0 == px0 and y0 == py0 and x1 == px1 and y1 == py1:
            continue
        source = sources[min(n, sources.shape[0] - 1)]
        ox, oy = origins[n, 0], origins[n, 1]
        for x in range(x0, x1):
            dst = maps_padded[n, x]
            src = source[x - ox]
            if px0 <= x < px1 and py0 < py1:  # a row the previous square covered in [py0, py1)
                for y in range(y0, min(y1, py0)):
                    dst[y] = src[y - oy]
                for y in range(max(y0, py1), y1):
                    dst[y] = src[y - oy]
            else:
                for y in range(y0, y1):
                    dst[y] = src[y - oy]


@_jit
def mark_explored(explored, lo, hi, block):
    """Mark in ``explored [N, B, B]`` the blocks of ``block`` cells that robot n's square
    [lo[n], hi[n]) covers whole (idempotent: a square already marked changes nothing)."""
    for n in range(lo.shape[0]):
        for bx in range(-(-lo[n, 0] // block), hi[n, 0] // block):
            for by in range(-(-lo[n, 1] // block), hi[n, 1] // block):
                explored[n, bx, by] = True


@_jit
def refresh_blocks(maps_padded, pad, within, tot, cum, cells, sensor_half):
    """Recompute the block sums of every robot whose ``cells[r]`` is a cell (not < -2^39) under its
    sensor square: world columns and 16-row blocks that the square [c - s/2, c + s/2) touches.

    ``within`` [N, W, W/16, 16, 2] float32: running sums of (map, map·(t + 0.5)) inside each block
    (t the row's offset in it); ``tot`` [N, W, W/16, 2] float64: the block totals, second moment in
    world rows; ``cum`` [N, W, W/16 + 1, 2] float64: sums of the whole blocks below. All sequential,
    as numpy's cumsum (bit-identical to the numpy refresh)."""
    n = cells.shape[0]
    w = within.shape[1]
    nb = within.shape[2]
    for r in range(n):
        if cells[r, 0] < -(1 << 39):
            continue
        c0 = max(cells[r, 0] - sensor_half, 0)
        c1 = min(cells[r, 0] + sensor_half, w)
        y0 = max(cells[r, 1] - sensor_half, 0)
        y1 = min(cells[r, 1] + sensor_half, w)
        if c0 >= c1 or y0 >= y1:
            continue
        _refresh_columns(maps_padded, pad, within, tot, cum, r, c0, c1, y0 // BLOCK, (y1 - 1) // BLOCK + 1, nb)


@_jit
def refresh_all(maps_padded, pad, within, tot, cum, lo, hi):
    """Every block of every robot's map (once per episode, when the block sums are first asked for),
    into ``within``, ``tot`` and ``cum`` that hold zeros: robot r's map may be non-zero only inside its
    sensed box [lo[r], hi[r]) (padded cells), so only the columns and blocks that box touches are
    computed; the others' sums are the zeros they hold (the same bits: sums of +0.0)."""
    w, nb = within.shape[1], within.shape[2]
    for r in range(within.shape[0]):
        c0 = max(lo[r, 0] - pad, 0)
        c1 = min(hi[r, 0] - pad, w)
        y0 = max(lo[r, 1] - pad, 0)
        y1 = min(hi[r, 1] - pad, w)
        if c0 < c1 and y0 < y1:
            _refresh_columns(maps_padded, pad, within, tot, cum, r, c0, c1, y0 // BLOCK, (y1 - 1) // BLOCK + 1, nb)


@_jit
def _refresh_columns(maps_padded, pad, within, tot, cum, r, c0, c1, blo, bhi, nb):
    half = np.float32(0.5)
    for c in range(c0, c1):
        row = maps_padded[r, c + pad]
        for b in range(blo, bhi):
            a0 = np.float32(0.0)
            a1 = np.float32(0.0)
            base = pad + b * BLOCK
            for t in range(BLOCK):
                v = row[base + t]
                a0 = a0 + v
                a1 = a1 + v * (np.float32(t) + half)
                within[r, c, b, t, 0] = a0
                within[r, c, b, t, 1] = a1
            t0 = np.float64(a0)
            tot[r, c, b, 0] = t0
            tot[r, c, b, 1] = np.float64(a1) + np.float64(b * BLOCK) * t0
        acc0 = 0.0
        acc1 = 0.0
        for b in range(nb):
            acc0 += tot[r, c, b, 0]
            acc1 += tot[r, c, b, 1]
            cum[r, c, b + 1, 0] = acc0
            cum[r, c, b + 1, 1] = acc1


# --- observations: antialiased resize of windows of the maps --------------------------------------
@_jit
def resize_windows(maps, starts, size, first, ntaps, weights, bbox, out):
    """out[k] = R · maps[k, x0 : x0 + size, y0 : y0 + size] · Rᵀ for (x0, y0) = starts[k], float32.

    R [O, size] is banded: row i has ``ntaps[i]`` weights ``weights[i, :ntaps[i]]`` from column
    ``first[i]``. First along x (whole contiguous rows of the window, vectorised over y), then
    along y on the [O, size] intermediate. ``bbox[k]`` = (x0, x1, y0, y1) bounds, in the maps'
    own coordinates, the part of map k that may be non-zero: rows and columns outside it are
    skipped (their terms are exact zeros, so the result is the same bit for bit)."""
    nk = maps.shape[0]
    no = first.shape[0]
    tmp = np.empty((no, size), np.float32)
    tmp_t = np.empty((size, no), np.float32)
    acc = np.empty((no, no), np.float32)
    for k in range(nk):
        x0 = starts[k, 0]
        y0 = starts[k, 1]
        ya = min(max(bbox[k, 2] - y0, 0), size)
        yb = min(max(bbox[k, 3] - y0, ya), size)
        tmp[:, :] = 0.0
        for i in range(no):
            for t in range(ntaps[i]):
                x = x0 + first[i] + t
                if x < bbox[k, 0] or x >= bbox[k, 1]:
                    continue
                wgt = weights[i, t]
                src = maps[k, x, y0 + ya : y0 + yb]
                dst = tmp[i, ya:yb]
                for y in range(yb - ya):
                    dst[y] += wgt * src[y]
        for y in range(size):
            for i in range(no):
                tmp_t[y, i] = tmp[i, y]
        acc[:, :] = 0.0
        for j in range(no):
            for t in range(ntaps[j]):
                wgt = weights[j, t]
                src = tmp_t[first[j] + t]
                dst = acc[j]
                for i in range(no):
                    dst[i] += wgt * src[i]
        for i in range(no):
            for j in range(no):
                out[k, i, j] = acc[j, i]
