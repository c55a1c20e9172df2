"""``madp/Coverage-v0``: the coverage world as a centralized Gymnasium environment (one agent, all robots).

    import gymnasium, madp.envs
    env = gymnasium.make("madp/Coverage-v0", max_steps=600)

Observation ``Dict``: ``positions`` [N, 2] (m) and ``maps`` [N, 4, 32, 32] (every robot's observation
tensor, as madp's policies see them). Action: velocities [N, 2] m/s in ``Box(-u_max, u_max)``, each
robot's speed clipped to u_max by the simulator. Reward, truncation, scenarios, seeding and ``render()`` as in
:mod:`madp.envs.coverage_v0`: (J(t−1) − J(t)) / J(0); truncated after ``max_steps``; never terminated.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from madp.sim.network import NetworkSettings
from madp.sim import SimParams

from .base import DEFAULT_MAX_STEPS, RENDER_MODES, CoverageWorld, map_bounds


class CoverageGymEnv(CoverageWorld, gym.Env):
    """Centralized view of madp's coverage world (see the module docstring)."""

    metadata = {"render_modes": RENDER_MODES, "render_fps": 5}

    def __init__(self, scenario=None, params: SimParams | None = None, max_steps: int = DEFAULT_MAX_STEPS,
                 render_mode: str | None = None, render_size: int = 512, network: NetworkSettings | None = None):
        n = self._configure(scenario, params, max_steps, render_mode, render_size, network)
        low, high = map_bounds(self.params)
        u, w = float(self.params.max_speed_mps), float(self.params.world_size)
        self.observation_space = spaces.Dict({
            "positions": spaces.Box(0.0, w, (n, 2), dtype=np.float32),
            "maps": spaces.Box(np.broadcast_to(low, (n, *low.shape)), np.broadcast_to(high, (n, *high.shape)),
                               dtype=np.float32),
        })
        self.action_space = spaces.Box(-u, u, (n, 2), dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._begin(seed, self.np_random)
        return self._observation(), self._info()

    def step(self, action):
        if self.sim is None:
            raise RuntimeError("step() before reset()")
        reward = self._advance(np.asarray(action, dtype=np.float64).reshape(self.sim.num_robots, 2))
        return self._observation(), reward, False, self.truncated, self._info()

    def actions_from(self, controller) -> np.ndarray:
        """The actions [N, 2] of any madp controller (:mod:`madp.controllers`) in the current state, as this
        env's action (the PettingZoo env's :meth:`~madp.envs.coverage_v0.CoverageParallelEnv.actions_from`
        gives them as its action dict)."""
        return np.asarray(controller(self.sim), dtype=np.float64)  # float64: the simulator's precision

    def _observation(self) -> dict:
        return {"positions": self.sim.estimates_m().astype(np.float32), "maps": self.sim.observations()}
