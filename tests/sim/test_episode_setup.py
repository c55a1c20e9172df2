"""What an episode builds once and keeps, built faster with the same bits (madp/sim): the world's column
prefix table in one pass (numpy's cumsums, signed zeros and non-finite values included); the robots'
block sums first built inside their sensed boxes alone (a build over the whole maps gives the same
arrays); the Delaunay competitors of a layout kept for the next time it is asked for (and not changed
by a caller moving its robots in place); the robots' maps in small pages, zero until written."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from madp.sim import ColumnPrefix, CoverageEnv, Scenario, SimParams, kernels, voronoi
from madp.sim.robot_maps import RobotMaps, sparse_zeros
from madp.sim.voronoi import world_competitors

PARAMS = SimParams(world_size=256, num_robots=6, num_features=4)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_column_prefix_is_numpys_cumsums_bit_for_bit():
    rng = np.random.default_rng(0)
    m = rng.standard_normal((40, 70)) * 10.0 ** rng.integers(-20, 20, (40, 70))
    m[:, 0] = -0.0  # a cumsum starts from its first term: -0.0 stays -0.0
    m[3, 5:9] = -0.0
    m[7, 10], m[8, 0], m[9, 4] = np.inf, np.nan, -np.inf
    y = np.arange(70) + 0.5
    want = np.zeros((40, 71, 4))
    np.cumsum(m, axis=1, out=want[:, 1:, 0])
    np.cumsum(m * y, axis=1, out=want[:, 1:, 1])
    np.cumsum(m * (y * y), axis=1, out=want[:, 1:, 2])
    got = ColumnPrefix(m).table
    assert _same(got, want)
    assert _same(ColumnPrefix(np.asfortranarray(m.astype(np.float32))).table,
                 ColumnPrefix(m.astype(np.float32).astype(np.float64)).table)


@pytest.mark.parametrize("sensor", [16, 64])
def test_block_sums_built_in_the_sensed_boxes_are_a_whole_build(sensor):
    """Robots sensed along paths (to the world's corners), then the block sums asked for: the same
    arrays as a build of every block of every map; and after more sensing, the same as such a build."""
    w, n = 128, 4
    rng = np.random.default_rng(sensor)
    world = (rng.random((w, w)) * rng.integers(0, 2, (w, w))).astype(np.float32)
    rm = RobotMaps(world, n, sensor, 64)
    for cells in ([[5, 5], [w - 1, 60], [60, w - 1], [0, 0]], [[9, 7], [w - 3, 62], [60, w - 1], [0, 0]]):
        rm.sense(np.array(cells))

    def whole(maps: RobotMaps):
        nb = w // kernels.BLOCK
        within, tot, cum = np.full((n, w, nb, kernels.BLOCK, 2), np.nan, np.float32), np.full((n, w, nb, 2), np.nan), \
            np.zeros((n, w, nb + 1, 2))
        size = maps.maps_padded.shape[1]
        everywhere_lo, everywhere_hi = np.zeros((n, 2), np.int64), np.full((n, 2), size)
        kernels.refresh_all(maps.maps_padded, maps.pad, within, tot, cum, everywhere_lo, everywhere_hi)
        return cum, within

    for later in ([[12, 9], [w - 3, 64], [58, w - 2], [0, 0]], [[40, 40], [w - 3, 64], [58, w - 2], [1, 0]]):
        cum, within = rm.block_sums()
        want_cum, want_within = whole(rm)
        assert _same(cum, want_cum) and _same(within, want_within)
        rm.sense(np.array(later))


def test_competitors_are_kept_and_not_changed_by_a_caller_moving_its_robots():
    rng = np.random.default_rng(5)
    layouts = [rng.uniform(1, 255, (6, 2)) for _ in range(3)]
    layouts.append(np.array([[10.0, 10.0], [10.0, 10.0], [50.0, 80.0], [200.0, 30.0]]))  # two on one point
    fresh = [voronoi._world_competitors(x.copy()) for x in layouts]
    for x, want in zip(layouts, fresh):
        for _ in range(2):  # asked for, then kept
            got = world_competitors(x)
            assert all((a is None and b is None) or _same(a, b) for a, b in zip(got, want))
    sites = rng.uniform(1, 255, (6, 2))
    before = sites.copy()
    world_competitors(sites)
    sites += 3.0  # the caller moves its robots in place
    assert _same(world_competitors(before)[0], before)
    for k in range(voronoi.COMPETITORS_KEPT + 5):  # bounded
        world_competitors(rng.uniform(1, 255, (5, 2)))
    assert len(voronoi._competitors) == voronoi.COMPETITORS_KEPT


def test_maps_in_small_pages_are_zero_until_written_and_copy_as_arrays():
    a = sparse_zeros((3, 50, 70), np.float32)
    assert a.shape == (3, 50, 70) and a.dtype == np.float32 and a.flags.writeable and a.flags.c_contiguous
    assert not a.any()
    a[1, 2, 3] = 5.0
    for b in (copy.deepcopy(a), pickle.loads(pickle.dumps(a))):
        assert _same(b, a) and b.flags.writeable
    env = CoverageEnv(Scenario.random(2, PARAMS))
    other = copy.deepcopy(env)
    assert _same(env.maps.maps_padded, other.maps.maps_padded)
    step = np.random.default_rng(2).normal(0, 3, (PARAMS.num_robots, 2))
    env.step(step), other.step(step)
    assert _same(env.maps.maps_padded, other.maps.maps_padded) and env.cost() == other.cost()
