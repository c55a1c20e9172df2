"""The expert controllers' public state: ``goals_m`` and ``masses`` are None until the first
``goals``/call, then the goals and each robot's Voronoi-cell mass (clairvoyant: on the world map,
checked against the brute-force oracle; decentralised: on the robot's own sensed map within its
window, checked by direct sums for robots with no neighbours).

Written against the second batch of mutants mutmut left alive in ``madp/sim/controllers.py``; each
test names the mutants it kills. ``test_lloyd_velocity_stops_only_closer_than_1e_10_m`` is from the
campaign on the numba simulator (2026-12-02): the library's stop rule (``dist < kEps``) at its
threshold, and no warning for a robot already at its goal.
"""

import warnings

import numpy as np

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario, SimParams
from madp.sim.controllers import GOAL_EPS_M, lloyd_velocity
from madp.sim.bruteforce import brute_force_sums

FEATS = np.array([[100.0, 100.0, 30.0, 1.0], [200.0, 60.0, 20.0, 0.8]])


def make_env(robots, comm=100.0) -> CoverageEnv:
    p = SimParams(world_size=256, num_robots=len(robots), num_features=2, local_map_size=64, sensor_size=16,
                  comm_radius_m=comm)
    return CoverageEnv(Scenario(FEATS, np.array(robots, dtype=np.float64), p))


def test_state_is_none_before_the_first_call():
    """ClairvoyantCVT.__init___1 / _2 and DecentralizedCVT.__init___1 / _2 (``""`` for None)."""
    for ctl in (ClairvoyantCVT(), DecentralizedCVT()):
        assert ctl.goals_m is None and ctl.masses is None


def test_clairvoyant_masses_are_the_voronoi_masses():
    """ClairvoyantCVT.goals_33 (``masses = None``)."""
    env = make_env([[90.0, 95.0], [150.0, 120.0], [60.0, 180.0], [210.0, 40.0]])
    ctl = ClairvoyantCVT()
    ctl(env)
    mass, centroid, _ = brute_force_sums(env.world_map, env.positions_m)
    assert (mass > 0).all()
    np.testing.assert_allclose(ctl.masses, mass, rtol=1e-9)
    np.testing.assert_allclose(ctl.goals_m, centroid, rtol=1e-9)


def test_decentralized_masses_are_each_robots_window_sum():
    """DecentralizedCVT.goals_67 (``masses = None``): robots farther apart than r_c each own their
    whole window (cells c - 32 .. c + 31, trimmed at the border) of their own map."""
    robots = [[90.0, 95.0], [200.0, 60.0], [20.0, 230.0]]
    env = make_env(robots, comm=10.0)
    ctl = DecentralizedCVT()
    ctl(env)
    want = []
    for n, (cx, cy) in enumerate(env.cells()):
        x0, y0 = max(cx - 32, 0), max(cy - 32, 0)
        want.append(env.maps.robot_map(n)[x0:cx + 32, y0:cy + 32].astype(np.float64).sum())
    np.testing.assert_allclose(ctl.masses, want, rtol=1e-6)
    assert ctl.goals_m.shape == (3, 2)


# Offsets (i, j) · 2^-66 whose float64 norm is exactly 1e-10: 2^-66 is the spacing of the floats in
# [2^-14, 2^-13) ∋ 1e-4, so a robot at 1e-4 and a goal at 1e-4 + offset differ by exactly the offset.
# (Found by search; the lattice of such offsets is fine enough that some round to 1e-10.)
_AT_THRESHOLD = np.array([2214231273.0, 7038633289.0]) * 2.0**-66


def test_lloyd_velocity_stops_only_closer_than_1e_10_m():
    """lloyd_velocity_29 (``dist <= 1e-10`` stops): the library moves a robot unless its goal is
    *closer* than kEps = 1e-10 m, so a goal exactly 1e-10 m away gives the speed dist/Δt toward it.
    And _16 / _18 (0/0 no longer silenced): a robot already at its goal gets 0 without a warning;
    _17 / _19 (x/0 no longer silenced): a robot on the border (start positions may lie on it) whose
    goal is 1e-300 m away, a distance whose square underflows to 0, gets 0 without a warning too."""
    env = make_env([[1e-4, 1e-4], [150.0, 120.0], [60.0, 180.0], [0.0, 40.0]])
    goals = env.positions_m + np.array([_AT_THRESHOLD, [0.0, 0.0], [3.0, -4.0], [1e-300, 0.0]])
    diff = goals - env.positions_m
    assert np.array_equal(diff[0], _AT_THRESHOLD) and np.linalg.norm(diff[0]) == GOAL_EPS_M == 1e-10
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        u = lloyd_velocity(env, goals)
    dt, umax = env.params.dt_s, env.params.max_speed_mps
    np.testing.assert_allclose(u[0], diff[0] / dt, rtol=1e-12)
    assert (u[0] != 0).all() and (u[1] == 0).all() and (u[3] == 0).all()
    np.testing.assert_allclose(u[2], np.array([3.0, -4.0]) / 5.0 * min(5.0 / dt, umax), rtol=1e-12)
