"""A robot that hears no one takes the Lloyd step of the disc of :func:`lone_radius_m` around its
anchor, where it last heard a neighbour; one that hears someone chooses among its samples as before."""

from __future__ import annotations

import numpy as np

from madp.policies.select import select_actions
from madp.robot.choice import GRID_M, LocalViews, lone_radius_m, lone_steps
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.network import NetworkSettings

P = SimParams()


def _views(valid: bool, anchor_m) -> LocalViews:
    """One robot at (500, 500) whose window holds mass only in its corner blocks (~180 m away)."""
    g = P.local_map_size // GRID_M
    w = np.zeros((1, g, g))
    w[0, 0, 0] = w[0, -1, -1] = 5.0
    start = np.array([[500.0, 500.0]])
    return LocalViews(start, np.zeros((1, 2)), w, start - P.local_map_size / 2, np.array([[[900.0, 900.0]]]),
                      np.array([[valid]]), np.array([anchor_m], dtype=np.float64))


def test_lone_radius_is_the_communication_radius():
    assert lone_radius_m(P) == P.comm_radius_m


def test_a_lone_robot_steps_toward_the_mass_of_its_disc_only():
    lone, u = lone_steps(_views(False, [900.0, 900.0]), P)
    assert lone[0] and (u == 0).all()  # every mass is farther than the radius from its anchor: it stays
    lone, u = lone_steps(_views(True, [500.0, 500.0]), P)
    assert not lone[0] and (u == 0).all()  # it hears someone: not its business
    lone, u = lone_steps(_views(False, [380.0, 380.0]), P)  # anchored near the lower corner's mass
    corner = np.array([372.0 + GRID_M / 2, 372.0 + GRID_M / 2])
    assert lone[0] and np.isclose(np.linalg.norm(u), P.max_speed_mps)
    assert np.allclose(u / np.linalg.norm(u), (corner - 500.0) / np.linalg.norm(corner - 500.0))


def test_select_gives_lone_robots_their_step_and_the_others_a_sample():
    """On a network that loses every message each robot takes its bounded Lloyd step, whatever its
    samples; on a perfect one robots with neighbours keep one of their own samples."""
    scenario = Scenario.random(5, P)
    rng = np.random.default_rng(0)
    cand = rng.uniform(-5, 5, (4, P.num_robots, 2))
    lost = CoverageEnv(scenario, network=NetworkSettings(loss=1.0))
    for _ in range(3):
        lost.step(np.full((P.num_robots, 2), 1.0))
    u = select_actions("explore", lost, cand)
    assert not any((u[i] == cand[:, i]).all(1).any() for i in range(P.num_robots))
    assert (np.linalg.norm(u, axis=1) <= P.max_speed_mps + 1e-9).all()
    env = CoverageEnv(scenario)
    u = select_actions("explore", env, cand)
    heard = env.neighbours().any(1)
    assert all((u[i] == cand[:, i]).all(1).any() for i in np.flatnonzero(heard))


def test_the_environment_keeps_each_robots_anchor():
    """With every message lost robots never hear anyone: their anchors stay at their starts. On a
    perfect network a robot's anchor follows it whenever it has a neighbour within r_c."""
    scenario = Scenario.random(5, P)
    lost = CoverageEnv(scenario, network=NetworkSettings(loss=1.0))
    start = lost.anchor_m.copy()
    assert np.array_equal(start, lost.start_m)
    for _ in range(5):
        lost.step(np.full((P.num_robots, 2), 3.0))
    assert np.array_equal(lost.anchor_m, start)
    env = CoverageEnv(scenario)
    for _ in range(5):
        env.step(np.full((P.num_robots, 2), 3.0))
    heard = env.neighbours().any(1)
    assert heard.any()
    assert np.array_equal(env.anchor_m[heard], env.positions_m[heard])
