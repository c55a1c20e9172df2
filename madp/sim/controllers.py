"""Classical controllers. Every controller is a callable ``controller(env) -> actions [N, 2] (m/s)``
that looks only at what it is allowed to see; learned policies implement the same interface.

- :class:`ClairvoyantCVT` (the expert): one Lloyd step per control step on the full world map.
- :class:`DecentralizedCVT`: each robot, on its own sensed map inside its 256 m local window, with
  only the neighbours within r_c.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .env import CoverageEnv
from .voronoi import (
    MASS_EPS,
    column_intervals,
    delaunay_neighbours,
    finish_centroids,
    moments_to_sums,
)

GOAL_EPS_M = 1e-10
BLOCK = 16  # rows per block for the block prefix sums over local maps


class Controller(Protocol):
    name: str

    def __call__(self, env: CoverageEnv) -> np.ndarray: ...


def lloyd_velocity(env: CoverageEnv, goals_m: np.ndarray) -> np.ndarray:
    """u = min(|g - x| / Δt, u_max) toward the goal; 0 when within 1e-10 m or oscillating. [N, 2]."""
    p = env.params
    diff = goals_m - env.positions_m
    dist = np.linalg.norm(diff, axis=1)
    speed = np.minimum(dist / p.dt_s, p.max_speed_mps)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = diff / dist[:, None] * speed[:, None]
    still = (dist < GOAL_EPS_M) | env.oscillating()
    return np.where(still[:, None], 0.0, u)


class ClairvoyantCVT:
    """Lloyd's algorithm with all robots on the full world map (the expert that makes datasets)."""

    name = "clairvoyant"

    def __init__(self) -> None:
        self.goals_m: np.ndarray | None = None
        self.masses: np.ndarray | None = None

    def goals(self, env: CoverageEnv) -> np.ndarray:
        """Φ-weighted centroids of the robots' Voronoi cells on the world map [N, 2]."""
        x = env.positions_m
        nbr, valid = delaunay_neighbours(x)
        others = x[nbr]
        w = env.params.world_size
        columns = np.arange(w)
        lo, hi = column_intervals(x, others, valid, columns, 0, w)
        s = env.prefix.interval_sums(columns, lo, hi)[:2]
        mass, first, _ = moments_to_sums(x, columns + 0.5, s[0], s[1], None)
        self.masses = mass
        return finish_centroids(mass, first, x, others, valid, np.array([0.0, 0.0, w, w]))

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        self.goals_m = self.goals(env)
        return lloyd_velocity(env, self.goals_m)


class DecentralizedCVT:
    """Each robot's own Lloyd step: its Voronoi cell among itself and its neighbours within r_c,
    restricted to its local window (trimmed at the world border), weighted by its own sensed map."""

    name = "dcvt"

    def __init__(self) -> None:
        self.goals_m: np.ndarray | None = None
        self.masses: np.ndarray | None = None

    def goals(self, env: CoverageEnv, local_maps: np.ndarray | None = None) -> np.ndarray:
        """[N, 2] goals. ``local_maps`` [N, S, S]: the robots' raw local maps, if already cropped."""
        p = env.params
        x = env.positions_m
        n, s, w = len(x), p.local_map_size, p.world_size
        cells = env.cells()
        if local_maps is None:
            local_maps = env.local_maps()
        # Competitors: every other robot within r_c.
        valid = env.neighbours()
        others = np.broadcast_to(x[None], (n, n, 2))
        # Window in global cells: columns/rows c - S/2 .. c + S/2 - 1, trimmed to the world.
        base = cells - s // 2  # [N, 2] global index of local cell 0
        box_lo = np.maximum(base, 0)
        box_hi = np.minimum(base + s, w)
        columns = base[:, 0:1] + np.arange(s)[None]  # [N, S]
        lo, hi = column_intervals(x, others, valid, columns, box_lo[:, 1], box_hi[:, 1])
        outside = (columns < box_lo[:, 0:1]) | (columns >= box_hi[:, 0:1])
        hi = np.where(outside, lo, hi)
        # Interval sums over the local maps via block prefix sums along y (local row coordinates).
        lo_l, hi_l = lo - base[:, 1:2], hi - base[:, 1:2]
        s0, s1 = _interval_sums(local_maps, lo_l, hi_l)
        s1 = s1 + base[:, 1:2] * s0  # local → global y moment
        mass, first, _ = moments_to_sums(x, columns + 0.5, s0, s1, None)
        self.masses = mass
        boxes = np.concatenate([box_lo, box_hi], axis=1).astype(np.float64)
        return finish_centroids(mass, first, x, others, valid, boxes)

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        self.goals_m = self.goals(env)
        return lloyd_velocity(env, self.goals_m)


def _interval_sums(maps: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Σ maps[n, c, lo:hi] and Σ maps[n, c, lo:hi]·(j + 0.5) for every robot n and column c.

    maps [N, C, S] float32; lo, hi [N, C] local rows. Uses per-block sums (16 rows) plus the partial
    block at each end, so the work is one pass over the maps and a small gather. Returns float64.
    """
    n, c, s = maps.shape
    nb = s // BLOCK
    blocks = maps.reshape(n, c, nb, BLOCK)
    offs = np.arange(BLOCK, dtype=np.float32) + np.float32(0.5)
    bs = blocks.sum(axis=3, dtype=np.float64)  # [N, C, nb]
    by = (blocks @ offs).astype(np.float64) + bs * (np.arange(nb) * BLOCK)  # Σ map·(j+0.5)
    cum0 = np.zeros((n, c, nb + 1))
    cum1 = np.zeros((n, c, nb + 1))
    np.cumsum(bs, axis=2, out=cum0[..., 1:])
    np.cumsum(by, axis=2, out=cum1[..., 1:])

    def prefix(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        b = h // BLOCK
        t = np.arange(BLOCK)
        rows = np.minimum(b[..., None] * BLOCK + t, s - 1)  # [N, C, BLOCK]
        vals = np.take_along_axis(maps, rows, axis=2).astype(np.float64)
        vals *= t < (h - b * BLOCK)[..., None]
        p0 = np.take_along_axis(cum0, b[..., None], axis=2)[..., 0] + vals.sum(axis=2)
        p1 = np.take_along_axis(cum1, b[..., None], axis=2)[..., 0] + (vals * (rows + 0.5)).sum(axis=2)
        return p0, p1

    a0, a1 = prefix(lo)
    b0, b1 = prefix(hi)
    return b0 - a0, b1 - a1


__all__ = ["Controller", "ClairvoyantCVT", "DecentralizedCVT", "lloyd_velocity", "MASS_EPS"]
