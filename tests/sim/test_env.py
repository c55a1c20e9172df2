"""Dynamics, sensing, oscillation and scenario files."""

import json

import numpy as np
import pytest

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario, ScenarioError, SimParams, rollout


@pytest.fixture(scope="module")
def env():
    return CoverageEnv(Scenario.random(3, SimParams(num_robots=8, num_features=8)))


def test_speed_is_clipped_and_positions_clamped(env):
    env.reset()
    x0 = env.positions_m.copy()
    u = np.zeros((8, 2))
    u[0] = [300.0, 400.0]  # 500 m/s → clipped to 5 m/s → 1 m per step
    env.step(u)
    assert np.linalg.norm(env.positions_m[0] - x0[0]) == pytest.approx(1.0)
    np.testing.assert_array_equal(env.positions_m[1:], x0[1:])
    u[:] = 0
    u[1] = [-5.0, 0.0]
    for _ in range(1100):
        env.step(u)
    assert env.positions_m[1, 0] == pytest.approx(1e-4)  # clamped 1e-4 m inside the border


def test_every_border_puts_robots_back_just_inside():
    """SPEC §2: a position at or beyond the border is put back 1e-4 m inside it, on all four sides.
    Robots 0 and 2 land exactly on x = 1024 / y = 1024 (fails if the upper clamp is dropped, the
    issue-17 mutation that let robots leave the world at x >= 1024, or if it tests > instead of >=),
    robot 1 exactly on x = 0 (fails on < instead of <=), robots 3 and 4 drive far past the upper and
    lower corners."""
    start = np.array([[1023.0, 600.0], [1.0, 500.0], [600.0, 1023.0], [1000.0, 1010.0], [20.0, 10.0]])
    sc = Scenario(np.array([[512.0, 512.0, 50.0, 1.0]]), start, SimParams(num_robots=5, num_features=1))
    env = CoverageEnv(sc)
    u = np.array([[5.0, 0.0], [-5.0, 0.0], [0.0, 5.0], [3.0, 4.0], [-3.0, -4.0]])  # 5 m/s: 1 m per step
    hi, lo = 1024.0 - 1e-4, 1e-4
    env.step(u)
    assert (env.positions_m[0, 0], env.positions_m[1, 0], env.positions_m[2, 1]) == (hi, lo, hi)
    for _ in range(60):
        env.step(u)
        assert ((env.positions_m > 0) & (env.positions_m < 1024)).all()
    np.testing.assert_array_equal(env.positions_m, [[hi, 600.0], [lo, 500.0], [600.0, hi], [hi, hi], [lo, lo]])


def test_sensing_copies_the_square_around_each_robot(env):
    env.reset()
    c = env.cells()[2]
    own = env.maps.robot_map(2)
    x0, x1 = max(c[0] - 32, 0), min(c[0] + 32, 1024)
    y0, y1 = max(c[1] - 32, 0), min(c[1] + 32, 1024)
    np.testing.assert_array_equal(own[x0:x1, y0:y1], env.world_map_f32[x0:x1, y0:y1])
    assert own.sum() == pytest.approx(env.world_map_f32[x0:x1, y0:y1].sum())


def test_oscillation_stops_a_robot_that_keeps_returning():
    sc = Scenario(np.array([[512.0, 512.0, 50.0, 1.0]]), np.array([[100.0, 100.0], [900.0, 900.0]]),
                  SimParams(num_robots=2, num_features=1))
    env = CoverageEnv(sc)
    for _ in range(4):
        env.step(np.zeros((2, 2)))  # standing still: every recent position equals the newest
    assert env.oscillating().all()
    np.testing.assert_array_equal(ClairvoyantCVT()(env), 0.0)


def test_same_scenario_same_trajectory():
    sc = Scenario.random(11, SimParams(num_robots=6, num_features=5))
    a = rollout(CoverageEnv(sc), DecentralizedCVT(), 30)
    b = rollout(CoverageEnv(sc), DecentralizedCVT(), 30)
    np.testing.assert_array_equal(a.positions_m, b.positions_m)
    assert a.normalized_cost[0] == 1.0 and a.normalized_cost[-1] < 1.0


def test_minimal_scenario_file_round_trip(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"features": [{"mean": [100, 200], "sigma": 50, "peak": 0.9}],
                                "robots": [[10, 10], [500.5, 600]]}))
    sc = Scenario.load(path)
    assert sc.params.num_robots == 2 and sc.params.num_features == 1
    assert sc.params.comm_radius_m == 256.0
    sc.save(tmp_path / "t.json")
    again = Scenario.load(tmp_path / "t.json")
    np.testing.assert_array_equal(again.features, sc.features)
    np.testing.assert_array_equal(again.robots_m, sc.robots_m)
    with_override = json.loads(path.read_text()) | {"params": {"comm_radius_m": 128}}
    path.write_text(json.dumps(with_override))
    assert Scenario.load(path).params.comm_radius_m == 128


@pytest.mark.parametrize("doc,field", [
    ({"robots": [[1, 2]]}, "features"),
    ({"features": [], "robots": [[1, 2, 3]]}, "robots[0]"),
    ({"features": [{"mean": [1, 2], "sigma": -1, "peak": 1}], "robots": [[1, 2]]}, "features[0]"),
    ({"features": [{"mean": [1, 2], "sigma": 5}], "robots": [[1, 2]]}, "features[0]"),
    ({"features": [], "robots": [[1, 2000]]}, "robots[0]"),
    ({"features": [], "robots": [[1, 2]], "params": {"comm_radius_mm": 3}}, "params"),
    ({"features": [], "robots": [["a", 2]]}, "robots[0]"),
    ({"features": [], "robots": [[1, 2]], "colour": 1}, "colour"),
])
def test_bad_scenarios_name_the_field(tmp_path, doc, field):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ScenarioError) as e:
        Scenario.load(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg and field in msg
