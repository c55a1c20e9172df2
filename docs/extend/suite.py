"""A suite of your own: a fixed list of environments, each built deterministically from its seed."""

from dataclasses import replace

import numpy as np

from madp.controllers import make_controller
from madp.eval.suites import EnvSpec
from madp.sim import CoverageEnv, SimParams, rollout


def crowded_suite(num_envs: int = 2) -> list[EnvSpec]:
    """64 robots on maps of 8 narrow features (σ ∈ [10, 20] m): one group, ``crowded``."""
    params = replace(SimParams(), num_robots=64, num_features=8, sigma_range_m=(10, 20))
    return [EnvSpec("crowded", "crowded", i, params) for i in range(num_envs)]


finals = []
for spec in crowded_suite():
    scenario = spec.scenario()  # the same scenario for the same suite, group and index, every time
    finals.append(rollout(CoverageEnv(scenario), make_controller("dcvt"), steps=10).normalized_cost[-1])
print(f"DCVT on crowded: J(10)/J(0) = {np.mean(finals):.3f} (mean of {len(finals)})")
assert len({s.seed for s in crowded_suite()}) == 2 and all(f < 1.0 for f in finals)
