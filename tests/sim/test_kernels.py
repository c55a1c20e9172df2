"""The compiled kernels (madp/sim/kernels.py) against the numpy code they replaced
(tests/sim/numpy_oracle.py), on random states along both controllers' trajectories and on
degenerate ones: robots sharing a point, cells without importance, robots at the world's border,
fewer than four robots or all collinear (no Delaunay triangulation), sensor squares as wide as the
world.

Tolerances (docs/reports/2026-12-02-sim-speed.md): the Voronoi sums (masses, centroids, costs, J, both controllers'
goals) and the block prefix sums are bit-identical, since the kernels do numpy's float operations
in numpy's order; the resize differs from the dense products by float32 summation order only.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from madp.sim import (ClairvoyantCVT, ColumnPrefix, CoverageEnv, DecentralizedCVT, Scenario, SimParams,
                      coverage_cost, importance_map, resize_matrix, voronoi_sums)
from madp.sim.observations import resize_band, resize_maps, resize_windows
from madp.sim.robot_maps import RobotMaps
from madp.sim.voronoi import cell_sums

from . import numpy_oracle as oracle

SMALL = SimParams(world_size=256, num_robots=12, num_features=6, sigma_range_m=(15.0, 30.0), local_map_size=128,
                  comm_radius_m=96.0)


def same(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def assert_world_sums_equal(phi: np.ndarray, sites: np.ndarray) -> None:
    prefix, ref_prefix = ColumnPrefix(phi), oracle.NumpyColumnPrefix(phi)
    for with_cost in (True, False):
        got, ref = voronoi_sums(prefix, sites, with_cost), oracle.voronoi_sums(ref_prefix, sites, with_cost)
        assert same(got.mass, ref.mass), (got.mass, ref.mass)
        assert same(got.centroid_m, ref.centroid_m), (got.centroid_m, ref.centroid_m)
        assert (got.cost is None) == (ref.cost is None) and (got.cost is None or same(got.cost, ref.cost))
    assert coverage_cost(prefix, sites) == oracle.coverage_cost(ref_prefix, sites)


def test_column_prefix_table_holds_the_numpy_prefix_sums():
    m = importance_map(np.array([[40.0, 50.0, 20.0, 1.0], [200.0, 90.0, 30.0, 0.7]]), 256)
    table, ref = ColumnPrefix(m).table, oracle.NumpyColumnPrefix(m).p.reshape(3, 256, 257)
    assert table.shape == (256, 257, 4) and table.dtype == np.float64
    assert same(np.moveaxis(table[..., :3], 2, 0), ref) and not table[..., 3].any()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_world_sums_and_clairvoyant_goals_bit_identical_along_expert_rollouts(seed):
    """J, masses, centroids and costs on every state of a 20-step expert rollout (plus the expert's
    goals and masses), 256 m world; seed 0 on the full 1024 m world with N = F = 32."""
    env = CoverageEnv(Scenario.random(seed, None if seed == 0 else SMALL))
    ref_prefix = oracle.NumpyColumnPrefix(env.world_map)
    expert = ClairvoyantCVT()
    for _ in range(20 if seed else 8):
        assert_world_sums_equal(env.world_map, env.positions_m)
        u = expert(env)
        goals, masses = oracle.clairvoyant_goals(env.positions_m, ref_prefix, env.params.world_size)
        assert same(expert.goals_m, goals) and same(expert.masses, masses)
        env.step(u)


def _sparse_map(w: int, rng) -> np.ndarray:
    """A map that is zero over most of the world, so several cells hold no importance."""
    return importance_map(np.array([[w * 0.8, w * 0.75, w / 20, 1.0], [w * 0.3, w * 0.85, w / 25, 0.8]]), w)


@pytest.mark.parametrize("case", ["shared", "border", "corners", "collinear", "three", "two", "one", "empty",
                                  "on_cell_edges"])
def test_world_sums_degenerate_states(case):
    w = 128
    rng = np.random.default_rng(7)
    phi = importance_map(np.array([[30.0, 40.0, 12.0, 1.0], [90.0, 80.0, 20.0, 0.8], [100.0, 20.0, 9.0, 0.9]]), w)
    sites = rng.uniform(1, w - 1, (10, 2))
    if case == "shared":  # robots put back onto one point (three on one, two on another)
        sites[3] = sites[4] = sites[0]
        sites[7] = sites[2]
    elif case == "border":  # clamped 1e-4 inside the border, some on the same border line
        sites[:4] = [[1e-4, 50.0], [1e-4, 80.0], [w - 1e-4, 3.0], [60.0, w - 1e-4]]
    elif case == "corners":
        sites[:4] = [[1e-4, 1e-4], [w - 1e-4, 1e-4], [1e-4, w - 1e-4], [w - 1e-4, w - 1e-4]]
        sites[4] = sites[0]
    elif case == "collinear":  # Qhull cannot triangulate: every other robot competes
        sites = np.stack([np.linspace(5.0, 120.0, 6), np.full(6, 64.0)], 1)
    elif case == "three":
        sites = sites[:3]
    elif case == "two":
        sites = np.array([[10.0, 10.0], [100.0, 110.0]])
    elif case == "one":
        sites = np.array([[64.0, 64.0]])
    elif case == "empty":  # most cells hold no importance: their goals are polygon vertex means
        phi = _sparse_map(w, rng)
        sites[5] = sites[6]
    elif case == "on_cell_edges":  # sites on cell corners and centres, bisectors through cell centres
        sites = np.array([[32.0, 32.0], [64.0, 32.0], [32.5, 96.5], [96.5, 96.5], [64.0, 64.0], [100.0, 20.0]])
    assert_world_sums_equal(phi, sites)
    if case == "empty":
        assert (voronoi_sums(ColumnPrefix(phi), sites).mass < 1e-10).sum() >= 3  # the vertex-mean path ran


def test_vertex_means_of_empty_cells_on_a_zero_map_bit_identical():
    """Every cell empty (a zero map): every goal is its polygon's vertex mean, over many layouts."""
    rng = np.random.default_rng(3)
    prefix = ColumnPrefix(np.zeros((64, 64)))
    ref_prefix = oracle.NumpyColumnPrefix(np.zeros((64, 64)))
    for n in (1, 2, 3, 5, 12, 32):
        sites = rng.uniform(0, 64, (n, 2))
        got, ref = voronoi_sums(prefix, sites, False), oracle.voronoi_sums(ref_prefix, sites, False)
        assert same(got.centroid_m, ref.centroid_m) and not got.mass.any()


