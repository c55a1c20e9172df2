"""``madp/Coverage-v0``: the coverage world as a centralized Gymnasium environment (one agent, all robots).

    import gymnasium, madp.envs
    env = gymnasium.make("madp/Coverage-v0", max_steps=600)

Observation ``Dict``: ``positions`` [N, 2] (m) and ``maps`` [N, 4, 32, 32] (every robot's observation
tensor, as madp's policies see them). Action: velocities [N, 2] m/s in ``Box(-u_max, u_max)``, each
robot's speed clipped to u_max by the simulator. Reward, truncation, scenarios and seeding as in
:mod:`madp.envs.coverage_v0`: (J(t−1) − J(t)) / J(0); truncated after ``max_steps``; never terminated.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from madp.sim import CoverageEnv, SimParams

from .coverage_v0 import DEFAULT_MAX_STEPS, episode_scenario, map_bounds, resolve_scenario
from .render import render_frame


class CoverageGymEnv(gym.Env):
    """Centralized view of madp's coverage world (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, scenario=None, params: SimParams | None = None, max_steps: int = DEFAULT_MAX_STEPS,
                 render_mode: str | None = None, render_size: int = 512):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: expected one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.scenario = resolve_scenario(scenario)
        self.params = self.scenario.params if self.scenario is not None else (params or SimParams())
        self.max_steps, self.render_mode, self.render_size = int(max_steps), render_mode, int(render_size)
        n = self.params.num_robots if self.scenario is None else len(self.scenario.robots_m)
        low, high = map_bounds(self.params)
        u, w = float(self.params.max_speed_mps), float(self.params.world_size)
        self.observation_space = spaces.Dict({
            "positions": spaces.Box(0.0, w, (n, 2), dtype=np.float32),
            "maps": spaces.Box(np.broadcast_to(low, (n, *low.shape)), np.broadcast_to(high, (n, *high.shape)),
                               dtype=np.float32),
        })
        self.action_space = spaces.Box(-u, u, (n, 2), dtype=np.float32)
        self.sim: CoverageEnv | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        scenario = episode_scenario(self.scenario, self.params, seed, self.np_random)
        if self.sim is None or self.sim.scenario is not scenario:
            self.sim = CoverageEnv(scenario)
        else:
            self.sim.reset()
        self._cost = self.sim.cost()
        return self._observation(), self._info()

    def step(self, action):
        if self.sim is None:
            raise RuntimeError("step() before reset()")
        self.sim.step(np.asarray(action, dtype=np.float64).reshape(self.sim.num_robots, 2))
        cost = self.sim.cost()
        reward = float((self._cost - cost) / self.sim.cost0)
        self._cost = cost
        return self._observation(), reward, False, self.sim.steps >= self.max_steps, self._info()

    def action_from(self, controller) -> np.ndarray:
        """The action [N, 2] of any madp controller (:mod:`madp.controllers`) in the current state."""
        return np.asarray(controller(self.sim), dtype=np.float64)  # float64: the simulator's precision

    def _observation(self) -> dict:
        return {"positions": self.sim.positions_m.astype(np.float32), "maps": self.sim.observations()}

    def _info(self) -> dict:
        return {"normalized_cost": float(self._cost / self.sim.cost0), "step": int(self.sim.steps)}

    def render(self):
        if self.render_mode is None or self.sim is None:
            return None
        return render_frame(self.sim.world_map, self.sim.positions_m, self.render_size)
