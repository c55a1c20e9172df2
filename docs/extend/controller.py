"""A controller of your own: anything with ``__call__(env) -> actions [N, 2]`` in m/s."""

import numpy as np

from madp.sim import CoverageEnv, DecentralizedCVT, Scenario, lloyd_velocity, rollout


class CautiousDCVT:
    """DCVT's goals (each robot's centroid on its own sensed map), approached at a capped speed."""

    def __init__(self, max_speed_mps: float = 2.5) -> None:
        self.dcvt = DecentralizedCVT()
        self.max_speed_mps = max_speed_mps

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        u = lloyd_velocity(env, self.dcvt.goals(env))  # toward the goals, at most u_max
        speed = np.linalg.norm(u, axis=1, keepdims=True)
        return u * np.minimum(1.0, self.max_speed_mps / np.maximum(speed, 1e-12))


result = rollout(CoverageEnv(Scenario.random(seed=0)), CautiousDCVT(), steps=20)
print(f"J(20)/J(0) = {result.normalized_cost[-1]:.3f}")
assert result.normalized_cost[-1] < 1.0  # the swarm spread out and covered more
