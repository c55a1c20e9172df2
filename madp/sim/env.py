"""The coverage world a stranger can drive in three lines::

    env = CoverageEnv(Scenario.random(seed=0))
    expert = ClairvoyantCVT()
    for _ in range(600): env.step(expert(env))

State: the fixed world map Φ (and its column prefix sums), robot positions (m), what each robot has
sensed, and the short position history the library uses to detect oscillation. Rules follow the
Coverage Control Library (SPEC §2): holonomic single integrators, speed clipped to u_max, positions
at or beyond the border put back 1e-4 m inside it, sensing after every step.
"""

from __future__ import annotations

import numpy as np

from .idf import importance_map
from .observations import stack_observations
from .params import SimParams
from .robot_maps import RobotMaps, robot_cells
from .scenario import Scenario, ScenarioError
from .voronoi import ColumnPrefix, coverage_cost

BORDER_EPS_M = 1e-4
SPEED_EPS = 1e-10


def move(start_m: np.ndarray, offset_m: np.ndarray, actions_mps: np.ndarray, params: SimParams
         ) -> tuple[np.ndarray, np.ndarray]:
    """The motion of one control step, the rule :meth:`CoverageEnv.step` executes, as a pure function:
    robots at ``start_m + offset_m`` driven by ``actions_mps`` (m/s), all ``[..., 2]`` and broadcast
    against each other. The speed is clipped to u_max, a robot slower than 1e-10 m/s stays, the
    start-relative offset is integrated over Δt (the library's order of operations) and positions at
    or beyond the border are put back 1e-4 m inside it. Returns ``(positions, offsets)`` ``[..., 2]``."""
    u = np.asarray(actions_mps, dtype=np.float64)
    speed = np.linalg.norm(u, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        direction = np.where(speed[..., None] > 0, u / speed[..., None], 0.0)
    speed = np.minimum(speed, params.max_speed_mps)
    moving = speed > SPEED_EPS
    new_offset = np.where(moving[..., None], offset_m + direction * (speed * params.dt_s)[..., None], offset_m)
    pos = new_offset + start_m
    w = float(params.world_size)
    pos = np.where(pos <= 0.0, BORDER_EPS_M, pos)
    pos = np.where(pos >= w, w - BORDER_EPS_M, pos)
    return pos, pos - start_m


class CoverageEnv:
    """One episode of decentralized coverage for N robots over a fixed importance map."""

    def __init__(self, scenario: Scenario, world_map: np.ndarray | None = None):
        """Build the world from ``scenario``; ``world_map`` [W, W] overrides the map from its features."""
        self.scenario = scenario
        self.params: SimParams = scenario.params
        p = self.params
        p.check_fits(f"scenario {scenario.name or scenario.seed}")  # before the maps are allocated
        if world_map is None:
            world_map = importance_map(scenario.features, p.world_size, p.truncation_sigmas)
        self.world_map = np.asarray(world_map, dtype=np.float64)
        self.world_map_f32 = self.world_map.astype(np.float32)
        self.prefix = ColumnPrefix(self.world_map)
        self.reset()

    # --- episode -------------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        """Put the robots at their start positions, sense, and return positions [N, 2] (m)."""
        p = self.params
        self.start_m = np.array(self.scenario.robots_m, dtype=np.float64)
        self.offset_m = np.zeros_like(self.start_m)  # the library integrates start-relative offsets
        self.positions_m = self.start_m.copy()
        self.num_robots = len(self.start_m)
        self.maps = RobotMaps(self.world_map_f32, self.num_robots, p.sensor_size, p.local_map_size)
        self.maps.sense(robot_cells(self.positions_m))
        self.history: list[np.ndarray] = []
        self._record_history()
        self.steps = 0
        self.cost0 = coverage_cost(self.prefix, self.positions_m)
        if not self.cost0 > 0:
            raise ScenarioError(f"scenario {self.scenario.name or self.scenario.seed}: J(0) = {self.cost0} (no importance "
                                "away from the robots), so J(t)/J(0) is undefined")
        return self.positions_m

    def step(self, actions_mps: np.ndarray) -> np.ndarray:
        """Move every robot by Δt · u (speed clipped to u_max), clamp, sense; return positions [N, 2]."""
        u = np.asarray(actions_mps, dtype=np.float64)
        if u.shape != self.positions_m.shape:
            raise ValueError(f"actions must have shape {self.positions_m.shape}, got {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError("actions contain NaN or infinity")
        pos, self.offset_m = move(self.start_m, self.offset_m, u, self.params)
        self.positions_m = pos
        self.maps.sense(robot_cells(pos))
        self._record_history()
        self.steps += 1
        return pos

    def _record_history(self) -> None:
        # The library's deque: when full it drops the oldest entry *instead of* adding the new one.
        if self.history and len(self.history) == self.params.history_size:
            self.history.pop(0)
        else:
            self.history.append(self.positions_m.copy())

    # --- what controllers may look at ----------------------------------------------------------
    def oscillating(self) -> np.ndarray:
        """[N] bool: more than 2 of the last ≤ 6 recorded positions within 1e-4 m of the newest one."""
        if not self.params.check_oscillations or len(self.history) < 3:
            return np.zeros(self.num_robots, dtype=bool)
        k = min(6, len(self.history) - 1)
        recent = np.stack(self.history[-k:])  # [k, N, 2]
        close = np.linalg.norm(recent - self.history[-1][None], axis=2) < BORDER_EPS_M
        return close.sum(axis=0) > 2

    def cells(self) -> np.ndarray:
        """Each robot's cell [N, 2] int (rounded position)."""
        return robot_cells(self.positions_m)

    def neighbours(self) -> np.ndarray:
        """Communication graph [N, N] bool: distance < r_c, no self loops."""
        d = np.linalg.norm(self.positions_m[:, None] - self.positions_m[None], axis=2)
        return (d < self.params.comm_radius_m) & ~np.eye(self.num_robots, dtype=bool)

    def local_maps(self) -> np.ndarray:
        """Raw 256 × 256 crops of each robot's own map [N, S, S] float32."""
        return self.maps.local_maps(self.cells())

    def observations(self) -> np.ndarray:
        """O [N, 4, 32, 32] float32, channels (local map, comm x, comm y, boundary)."""
        p = self.params
        cells = self.cells()
        return stack_observations(self.maps.resized_local_maps(cells, p.obs_size), cells, self.positions_m,
                                  p.world_size, p.comm_radius_m, p.local_map_size)

    def cost(self) -> float:
        """Coverage cost J of the current positions on the world map."""
        return coverage_cost(self.prefix, self.positions_m)

    def normalized_cost(self) -> float:
        """J(t) / J(0)."""
        return self.cost() / self.cost0
