"""The selection rules' kernels (madp/robot/choice.py) give the bits of the code they replaced
(tests/robot/choice_oracle.py): every robot's window block sums (its own map, read only inside its
sensed box, and the world's), the ``explore`` prior and the local cell costs, along rollouts that
take robots to the world's border and past it, for K from 1 to 9 and robots with no neighbour; a map
with values a sum can round differently (signed zeros, magnitudes far apart) and a robot that knows of
no neighbour at all; and numpy's pairwise sum, which the prior's mean mass reproduces."""

from __future__ import annotations

import numpy as np
import pytest

from madp.robot import choice
from madp.robot.choice import GRID_M, explore_prior, local_cell_costs, local_views, map_prior, map_views
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.env import move
from madp.sim.robot_maps import robot_cells
from madp.sim.network import NetworkSettings
from tests.robot import choice_oracle as oracle

SMALL = SimParams(world_size=512, num_robots=10, num_features=8)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _oracle_costs(views, actions_mps, params) -> np.ndarray:
    y, _ = move(views.start_m[:, None], views.offset_m[:, None], actions_mps, params)
    return oracle.cell_costs(np.ascontiguousarray(y), views.weights, views.origin_m,
                             np.ascontiguousarray(views.neighbours_m), views.valid, GRID_M)


def _check_state(env: CoverageEnv, rng: np.random.Generator) -> None:
    maps, s, g = env.maps, env.params.local_map_size, env.params.local_map_size // GRID_M
    starts = robot_cells(env.estimates_m()) - s // 2 + maps.pad
    for true_map in (False, True):
        views = local_views(env, true_map)
        grids = maps.world_padded[None] if true_map else maps.maps_padded
        assert _same(views.weights, oracle.block_sums(grids, not true_map, starts, g, GRID_M)), true_map
    views = local_views(env)
    prior = explore_prior(env, views)
    assert _same(prior.weights, oracle.prior_weights(maps.explored, views.origin_m, views.weights, maps.pad,
                                                     maps.world_size))
    for k in (1, 3, 4, 5, 9):
        u = rng.uniform(-6.0, 6.0, (env.num_robots, k, 2))
        for v in (views, prior):
            assert _same(local_cell_costs(v, u, env.params), _oracle_costs(v, u, env.params)), k


@pytest.mark.parametrize("params, network, seed", [(SMALL, None, 0), (SMALL, NetworkSettings(loss=0.5, seed=3), 1),
                                                   (None, None, 2)], ids=["small", "lossy", "default-world"])
def test_views_prior_and_costs_bit_identical_along_rollouts(params, network, seed):
    """Robots driven toward a corner and along the border (windows and sensor squares past the world,
    window corners on and off the explored grid); with a lossy network some robots know of no neighbour."""
    env = CoverageEnv(Scenario.random(seed, params), network=network)
    rng = np.random.default_rng(seed)
    drift = np.array([-4.0, -2.5])
    for t in range(24):
        if t % 6 == 0:
            _check_state(env, rng)
        env.step(drift + rng.normal(0, 2.0, (env.num_robots, 2)))
    _check_state(env, rng)


def test_hand_made_readings_with_signed_zeros_and_far_apart_magnitudes():
    """One robot's maps (as a robot holds them) from readings whose sums round differently in another
    order: -0.0, tiny and huge values; its view, prior and costs are the oracle's bits, and a robot
    that knows of no neighbour (one invalid slot) keeps every block it is nearest to; a neighbour on
    the robot's own point ties every block with the candidate that stays (ties: its own)."""
    p = SimParams(world_size=512, num_robots=1, num_features=1)
    from madp.sim.robot_maps import RobotMaps

    rng = np.random.default_rng(4)
    maps = RobotMaps(None, 1, p.sensor_size, p.local_map_size, world_size=p.world_size)
    for lo in ([-20, 30], [10, 40], [300, 480], [200, 200]):
        values = (rng.random((64, 64)) * 10.0 ** rng.integers(-30, 30, (64, 64))).astype(np.float32)
        values[rng.random((64, 64)) < 0.3] = -0.0
        maps.record(np.array([lo]), values[None])
    for own in ([[20.3, 60.7]], [[230.5, 231.5]], [[511.9, 0.2]]):
        own = np.array(own)
        for known, held in ((np.zeros((1, 0), bool), np.zeros((1, 0, 2))),
                            (np.array([[True, False, True]]), rng.uniform(0, 512, (1, 3, 2))),
                            (np.array([[True]]), own[:, None].copy())):
            views = map_views(maps, own, own, np.zeros_like(own), known, held)
            s, g = p.local_map_size, p.local_map_size // GRID_M
            starts = robot_cells(own) - s // 2 + maps.pad
            assert _same(views.weights, oracle.block_sums(maps.maps_padded, True, starts, g, GRID_M))
            prior = map_prior(maps, views)
            assert _same(prior.weights, oracle.prior_weights(maps.explored, views.origin_m, views.weights, maps.pad,
                                                             maps.world_size))
            u = rng.uniform(-6.0, 6.0, (1, 6, 2))
            u[0, 2] = 0.0  # stays: on a neighbour's point when one is there
            for v in (views, prior):
                got = local_cell_costs(v, u, p)
                assert _same(got, _oracle_costs(v, u, p))
                assert (got[0, 2] > 0) == bool(v.weights.any())


def test_block_sums_read_nothing_outside_the_sensed_box():
    """Each robot's window block sums read its map only inside its sensed box (the map is zero outside
    it): NaN written outside the box changes no bit of the sums."""
    env = CoverageEnv(Scenario.random(3, SMALL))
    rng = np.random.default_rng(3)
    for _ in range(8):
        env.step(rng.normal(0, 4.0, (env.num_robots, 2)))
    want = local_views(env).weights
    m = env.maps
    size = m.maps_padded.shape[1]
    for r in range(env.num_robots):
        (x0, y0), (x1, y1) = m.seen_lo[r], m.seen_hi[r]
        outside = np.ones((size, size), bool)
        outside[x0:x1, y0:y1] = False
        m.maps_padded[r][outside] = np.nan
    got = local_views(env).weights
    assert _same(got, want) and np.isfinite(got).all() and got.any()


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 127, 128, 129, 136, 255, 256, 1000, 4096, 4103, 70000])
def test_numpy_sum_is_numpys_pairwise_sum(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        x = rng.standard_normal(n) * 10.0 ** rng.integers(-12, 12, n)
        x[rng.random(n) < 0.2] = -0.0
        assert _same(np.float64(0.0 + choice._numpy_sum(x, 0, n)), np.add.reduce(x))
        if n > 10:
            assert _same(np.float64(0.0 + choice._numpy_sum(x, 3, n - 10)), np.add.reduce(x[3 : n - 7]))
