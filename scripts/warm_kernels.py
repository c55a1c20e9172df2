"""Compile the simulator's numba kernels once and cache them (``madp/sim/kernels.py``, ``cache=True``).

In a fresh clone nothing is cached: every process that steps an environment compiles the kernels
(5-8 s), so pytest's workers and the commands the tests start would all compile the same kernels at
once. CI runs this first (``.ci/run``); afterwards each process loads the cached machine code. It
drives the public API as every run does: each classical controller steps a small world (DCVT twice:
its maps' update after a move), then the observations and the cost; and the selection rules' kernels
(``madp/policies/select.py``: a local rule's choice among candidates).

    .venv/bin/python scripts/warm_kernels.py
"""

from __future__ import annotations

import time

import numpy as np

from madp.policies.select import select_actions
from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario, SimParams


def warm_kernels() -> None:
    env = CoverageEnv(Scenario.random(0, SimParams(world_size=256, num_robots=4, num_features=4)))
    for controller in (ClairvoyantCVT(), DecentralizedCVT(), DecentralizedCVT()):
        env.step(controller(env))
    env.observations()
    env.normalized_cost()
    select_actions("explore", env, np.zeros((2, 4, 2)))
    select_actions("oracle_cell", env, np.zeros((2, 4, 2)))


if __name__ == "__main__":
    t0 = time.perf_counter()
    warm_kernels()
    print(f"numba kernels compiled and cached in {time.perf_counter() - t0:.1f} s")
