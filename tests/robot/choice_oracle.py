"""The selection rules' computations as madp/robot/choice.py had them before its kernels read only
the sensed box, shared squares between blocks and fused the ``explore`` prior, kept as the tests'
oracle (tests/robot/test_choice_kernels.py): each window's block sums in numpy (the loops' order),
the prior in numpy, the local cell cost as the loop over every block and neighbour it was.
"""

from __future__ import annotations

import numba
import numpy as np

from madp.robot.choice import GRID_M
from madp.sim.robot_maps import EXPLORED_BLOCK_M


def block_sums(maps: np.ndarray, own: bool, starts: np.ndarray, g: int, b: int) -> np.ndarray:
    """[R, g, g] float64: the b × b block sums of robot r's window of ``maps[r if own else 0]`` from
    padded corner ``starts[r]``, over its rows, then its columns (the whole window read)."""
    out = np.empty((len(starts), g, g))
    for r, (x0, y0) in enumerate(starts):
        window = maps[r if own else 0, x0 : x0 + g * b, y0 : y0 + g * b].astype(np.float64)
        out[r] = window.reshape(g, b, g, b).sum(1).sum(2)
    return out


def prior_weights(explored: np.ndarray, origin_m: np.ndarray, weights: np.ndarray, pad: int, w: int) -> np.ndarray:
    """``map_prior``'s weights [N, G, G], the numpy code it had."""
    g = weights.shape[1]
    corner = origin_m.astype(np.int64) + pad
    first = corner[:, :, None] + GRID_M * np.arange(g)
    last = first + GRID_M - 1
    lo = corner // EXPLORED_BLOCK_M
    straddles = (corner % EXPLORED_BLOCK_M != 0)[:, :, None, None]
    span = np.minimum(lo[:, :, None] + np.arange(g + 1), explored.shape[1] - 1)
    n = np.arange(len(corner))[:, None, None]
    slab = explored[n, span[:, 0, :, None], span[:, 1, None, :]]
    rows = slab[:, :-1] & (slab[:, 1:] | ~straddles[:, 0])
    done = rows[:, :, :-1] & (rows[:, :, 1:] | ~straddles[:, 1])
    inside = (first >= pad) & (last < pad + w)
    inside = inside[:, 0, :, None] & inside[:, 1, None, :]
    seen = done & inside
    mass = np.where(seen, weights, 0.0).sum((1, 2)) / np.maximum(seen.sum((1, 2)), 1)
    mass = np.where(mass > 0, mass, 1.0)
    return weights + np.where(inside & ~done, mass[:, None, None], 0.0)


@numba.njit(nogil=True)
def cell_costs(y, weights, origin, nbr, valid, b):  # pragma: no cover (compiled)
    """[R, K]: the local cell costs, every block against every valid neighbour and candidate."""
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

