"""RobotMaps' row sums after incremental updates: equal to a brute-force sum over each robot's own
map, and bit-identical to a fresh full recompute, whatever path the robots took (world edges
included, and sensor squares as wide as the world).

Written against the second batch of mutants mutmut left alive in ``madp/sim/robot_maps.py``; each
test names the mutants it kills (``_refresh`` mutants are written ``_N``).
"""

import numpy as np
import pytest

from madp.sim.robot_maps import RobotMaps


def _brute(rm: RobotMaps, robot, column, lo, hi):
    s0, s1 = [], []
    for r, c, a, b in zip(robot, column, lo, hi):
        m = rm.robot_map(int(r))[int(c), a:b].astype(np.float64)
        s0.append(m.sum())
        s1.append((m * (np.arange(a, b) + 0.5)).sum())
    return np.array(s0), np.array(s1)


def _queries(w: int, n: int, rng):
    robot = np.repeat(np.arange(n), 4 * w)
    column = np.tile(np.repeat(np.arange(w), 4), n)
    lo = rng.integers(0, w, len(robot))
    hi = np.minimum(w, lo + rng.integers(0, w + 1, len(robot)))
    lo[::7], hi[::7] = 0, w
    return robot, column, lo, hi


def _fresh(rm: RobotMaps, world: np.ndarray, sensor: int, local: int) -> RobotMaps:
    f = RobotMaps(world, len(rm.maps_padded), sensor, local)
    f.maps_padded[:] = rm.maps_padded
    return f


@pytest.mark.parametrize("sensor", [16, 48, 64])
def test_incremental_row_sums_match_brute_force_and_a_fresh_recompute(sensor):
    """_77 (robots at cell x = 0 dropped from the update), _83 / _84 / _96 / _97 (the updated
    columns clipped wrongly at the world's edges), _101 (rows clipped wrongly at y = 0), _115 /
    _116 (more blocks than the world has: a sensor square as wide as the world); and, by the
    bit-identity with a fresh recompute, _running_sums_34 / _36 and _within_of_13 / _15 (running
    sums accumulated in float64 on one path and float32 on the other)."""
    w, local, n = 64, 32, 3
    rng = np.random.default_rng(sensor)
    world = rng.random((w, w), dtype=np.float32) * rng.integers(0, 2, (w, w)).astype(np.float32)
    rm = RobotMaps(world, n, sensor, local)
    path = [[(5, 5), (w - 1, 30), (30, w - 1)],
            [(0, 0), (w - 1, w - 1), (0, w - 1)],
            [(0, 40), (1, w - 1), (w - 2, 0)],
            [(w - 1, 0), (20, 1), (0, 17)],
            [(0, 0), (w - 1, w - 1), (33, 2)]]
    for cells in path:
        rm.sense(np.array(cells, dtype=np.int64))
        q = _queries(w, n, rng)
        s0, s1 = rm.row_sums(*q)
        b0, b1 = _brute(rm, *q)
        np.testing.assert_allclose(s0, b0, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(s1, b1, rtol=1e-5, atol=1e-3)
        f0, f1 = _fresh(rm, world, sensor, local).row_sums(*q)
        assert np.array_equal(s0, f0) and np.array_equal(s1, f1)


def test_running_sums_are_float32():
    """_refresh_7 / _9 (the within-block running sums allocated float64): the module's documented
    layout keeps them float32, half the memory of the largest array RobotMaps holds."""
    w = 64
    rm = RobotMaps(np.ones((w, w), np.float32), 2, 16, 32)
    rm.sense(np.array([[3, 3], [40, 50]]))
    rm.row_sums(np.array([0]), np.array([3]), np.array([0]), np.array([w]))
    assert rm._within.dtype == np.float32 and rm._within.nbytes == 2 * w * w * 2 * 4
