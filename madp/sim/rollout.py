"""Run a controller on a scenario and record J(t)/J(0) and positions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .controllers import Controller
from .env import CoverageEnv


@dataclass
class Rollout:
    """normalized_cost [T+1] (J(t)/J(0), t = 0..T); positions_m [T+1, N, 2]; converged_at: the control
    step t (1-based, as the library counts) whose actions were all zero, or None if none was."""

    normalized_cost: np.ndarray
    positions_m: np.ndarray
    converged_at: int | None

    def to_json(self, controller: str) -> dict:
        return {
            "controller": controller,
            "steps": len(self.normalized_cost) - 1,
            "cost": [float(c) for c in self.normalized_cost],
            "positions": self.positions_m[-1].tolist(),
            "converged_at": self.converged_at,
        }


def rollout(env: CoverageEnv, controller: Controller, steps: int) -> Rollout:
    """Reset ``env`` and run ``controller`` for ``steps`` steps."""
    env.reset()
    costs = np.empty(steps + 1)
    positions = np.empty((steps + 1, env.num_robots, 2))
    costs[0], positions[0] = 1.0, env.positions_m
    converged_at = None
    for t in range(1, steps + 1):
        u = controller(env)
        if converged_at is None and not np.any(u):
            converged_at = t
        env.step(u)
        costs[t] = env.normalized_cost()
        positions[t] = env.positions_m
    return Rollout(costs, positions, converged_at)