def test_cell_sums_needs_exactly_one_map():
    x = np.array([[1.0, 1.0]])
    with pytest.raises(ValueError, match="exactly one of prefix and block_sums"):
        cell_sums(x, x, np.zeros((1, 1), int), np.zeros((1, 1), bool), np.array([[0.0, 0.0, 4.0, 4.0]]))


def _dcvt_run(params: SimParams, seed: int, steps: int, start: np.ndarray | None = None) -> None:
    sc = Scenario.random(seed, params)
    if start is not None:
        sc = Scenario(sc.features, start, params)
    env = CoverageEnv(sc)
    ref = oracle.NumpyRobotMaps(env.world_map_f32, env.num_robots, params.sensor_size, params.local_map_size)
    ctrl = DecentralizedCVT()
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        ref.sense(env.cells())
        u = ctrl(env)
        goals, masses = oracle.dcvt_goals(env, ref)
        assert same(ctrl.goals_m, goals) and same(ctrl.masses, masses)
        for name in ("_within", "_tot", "_cum"):
            assert same(getattr(env.maps, name), getattr(ref, name)), name
        w = params.world_size
        q = (rng.integers(0, env.num_robots, 64), rng.integers(0, w, 64), rng.integers(0, w + 1, 64))
        lo = np.minimum(q[2], rng.integers(0, w + 1, 64))
        got, want = env.maps.row_sums(q[0], q[1], lo, q[2]), ref.row_sums(q[0], q[1], lo, q[2])
        assert same(got[0], want[0]) and same(got[1], want[1])
        env.step(u + rng.normal(0, 3, u.shape))  # jitter: robots also cross block and world borders


