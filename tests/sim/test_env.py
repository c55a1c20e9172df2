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
