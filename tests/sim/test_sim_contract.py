"""Smaller contracts of the simulator: the feature draw's ranges, the unknown-parameter message,
float32 local maps, observations at a non-default size, and the brute-force oracle's silence on
empty cells.

Written against the mutants mutmut left alive in ``madp/sim/{idf,params,robot_maps,env,bruteforce}.py``
(issue 17); each test names the mutants it kills.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from madp.sim import CoverageEnv, Scenario, ScenarioError, SimParams
from madp.sim.bruteforce import brute_force_sums
from madp.sim.idf import random_features
from madp.sim.observations import boundary_maps, neighbour_maps, resize_maps
from madp.sim.robot_maps import RobotMaps


def test_random_features_cover_the_given_ranges():
    """μ ~ U(0, W)², σ ~ U(σ range), peak ~ U(peak range): 400 draws on a 2 m world with σ in
    [3, 4) and peaks in [5, 6) fill each range (some μ below 0.05 m and above 1.95 m). Guards
    random_features__mutmut_6 (μ ~ U(0, 1)), _8 (μ ~ U(1, W)) and _16 (peak ~ U(0, 1))."""
    f = random_features(np.random.default_rng(0), 400, 2.0, (3.0, 4.0), (5.0, 6.0))
    assert f.shape == (400, 4)
    mean, sigma, peak = f[:, :2], f[:, 2], f[:, 3]
    assert (mean >= 0).all() and (mean < 2).all() and mean.min() < 0.05 and mean.max() > 1.95
    assert (sigma >= 3).all() and (sigma < 4).all()
    assert (peak >= 5).all() and (peak < 6).all()


KNOWN = ("['check_oscillations', 'comm_radius_m', 'dt_s', 'history_size', 'local_map_size', 'max_speed_mps', "
         "'num_features', 'num_robots', 'obs_size', 'peak_range', 'sensor_size', 'sigma_range_m', "
         "'truncation_sigmas', 'world_size']")


def test_unknown_parameter_message():
    """The exact message, also as a scenario file shows it. Guards SimParams.from_dict__mutmut_3
    (no check: a TypeError from the constructor), _7 (message None) and _8 (the known names
    replaced by ``sorted(None)``)."""
    with pytest.raises(ValueError) as e:
        SimParams.from_dict({"comm_radius_mm": 3, "world_size": 256})
    assert str(e.value) == f"unknown parameter(s) ['comm_radius_mm']; expected some of {KNOWN}"
    with pytest.raises(ScenarioError) as e:
        Scenario.from_dict({"features": [{"mean": [1, 2], "sigma": 40, "peak": 1}], "robots": [[1, 2]],
                            "params": {"comm_radius_mm": 3}}, "s.json")
    assert str(e.value) == f"s.json: field 'params': unknown parameter(s) ['comm_radius_mm']; expected some of {KNOWN}"


def test_local_maps_are_float32_crops_of_what_was_sensed():
    """A 64 m world, 16 m sensor, 32 m window: the crop around a robot is its sensed square of the
    world map and zero elsewhere (inside or outside the world), float32. Guards
    RobotMaps.local_maps__mutmut_4/_6 (float64 crops)."""
    world = np.random.default_rng(0).random((64, 64)).astype(np.float32) + 0.5
    maps = RobotMaps(world, 2, 16, 32)
    cells = np.array([[20, 30], [2, 60]])
    maps.sense(cells)
    local = maps.local_maps(cells)
    assert local.shape == (2, 32, 32) and local.dtype == np.float32
    for n, (cx, cy) in enumerate(cells):
        expect = np.zeros((32, 32), np.float32)
        for a in range(32):
            for b in range(32):
                x, y = cx - 16 + a, cy - 16 + b
                if 0 <= x < 64 and 0 <= y < 64 and abs(x - cx + 0.5) < 8 and abs(y - cy + 0.5) < 8:
                    expect[a, b] = world[x, y]
        np.testing.assert_array_equal(local[n], expect)


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


def test_brute_force_oracle_is_silent_on_an_empty_cell():
    """A robot whose cell holds no importance gets mass 0, cost 0 and a NaN centroid, without a
    numpy warning (callers run with warnings as errors). Guards brute_force_sums__mutmut_109/_111
    (0/0 no longer ignored: RuntimeWarning "invalid value")."""
    phi = np.zeros((32, 32))
    phi[20:24, 20:24] = 1.0
    sites = np.array([[2.0, 2.0], [22.0, 22.0]])  # robot 0's cell (x + y < 24) holds nothing
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mass, centroid, cost = brute_force_sums(phi, sites)
    np.testing.assert_array_equal(mass, [0.0, 16.0])
    assert np.isnan(centroid[0]).all() and np.allclose(centroid[1], [22.0, 22.0])
    assert cost[0] == 0.0 and cost[1] == pytest.approx(4 * 4 * 2 * ((0.25 + 2.25) / 2))
