"""RobotMaps: each robot's map is a float32 crop of what it sensed, and its row sums after incremental
updates equal a brute-force sum over the robot's own map and are bit-identical to a fresh full
recompute, whatever path the robots took (world edges included, and sensor squares as wide as the
world).

Written against the mutants mutmut left alive in ``madp/sim/robot_maps.py``; each test names the
mutants it kills (``_refresh`` mutants are written ``_N``). The tests from
``test_only_robots_that_moved_are_refreshed`` on are from the campaign on the numba simulator
(2026-12-02): the incremental bookkeeping the module docstring promises (only the robots that moved
are refreshed, nothing piles up while no block sums are asked for) and the sensed box that
``resized_local_maps`` skips outside of."""

from __future__ import annotations

import numpy as np
import pytest

from madp.sim import kernels
from madp.sim.observations import resize_maps
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
    f.seen_lo[:], f.seen_hi[:] = rm.seen_lo, rm.seen_hi  # what it wrote: the sensed boxes
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


NOT_A_CELL = -(1 << 39)  # refresh_blocks skips rows below this: "robot did not move"


def _spy_refresh(monkeypatch) -> list[np.ndarray]:
    calls: list[np.ndarray] = []
    real = kernels.refresh_blocks

    def spy(maps_padded, pad, within, tot, cum, cells, sensor_half):
        calls.append(np.array(cells))
        return real(maps_padded, pad, within, tot, cum, cells, sensor_half)

    monkeypatch.setattr(kernels, "refresh_blocks", spy)
    return calls


@pytest.mark.parametrize("as_cells", [lambda c: np.array(c, np.int64), lambda c: np.array(c, np.int32), lambda c: c],
                         ids=["int64", "int32", "list"])
def test_only_robots_that_moved_are_refreshed(monkeypatch, as_cells):
    """The module's promise: after a step only the blocks under the squares of robots that moved to a
    new cell are recomputed; the others reach ``refresh_blocks`` as "not a cell" (< -2^39), for cells of
    any integer dtype. Kills sense_32 / _37 / _41 (every robot counted as moved: all refreshed every
    step), sense_77 (the mark -(1 >> 40) = 0, a real cell), sense_76 (the mark +2^40, not the
    documented < -2^39) and sense_3 / _5 (int32 cells kept int32, which turns the mark -2^40 into 0).
    The sums stay bit-identical to a fresh build throughout."""
    w, n = 64, 3
    rng = np.random.default_rng(7)
    world = rng.random((w, w), dtype=np.float32)
    rm = RobotMaps(world, n, 16, 32)
    rm.sense(as_cells([[10, 10], [30, 40], [50, 5]]))
    rm.block_sums()  # built whole
    calls = _spy_refresh(monkeypatch)
    steps = [([[11, 10], [30, 40], [50, 5]], [0]),      # robot 0 one cell on
             ([[11, 10], [30, 40], [50, 5]], []),       # nobody moved
             ([[11, 10], [31, 41], [49, 5]], [1, 2])]
    q = (np.repeat(np.arange(n), w), np.tile(np.arange(w), n), np.zeros(n * w, np.int64), np.full(n * w, w))
    for cells, moved in steps:
        calls.clear()
        rm.sense(as_cells(cells))
        s0, s1 = rm.row_sums(*q)
        got = np.concatenate(calls) if calls else np.empty((0, 2), np.int64)
        refreshed = sorted({r for c in calls for r in range(n) if c[r, 0] >= NOT_A_CELL})
        assert refreshed == moved
        assert (got[got[:, 0] >= NOT_A_CELL] == np.array(cells)[moved]).all()
        f0, f1 = _fresh(rm, world, 16, 32).row_sums(*q)
        assert np.array_equal(s0, f0) and np.array_equal(s1, f1)


def test_sensing_without_block_sums_keeps_no_backlog():
    """sense_67 (``and`` → ``or``: the cells of every step queued while no block sums exist). An
    episode whose controller never asks for the robots' block sums (the clairvoyant expert) must not
    keep one [N, 2] array per step; when block sums are first asked for they are built whole."""
    w = 64
    rm = RobotMaps(np.ones((w, w), np.float32), 2, 16, 32)
    for k in range(20):
        rm.sense(np.array([[k, 2 * k], [w - 1 - k, 5]]))
    assert rm._stale == []
    cum, _ = rm.block_sums()
    assert cum[0, 5, -1, 0] == np.float32(rm.robot_map(0)[5].sum())


def test_resized_local_maps_read_nothing_outside_the_sensed_box():
    """resized_local_maps_10 / _24 / _29 (no box passed: the whole window read). The maps are zero
    outside each robot's sensed box (seen_lo, seen_hi), which is the union of its sensed squares, and
    ``resized_local_maps`` promises to skip what lies outside it: poisoning the maps there with NaN
    must leave the resized maps, bit for bit ``resize_maps(local_maps)``, unchanged."""
    w, s, n = 64, 32, 3
    rng = np.random.default_rng(3)
    rm = RobotMaps(rng.random((w, w), dtype=np.float32) + 0.5, n, 16, s)
    path = [[[20, 20], [0, 63], [-40, 10]], [[22, 25], [1, 60], [-40, 10]]]
    for cells in path:
        rm.sense(np.array(cells))
    cells = np.array([[21, 24], [2, 58], [5, 10]])
    p = rm.pad
    for r, sq in enumerate(np.array(path).transpose(1, 0, 2)):  # the box is the union of the squares
        lo = np.clip(sq - 8 + p, 0, w + 2 * p).min(0)
        hi = np.clip(sq + 8 + p, 0, w + 2 * p).max(0)
        if (hi > lo).all():
            assert (rm.seen_lo[r] == lo).all() and (rm.seen_hi[r] == hi).all()
        else:  # robot 2 stayed farther than half a sensor outside the world: saw nothing
            assert not rm.robot_map(r).any()
    want = resize_maps(rm.local_maps(cells), 8)
    assert np.array_equal(rm.resized_local_maps(cells, 8), want)
    assert want[0].any() and want[1].any() and not want[2].any()
    inside = np.zeros(rm.maps_padded.shape, bool)
    for r in range(n):
        (x0, y0), (x1, y1) = rm.seen_lo[r], rm.seen_hi[r]
        inside[r, x0:x1, y0:y1] = True
    assert not rm.maps_padded[~inside].any()  # zero outside the box
    rm.maps_padded[~inside] = np.nan
    assert np.array_equal(rm.resized_local_maps(cells, 8), want)


@pytest.mark.parametrize("as_index", [lambda a: a.astype(np.float64), lambda a: a.astype(np.int32), lambda a: a.tolist()],
                         ids=["float64", "int32", "list"])
def test_row_sums_take_whole_numbers_of_any_array_type(as_index):
    """row_sums__mutmut_5 / _7 (robot, column and rows not cast to int64: the kernel cannot index
    with float64). Robots, columns and row bounds are whole numbers, whatever array type holds them:
    the sums are the same as with int64 arrays."""
    w = 64
    rng = np.random.default_rng(11)
    rm = RobotMaps(rng.random((w, w), dtype=np.float32), 2, 16, 32)
    rm.sense(np.array([[10, 20], [50, 60]]))
    q = _queries(w, 2, rng)
    want = rm.row_sums(*q)
    got = rm.row_sums(*(as_index(a) for a in q))
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]) and want[0].any()


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
