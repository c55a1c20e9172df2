"""Classical controllers. Every controller is a callable ``controller(env) -> actions [N, 2] (m/s)``
that looks only at what it is allowed to see; learned policies implement the same interface.

- :class:`ClairvoyantCVT` (the expert): one Lloyd step per control step on the full world map.
- :class:`DecentralizedCVT`: each robot, on its own sensed map inside its 256 m local window, with
  only the neighbours within r_c that it knows of (:meth:`CoverageEnv.neighbour_view`: through its
  inbox when the environment has a network).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .env import CoverageEnv
from .robot_maps import robot_cells
from .voronoi import MASS_EPS, cell_sums, world_sums

GOAL_EPS_M = 1e-10


class Controller(Protocol):
    """Anything that acts: ``controller(env) -> actions [N, 2]`` m/s (their names: :mod:`madp.controllers`)."""

    def __call__(self, env: CoverageEnv) -> np.ndarray: ...


def lloyd_velocity(env: CoverageEnv, goals_m: np.ndarray) -> np.ndarray:
    """u = min(|g - x| / Δt, u_max) toward the goal from each robot's own position estimate x (the
    true position without position noise); 0 when within 1e-10 m or oscillating. [N, 2]."""
    p = env.params
    diff = goals_m - env.estimates_m()
    dist = np.linalg.norm(diff, axis=1)
    speed = np.minimum(dist / p.dt_s, p.max_speed_mps)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = diff / dist[:, None] * speed[:, None]
    still = (dist < GOAL_EPS_M) | env.oscillating()
    return np.where(still[:, None], 0.0, u)


class ClairvoyantCVT:
    """Lloyd's algorithm with all robots on the full world map (the expert that makes datasets)."""

    def __init__(self) -> None:
        self.goals_m: np.ndarray | None = None
        self.masses: np.ndarray | None = None

    def goals(self, env: CoverageEnv) -> np.ndarray:
        """Φ-weighted centroids of the robots' Voronoi cells on the world map [N, 2]."""
        sums = world_sums(env.prefix, env.positions_m, with_cost=False)
        self.masses = sums.mass
        return sums.centroid_m

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        self.goals_m = self.goals(env)
        return lloyd_velocity(env, self.goals_m)


class DecentralizedCVT:
    """Each robot's own Lloyd step: its Voronoi cell among itself and its neighbours within r_c,
    restricted to its local window (trimmed at the world border), weighted by its own sensed map."""

    def __init__(self) -> None:
        self.goals_m: np.ndarray | None = None
        self.masses: np.ndarray | None = None

    def goals(self, env: CoverageEnv) -> np.ndarray:
        """[N, 2] goals from each robot's own map, the neighbours it knows of and its window."""
        p = env.params
        x = env.estimates_m()
        n, s, w = len(x), p.local_map_size, p.world_size
        base = robot_cells(x) - s // 2  # [N, 2] global cell of local cell (0, 0)
        boxes = np.concatenate([np.maximum(base, 0), np.minimum(base + s, w)], axis=1).astype(np.float64)
        known, held_m = env.neighbour_view()  # robot i competes with the positions it holds, [i, j] at i·N + j
        others = np.arange(n * n).reshape(n, n)
        mass, centroid, _ = cell_sums(x, held_m.reshape(n * n, 2), others, known, boxes,
                                      block_sums=env.maps.block_sums())
        self.masses = mass
        return centroid

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        self.goals_m = self.goals(env)
        return lloyd_velocity(env, self.goals_m)


__all__ = ["Controller", "ClairvoyantCVT", "DecentralizedCVT", "lloyd_velocity", "MASS_EPS"]