@pytest.mark.parametrize("seed", [1, 2])
def test_dcvt_goals_and_block_sums_bit_identical(seed):
    """DCVT goals, masses, the block prefix sums (running sums, block totals, cumulative sums) and
    row sums after every step of a jittered DCVT rollout."""
    _dcvt_run(SMALL, seed, 25)


def test_dcvt_default_world_bit_identical():
    _dcvt_run(SimParams(), 5, 4)


@pytest.mark.parametrize("sensor", [64, 96])
def test_dcvt_sensor_as_wide_as_the_world_and_robots_at_the_border(sensor):
    """A sensor square as wide as (or wider than) the 64 m world: every block of every column is
    refreshed; robots start on the border and in corners (the bug of f510fa8 was here)."""
    p = SimParams(world_size=64, num_robots=5, num_features=2, sigma_range_m=(5.0, 10.0), sensor_size=sensor,
                  local_map_size=64, comm_radius_m=40.0)
    start = np.array([[1e-4, 1e-4], [64 - 1e-4, 30.0], [30.0, 64 - 1e-4], [0.5, 63.5], [32.0, 32.0]])
    _dcvt_run(p, 3, 8, start)


def test_refresh_of_robots_outside_the_world_changes_nothing():
    """Hand-made cells far outside the world (sensor square misses it) leave the block sums alone."""
    world = np.random.default_rng(0).random((64, 64), dtype=np.float32)
    rm = RobotMaps(world, 2, 16, 32)
    rm.sense(np.array([[10, 10], [50, 40]]))
    cum, within = (a.copy() for a in rm.block_sums())
    rm.sense(np.array([[-100, 10], [50, 500]]))
    cum2, within2 = rm.block_sums()
    assert same(cum, cum2) and same(within, within2)


# --- observations ---------------------------------------------------------------------------------
def test_resize_band_is_the_resize_matrix():
    for s, o in ((256, 32), (64, 16), (64, 8), (32, 8), (100, 32), (48, 32)):
        first, taps, weights = resize_band(s, o)
        dense = np.zeros((o, s), np.float32)
        for i in range(o):
            dense[i, first[i] : first[i] + taps[i]] = weights[i, : taps[i]]
        assert same(dense, resize_matrix(s, o))


