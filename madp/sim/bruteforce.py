"""Brute-force Voronoi sums: assign every cell centre to its nearest robot, then sum.

The obvious implementation, kept as an independent oracle in the tests (``madp bench sim`` measures
madp against the Coverage Control Library itself). Chunked over columns so memory stays bounded; still O(W² · N).
"""

from __future__ import annotations

import numpy as np


def brute_force_sums(map_xy: np.ndarray, sites_m: np.ndarray, chunk: int = 64):
    """(mass [N], centroid [N, 2], cost [N]) by nearest-site assignment of every cell centre."""
    w, h = map_xy.shape
    n = len(sites_m)
    y = np.arange(h) + 0.5
    mass = np.zeros(n)
    first = np.zeros((n, 2))
    cost = np.zeros(n)
    for c0 in range(0, w, chunk):  # chunks of columns, each fully vectorised
        x = np.arange(c0, min(c0 + chunk, w)) + 0.5
        qx, qy = np.meshgrid(x, y, indexing="ij")
        d2 = (qx[..., None] - sites_m[:, 0]) ** 2 + (qy[..., None] - sites_m[:, 1]) ** 2
        owner = d2.argmin(axis=2).ravel()
        phi = map_xy[c0 : c0 + len(x)].ravel()
        mass += np.bincount(owner, phi, n)
        first[:, 0] += np.bincount(owner, phi * qx.ravel(), n)
        first[:, 1] += np.bincount(owner, phi * qy.ravel(), n)
        cost += np.bincount(owner, phi * np.take_along_axis(d2.reshape(-1, n), owner[:, None], 1)[:, 0], n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return mass, first / mass[:, None], cost
