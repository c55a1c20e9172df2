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
from .voronoi import MASS_EPS, Cells, reduce_cells, world_cells

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
        cells = world_cells(env.positions_m, env.params.world_size)
        robot, column = cells.column_pairs()
        lo, hi = cells.row_intervals(robot, column)
        sums = reduce_cells(cells, robot, column, env.prefix.interval_sums(column, lo, hi, 2), False)
        self.masses = sums.mass
        return sums.centroid_m

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
        if local_maps is None:
            local_maps = env.local_maps()
        base = env.cells() - s // 2  # [N, 2] global cell of local cell (0, 0)
        boxes = np.concatenate([np.maximum(base, 0), np.minimum(base + s, w)], axis=1).astype(np.float64)
        cells = Cells(x, np.broadcast_to(x[None], (n, n, 2)), env.neighbours(), boxes)
        robot, column = cells.column_pairs()
        lo, hi = cells.row_intervals(robot, column)
        s0, s1 = LocalPrefix(local_maps).interval_sums(robot, column - base[robot, 0], lo - base[robot, 1], hi - base[robot, 1])
        s1 = s1 + base[robot, 1] * s0  # local → global y moment
        sums = reduce_cells(cells, robot, column, np.stack([s0, s1]), False)
        self.masses = sums.mass
        return sums.centroid_m

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        self.goals_m = self.goals(env)
        return lloyd_velocity(env, self.goals_m)


class LocalPrefix:
    """Block prefix sums along y of per-robot local maps [N, C, S] float32 (S a multiple of 16).

    ``cum[n, c, b]`` = Σ over rows < 16·b of the map and of map·(j + 0.5); a sum over rows
    [lo, hi) is then two block lookups plus the partial blocks at each end (≤ 16 cells each).
    """

    def __init__(self, maps: np.ndarray):
        n, c, s = maps.shape
        nb = s // BLOCK
        self.maps = maps
        self.shape = (n, c, s)
        weights = np.stack([np.ones(BLOCK), np.arange(BLOCK) + 0.5], 1).astype(np.float32)  # [16, 2]
        blocks = (maps.reshape(-1, BLOCK) @ weights).reshape(n * c, nb, 2).astype(np.float64)
        blocks[..., 1] += blocks[..., 0] * (np.arange(nb) * BLOCK)  # → local row offsets
        # Cumulative sums over blocks as one GEMM: cum[:, b, m] = Σ_{b' < b} blocks[:, b', m].
        tri = np.kron(np.triu(np.ones((nb, nb + 1)), 1), np.eye(2))  # [nb·2, (nb+1)·2]
        self.cum = (blocks.reshape(n * c, nb * 2) @ tri).reshape(n * c, nb + 1, 2)

    def prefix(self, robot: np.ndarray, column: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Σ over rows < h of (map, map·(j+0.5)) at each (robot, local column): [P, 2]."""
        n, c, s = self.shape
        b = h // BLOCK
        t = np.arange(BLOCK)
        rows = np.minimum(b[:, None] * BLOCK + t, s - 1)  # [P, 16]
        line = robot * c + column
        vals = np.take(self.maps.reshape(-1), (line * s)[:, None] + rows).astype(np.float64)
        vals *= t < (h - b * BLOCK)[:, None]
        part = np.stack([vals.sum(1), (vals * (rows + 0.5)).sum(1)], 1)
        return self.cum[line, b] + part

    def interval_sums(self, robot, column, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """(Σ map, Σ map·(j+0.5)) over local rows [lo, hi) per pair, float64 [P] each."""
        p = len(robot)
        both = self.prefix(np.concatenate([robot, robot]), np.concatenate([column, column]), np.concatenate([hi, lo]))
        d = both[:p] - both[p:]
        return d[:, 0], d[:, 1]


__all__ = ["Controller", "ClairvoyantCVT", "DecentralizedCVT", "lloyd_velocity", "MASS_EPS"]
