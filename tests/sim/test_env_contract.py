"""CoverageEnv's contract, second part: the memory refusal names the scenario, the map uses the
scenario's truncation and is float64, ``step`` refuses bad actions with one-line messages, computes
in float64 whatever the actions' dtype, never warns, leaves robots whose speed is at most 1e-10 in
place, keeps positions in (0, W) without snapping ones near the border, and counts its steps.

Written against the second batch of mutants mutmut left alive in ``madp/sim/env.py``; each test
names the mutants it kills.
"""

import warnings

import numpy as np
import pytest

from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim import params as params_mod
from madp.sim.env import SPEED_EPS
from madp.sim.idf import importance_map

FEATS = np.array([[100.0, 100.0, 30.0, 1.0], [200.0, 60.0, 20.0, 0.8]])
ROBOTS = np.array([[90.0, 95.0], [150.0, 120.0], [5.0, 250.0]])


def make_env(**kw) -> CoverageEnv:
    p = SimParams(**{"world_size": 256, "num_robots": 3, "num_features": 2, "local_map_size": 64,
                     "sensor_size": 16, "comm_radius_m": 100.0, **kw})
    return CoverageEnv(Scenario(FEATS, ROBOTS, p))


@pytest.mark.parametrize("name,seed,where", [("city", 7, "scenario city"), ("", 7, "scenario 7")])
def test_memory_refusal_names_the_scenario(monkeypatch, name, seed, where):
    """__init___4 (``check_fits(None)``), _5 (``name and seed``)."""
    monkeypatch.setattr(params_mod, "physical_memory_bytes", lambda: 2**20)
    p = SimParams(world_size=256, num_robots=3, num_features=2, local_map_size=64, sensor_size=16)
    with pytest.raises(ValueError) as e:
        CoverageEnv(Scenario(FEATS, ROBOTS, p, name=name, seed=seed))
    assert str(e.value).startswith(f"{where}: N = 3 robots and F = 2 features on a 256 m world need at least ")


def test_world_map_uses_the_scenario_truncation_and_is_float64():
    """__init___13 (truncation not passed: 2σ), _16 / _18 (a given map kept in its own dtype)."""
    env = make_env(truncation_sigmas=3.0)
    assert np.array_equal(env.world_map, importance_map(FEATS, 256, 3.0))
    assert not np.array_equal(env.world_map, importance_map(FEATS, 256, 2.0))
    given = np.random.default_rng(0).random((256, 256)).astype(np.float32)
    p = SimParams(world_size=256, num_robots=3, num_features=2, local_map_size=64, sensor_size=16)
    env = CoverageEnv(Scenario(FEATS, ROBOTS, p), world_map=given)
    assert env.world_map.dtype == np.float64 and np.array_equal(env.world_map, given.astype(np.float64))


def test_bad_actions_are_refused_with_one_line_messages():
    """step_8, _11.._14 (messages dropped or changed)."""
    env = make_env()
    with pytest.raises(ValueError) as e:
        env.step(np.zeros((2, 2)))
    assert str(e.value) == "actions must have shape (3, 2), got (2, 2)"
    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError) as e:
            env.step(np.array([[0.0, 0.0], [bad, 0.0], [0.0, 0.0]]))
        assert str(e.value) == "actions contain NaN or infinity"


def test_float32_actions_move_robots_as_their_float64_values():
    """step_4 / _6 (the actions not converted to float64: the motion would be computed in float32)."""
    a = np.array([[1.3, -2.7], [0.11, 4.9], [-3.3, 0.7]], dtype=np.float32)
    e32, e64 = make_env(), make_env()
    for _ in range(3):
        p32, p64 = e32.step(a), e64.step(a.astype(np.float64))
    assert p32.dtype == np.float64 and np.array_equal(p32, p64)


def test_zero_and_underflowing_actions_do_not_warn_or_move():
    """step_21.._24 (0/0 or x/0 no longer silenced): an action of 0, or one whose squared norm
    underflows to 0, leaves the robot where it is without a numpy warning."""
    env = make_env()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pos = env.step(np.array([[0.0, 0.0], [1e-200, 0.0], [0.0, -1e-200]]))
    assert np.array_equal(pos, ROBOTS)


def test_speed_at_the_threshold_does_not_move():
    """step_46 (``speed >= SPEED_EPS`` moves): a speed of exactly 1e-10 m/s is treated as 0."""
    assert np.linalg.norm([SPEED_EPS, 0.0]) == SPEED_EPS
    env = make_env()
    pos = env.step(np.array([[SPEED_EPS, 0.0], [0.0, 0.0], [0.0, 0.0]]))
    assert np.array_equal(pos, ROBOTS)


def test_positions_near_the_border_are_not_snapped():
    """step_69 (positions <= 1 m snapped to 1e-4 m): a robot moved to x = 0.5 stays there; one
    pushed past 0 is put at 1e-4 m."""
    env = make_env(max_speed_mps=10.0, dt_s=0.5)
    pos = env.step(np.array([[0.0, 0.0], [0.0, 0.0], [-9.0, 0.0]]))
    assert pos[2].tolist() == [5.0 - 4.5, 250.0]
    pos = env.step(np.array([[0.0, 0.0], [0.0, 0.0], [-9.0, 0.0]]))
    assert pos[2].tolist() == [1e-4, 250.0]


def test_steps_are_counted():
    """step_84.._86 (the counter set to 1, decremented, or incremented by 2)."""
    env = make_env()
    assert env.steps == 0
    for k in range(1, 4):
        env.step(np.ones((3, 2)))
        assert env.steps == k
    env.reset()
    assert env.steps == 0
