"""CoverageEnv: dynamics, sensing, oscillation and scenario files; and its contract in detail: the
memory refusal names the scenario, the map uses the scenario's truncation and is float64, ``step``
refuses bad actions with one-line messages, computes in float64 whatever the actions' dtype, never
warns, leaves robots whose speed is at most 1e-10 in place, keeps positions in (0, W) without snapping
ones near the border, counts its steps, and builds observations of any ``obs_size``.

The contract tests are written against the mutants mutmut left alive in ``madp/sim/env.py``
(and in the campaign on the numba simulator, 2026-12-02); each names the mutants it kills. The oracle of
the library's oscillation check is ``CoverageSystem::CheckOscillation``, transcribed below."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario, ScenarioError, SimParams, rollout
from madp.sim import params as params_mod
from madp.sim.env import SPEED_EPS
from madp.sim.idf import importance_map
from madp.sim.observations import boundary_maps, neighbour_maps, resize_maps


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


# --- the contract (mutation survivors) ------------------------------------------------------------

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


@pytest.mark.parametrize("as_robots", [lambda r: r.astype(np.float32), lambda r: r.astype(np.int64).tolist()],
                         ids=["float32", "int list"])
def test_start_positions_are_float64_whatever_their_type(as_robots):
    """reset_4 / _6 (the start positions kept in the scenario's own dtype: float32 start positions
    make J(0) and every Voronoi cell be computed from float32 sites). Start positions of any type
    are their float64 values: the same positions, J(0) and trajectory as float64 ones."""
    robots = np.array([[90.25, 95.5], [150.0, 120.125], [5.0, 250.0]])
    p = SimParams(world_size=256, num_robots=3, num_features=2, local_map_size=64, sensor_size=16,
                  comm_radius_m=100.0)
    given = as_robots(robots)
    want = CoverageEnv(Scenario(FEATS, np.array(given, dtype=np.float64), p))
    got = CoverageEnv(Scenario(FEATS, given, p))
    assert got.positions_m.dtype == np.float64 and np.array_equal(got.positions_m, want.positions_m)
    assert got.cost0 == want.cost0
    ctrl_a, ctrl_b = DecentralizedCVT(), DecentralizedCVT()
    for _ in range(3):
        assert np.array_equal(got.step(ctrl_b(got)), want.step(ctrl_a(want)))


@pytest.mark.parametrize("name,seed,where", [("flat", 3, "scenario flat"), ("", 3, "scenario 3")])
def test_a_world_without_importance_is_refused_with_its_name(name, seed, where):
    """reset_31 (``>= 0``: J(0) = 0 accepted), _33 .. _37 (the message dropped, ``name and seed``,
    its text changed). J(t)/J(0) needs J(0) > 0; a map that is 0 everywhere gives J(0) = 0."""
    p = SimParams(world_size=256, num_robots=3, num_features=2, local_map_size=64, sensor_size=16)
    with pytest.raises(ScenarioError) as e:
        CoverageEnv(Scenario(FEATS, ROBOTS, p, name=name, seed=seed), world_map=np.zeros((256, 256)))
    assert str(e.value) == (f"{where}: J(0) = 0.0 (no importance away from the robots), so J(t)/J(0) is "
                            "undefined")


def test_a_small_but_positive_j0_is_accepted():
    """reset_32 (``> 1``: 0 < J(0) <= 1 refused). Importance is relative: scaling the map by 1e-9
    scales J by 1e-9 and changes no normalised cost."""
    p = SimParams(world_size=256, num_robots=3, num_features=2, local_map_size=64, sensor_size=16)
    big = CoverageEnv(Scenario(FEATS, ROBOTS, p))
    small = CoverageEnv(Scenario(FEATS, ROBOTS, p), world_map=big.world_map * 1e-9)
    assert 0 < small.cost0 < 1 < big.cost0
    np.testing.assert_allclose(small.cost0, big.cost0 * 1e-9, rtol=1e-9)


def test_position_history_is_the_librarys_deque():
    """_record_history_4 (``pop(1)``). The library's history of ``history_size`` positions: while
    not full each step appends; when full a step drops the oldest entry *instead of* appending (so
    the history alternates between full and one short). With ``history_size`` 1 it alternates
    between empty and one entry, which ``pop(1)`` cannot do."""
    env = make_env(history_size=3)
    seen = [env.positions_m.copy()]
    for k in range(6):
        seen.append(env.step(np.full((3, 2), 0.5 + k)).copy())
    # steps 1, 2 append; 3 drops; 4 appends; 5 drops; 6 appends
    want = [seen[2], seen[4], seen[6]]
    assert len(env.history) == 3 and all(np.array_equal(a, b) for a, b in zip(env.history, want))
    env = make_env(history_size=1)
    for k in range(4):
        env.step(np.ones((3, 2)))
        assert len(env.history) == (0 if k % 2 == 0 else 1)
        assert not env.oscillating().any()


def _library_oscillation(history: list[np.ndarray], check: bool) -> np.ndarray:
    """CoverageSystem::CheckOscillation per robot: false if not checking or fewer than 3 entries;
    else count, from the newest backwards over min(6, size - 1) entries, those closer than kLargeEps
    (1e-4) to the newest; oscillating if the count exceeds 2."""
    n = len(history[0]) if history else 0
    out = np.zeros(n, bool)
    for r in range(n):
        h = [e[r] for e in history]
        if not check or len(h) < 3:
            continue
        last = h[-1]
        count = sum(1 for pt in reversed(h[len(h) - min(6, len(h) - 1):]) if np.hypot(*(pt - last)) < 1e-4)
        out[r] = count > 2
    return out


@pytest.mark.parametrize("check", [True, False])
def test_oscillation_is_the_librarys_check(check):
    """oscillating_1 (``and``: a history is checked with check_oscillations off), _14 / _15 / _16
    (7 entries, or the oldest too, or one fewer), _27 (compared with the second newest), _29
    (``<=``: an entry exactly 1e-4 m away counts). Histories of 1 to 12 entries drawn from three
    points: P0, P1 exactly 1e-4 m from P0 (x = 1e-4 and 2e-4: the difference is exact), P2 5e-5 m
    from P0."""
    pts = np.array([[1e-4, 3.0], [2e-4, 3.0], [1e-4, 3.0 + 5e-5]])
    assert np.linalg.norm(pts[1] - pts[0]) == 1e-4
    env = make_env(check_oscillations=check)
    rng = np.random.default_rng(4)
    n = 400
    env.num_robots = n  # oscillating() reads only the history and the robot count
    hits = 0
    for length in range(1, 13):
        env.history = [pts[rng.choice(3, n, p=[0.55, 0.25, 0.2])] for _ in range(length)]
        want = _library_oscillation(env.history, check)
        assert np.array_equal(env.oscillating(), want), length
        hits += want.sum()
    assert (hits > 100) == check


def test_env_observations_follow_obs_size():
    """``SimParams.obs_size`` sets the observation size: 16 gives [N, 4, 16, 16], each channel the
    16 × 16 version. Guards CoverageEnv.observations__mutmut_13 (obs_size not passed: 32 × 32)."""
    p = SimParams(world_size=256, num_robots=3, num_features=2, local_map_size=64, sensor_size=16, obs_size=16,
                  comm_radius_m=100.0)
    env = CoverageEnv(Scenario(np.array([[100.0, 100.0, 30.0, 1.0], [200.0, 60.0, 20.0, 0.8]]),
                               np.array([[90.0, 95.0], [150.0, 120.0], [10.0, 250.0]]), p))
    obs = env.observations()
    assert obs.shape == (3, 4, 16, 16) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs[:, 0], resize_maps(env.local_maps(), 16))
    np.testing.assert_array_equal(obs[:, 1:3], neighbour_maps(env.positions_m, 100.0, 16))
    np.testing.assert_array_equal(obs[:, 3], boundary_maps(env.cells(), 256, 64, 16))
