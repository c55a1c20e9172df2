"""``madp.sim.rollout``: what ``madp rollout`` runs (mutmut found no test of the rollout record
or ``Rollout.to_json`` in the unit suites)."""

from __future__ import annotations

import numpy as np
import pytest

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario, SimParams
from madp.sim.rollout import rollout

PARAMS = SimParams(world_size=256, num_robots=3, num_features=2)


def _scenario() -> Scenario:
    return Scenario(np.array([[60.0, 60.0, 20.0, 1.0], [200.0, 180.0, 30.0, 1.0]]),
                    np.array([[10.0, 10.0], [240.0, 20.0], [128.0, 240.0]]), PARAMS)


@pytest.mark.parametrize("name, cls", [("clairvoyant", ClairvoyantCVT), ("dcvt", DecentralizedCVT)])
def test_rollout_is_the_step_loop(name, cls):
    """The record equals a hand-written loop over ``CoverageEnv.step``: J(t)/J(0) from 1, the positions
    at t = 0..T, and ``to_json``'s fields."""
    r = rollout(CoverageEnv(_scenario()), cls(), 5)
    env, ctrl = CoverageEnv(_scenario()), cls()
    costs, positions = [1.0], [env.positions_m.copy()]
    for _ in range(5):
        env.step(ctrl(env))
        costs.append(env.normalized_cost())
        positions.append(env.positions_m.copy())
    np.testing.assert_array_equal(r.normalized_cost, costs)
    np.testing.assert_array_equal(r.positions_m, np.stack(positions))
    assert r.normalized_cost.shape == (6,) and r.positions_m.shape == (6, 3, 2)
    d = r.to_json(name)
    assert d == {"controller": name, "steps": 5, "cost": [float(c) for c in costs],
                 "positions": positions[-1].tolist(), "converged_at": r.converged_at}


def test_converged_at_is_the_first_all_zero_step_and_rollout_resets():
    """``converged_at`` is the 1-based step whose actions were all zero (None if none was), and a
    rollout starts from the scenario's start even on a used env."""
    class StopAfter:
        def __init__(self, t):
            self.t, self.calls = t, 0

        def __call__(self, env):
            self.calls += 1
            return np.zeros((env.num_robots, 2)) if self.calls >= self.t else np.ones((env.num_robots, 2))

    env = CoverageEnv(_scenario())
    env.step(np.full((3, 2), 2.0))
    r = rollout(env, StopAfter(3), 4)
    np.testing.assert_array_equal(r.positions_m[0], _scenario().robots_m)
    assert r.converged_at == 3
    assert rollout(env, StopAfter(10), 4).converged_at is None
