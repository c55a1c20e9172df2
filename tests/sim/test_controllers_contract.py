"""The expert controllers' public state: ``goals_m`` and ``masses`` are None until the first
``goals``/call, then the goals and each robot's Voronoi-cell mass (clairvoyant: on the world map,
checked against the brute-force oracle; decentralised: on the robot's own sensed map within its
window, checked by direct sums for robots with no neighbours).

Written against the second batch of mutants mutmut left alive in ``madp/sim/controllers.py``; each
test names the mutants it kills.
"""

import numpy as np

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario, SimParams
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