@pytest.mark.parametrize("s,o", [(256, 32), (64, 16), (64, 8), (100, 32), (48, 32)])
def test_resize_against_the_dense_products(s, o):
    """Within float32 summation order of the dense [out, S] products (values in [0, 1])."""
    maps = np.random.default_rng(s).random((5, s, s), dtype=np.float32)
    maps[1] = 0.0
    maps[2, :, : s // 2] = 0.0
    got, ref = resize_maps(maps, o), oracle.resize_maps(maps, o)
    assert got.dtype == np.float32 and got.shape == (5, o, o)
    np.testing.assert_allclose(got, ref, rtol=0, atol=5e-7)
    assert not got[1].any()


def test_resize_windows_skips_only_zeros():
    """Windows read in place from larger maps, with a box bounding the non-zero part, give the
    resize of the cropped windows bit for bit."""
    rng = np.random.default_rng(2)
    maps = np.zeros((3, 90, 90), np.float32)
    maps[0, 10:40, 20:70] = rng.random((30, 50))
    maps[1, 0:90, 50:52] = rng.random((90, 2))
    maps[2, 60:61, 0:90] = rng.random((1, 90))
    box = np.array([[10, 40, 20, 70], [0, 90, 50, 52], [60, 61, 0, 90]])
    starts = np.array([[5, 7], [0, 26], [26, 0]])
    crops = np.stack([m[x : x + 64, y : y + 64] for m, (x, y) in zip(maps, starts)])
    got = resize_windows(maps, starts, 64, 16, box)
    assert same(got, resize_maps(crops, 16)) and same(resize_windows(maps, starts, 64, 16), got)


@pytest.mark.parametrize("params", [SMALL, SimParams(world_size=64, num_robots=4, num_features=2, sigma_range_m=(5.0, 10.0),
                                                     sensor_size=64, local_map_size=64, comm_radius_m=40.0)],
                         ids=["small", "sensor-as-wide-as-the-world"])
def test_observations_resize_the_local_maps_bit_for_bit(params):
    """env.observations' local-map channel equals resize_maps of the cropped local maps exactly,
    along a rollout whose robots reach the border (sensed boxes growing), and the dense products
    within float32 rounding."""
    env = CoverageEnv(Scenario.random(4, params))
    expert = ClairvoyantCVT()
    rng = np.random.default_rng(0)
    for t in range(12):
        local = env.local_maps()
        obs = env.observations()
        assert same(obs[:, 0], resize_maps(local, params.obs_size))
        np.testing.assert_allclose(obs[:, 0], oracle.resize_maps(local, params.obs_size), rtol=0, atol=5e-7)
        env.step(expert(env) + rng.normal(0, 5, (env.num_robots, 2)) + (10.0 if t < 6 else -10.0))


def test_sensed_box_bounds_the_maps():
    """Each robot's map is zero outside the box of what it has sensed."""
    env = CoverageEnv(Scenario.random(6, SMALL))
    expert = ClairvoyantCVT()
    for _ in range(5):
        env.step(expert(env))
    m = env.maps
    for n in range(env.num_robots):
        (x0, y0), (x1, y1) = m.seen_lo[n], m.seen_hi[n]
        outside = m.maps_padded[n].copy()
        assert x1 - x0 >= SMALL.sensor_size and y1 - y0 >= SMALL.sensor_size
        outside[x0:x1, y0:y1] = 0.0
        assert not outside.any()


def test_numba_cache_dir_is_used(tmp_path):
    """With NUMBA_CACHE_DIR set (site-packages read-only, say) the compiled kernels are cached
    there, and a second process loads them from it."""
    code = ("import numpy as np; from madp.sim.robot_maps import RobotMaps; "
            "m = RobotMaps(np.ones((32, 32), np.float32), 1, 8, 16); m.sense(np.array([[4, 4]])); "
            "print(m.row_sums(np.array([0]), np.array([4]), np.array([0]), np.array([8]))[0][0])")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    root = Path(__file__).resolve().parents[2]
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", code], env=env, cwd=root, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == "8.0"
    assert list((tmp_path / "cache").rglob("kernels.refresh_all-*.nbi"))


@pytest.mark.parametrize("sensor", [16, 64, 96])
def test_sensing_copies_the_union_of_the_sensed_squares(sensor):
    """After steps of one cell, jumps, robots standing still and robots outside the world, each map
    is the world inside the union of the squares its robot sensed and zero elsewhere (sensing copies
    only what a new square adds to the previous one)."""
    w, local, n = 64, 32, 4
    rng = np.random.default_rng(sensor)
    world = rng.random((w, w), dtype=np.float32) + 0.5
    rm = RobotMaps(world, n, sensor, local)
    seen = np.zeros((n, w, w), bool)
    cells = np.array([[5, 5], [60, 2], [30, 30], [0, 63]])
    for t in range(40):
        if t % 10 == 9:
            cells = rng.integers(-40, w + 40, (n, 2))  # jumps, some far outside the world
        else:
            cells = cells + rng.integers(-1, 2, (n, 2)) * (rng.random((n, 1)) < 0.7)
        rm.sense(cells)
        h = sensor // 2
        for r, (cx, cy) in enumerate(cells):
            seen[r, max(cx - h, 0) : max(min(cx + h, w), 0), max(cy - h, 0) : max(min(cy + h, w), 0)] = True
        for r in range(n):
            assert same(rm.robot_map(r), np.where(seen[r], world, np.float32(0.0))), (t, r)
    p = rm.pad
    inner = rm.maps_padded[:, p : p + w, p : p + w].copy()
    rm.maps_padded[:, p : p + w, p : p + w] = 0.0
    assert not rm.maps_padded.any() and inner.any()  # nothing outside the world
