"""Voronoi sums: ColumnPrefix reads its map as float64, whatever the map's array type; and the
brute-force oracle they are checked against is silent on an empty cell.

Written against the mutants mutmut left alive in ``madp/sim/voronoi.py`` and
``madp/sim/bruteforce.py``; each test names the mutants it kills."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from madp.sim.bruteforce import brute_force_sums
from madp.sim.voronoi import ColumnPrefix, cell_sums, coverage_cost, voronoi_sums, world_competitors

from tests.sim import numpy_oracle


def _table(m: np.ndarray) -> np.ndarray:
    """Prefix sums along y of (Φ, Φ·y, Φ·y²), y the row centre, by plain Python float64 loops."""
    w, h = m.shape
    t = np.zeros((w, h + 1, 4))
    for c in range(w):
        acc = [0.0, 0.0, 0.0]
        for r in range(h):
            v, y = float(m[c, r]), r + 0.5
            acc = [acc[0] + v, acc[1] + v * y, acc[2] + v * (y * y)]
            t[c, r + 1, :3] = acc
    return t


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int32, np.longdouble])
def test_column_prefix_reads_the_map_as_float64(dtype):
    """__init___3 / _5 (the map not cast to float64: an extended-precision ``longdouble`` map's
    products Φ·y and Φ·y² would be taken before rounding to float64). The table holds the prefix
    sums of the map's float64 values, bit for bit those of the map cast to float64 first (and, for
    these small maps, of plain sequential sums); float32 and integer maps give them too."""
    rng = np.random.default_rng(2)
    m = (rng.random((6, 40)) * 50).astype(dtype)
    if dtype == np.longdouble:
        m = m / np.longdouble(3)  # values a float64 cannot hold (where longdouble is wider)
    want = ColumnPrefix(m.astype(np.float64)).table
    got = ColumnPrefix(m).table
    assert got.dtype == np.float64 and np.array_equal(got, want)
    assert np.array_equal(want, _table(m.astype(np.float64)))


def test_robots_on_one_point_share_its_cell_when_every_robot_has_the_same_x():
    """world_competitors_11 (the cheap duplicate test's ``==`` turned into ``!=``: it then asks whether some
    neighbouring pair in sorted order differs in *both* coordinates; when every robot stands on one
    vertical line none does, so a layout with two robots on one point took the no-duplicates path and
    the duplicate's cell was not shared). Two robots on one point, all four robots at x = 100 m: the
    masses, costs and centroids are the numpy oracle's (which merges points explicitly), J is the
    brute-force nearest-robot integral, and the duplicate's mass and cost count once."""
    rng = np.random.default_rng(11)
    m = rng.random((64, 64))
    sites = np.array([[10.5, 20.25], [10.5, 20.25], [10.5, 40.75], [10.5, 55.0]])
    got = voronoi_sums(ColumnPrefix(m), sites)
    want = numpy_oracle.voronoi_sums(numpy_oracle.NumpyColumnPrefix(m), sites)
    np.testing.assert_allclose(got.mass, want.mass, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got.cost, want.cost, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(got.centroid_m, want.centroid_m, rtol=1e-12, atol=1e-9)
    assert got.mass[1] == 0.0 and got.cost[1] == 0.0
    _, _, bf_cost = brute_force_sums(m, np.unique(sites, axis=0))
    assert coverage_cost(ColumnPrefix(m), sites) == pytest.approx(bf_cost.sum(), rel=1e-9)


def test_cell_sums_leaves_the_cost_out_unless_asked_and_wants_exactly_one_map():
    """cell_sums_1 (``with_cost`` defaulting to True: every DCVT step would pay for costs it drops) and
    cell_sums_7 (the message of the one-map check). Without ``with_cost`` the costs are 0; with it they
    are the world's J terms; giving both maps, or neither, is refused with a message that says so."""
    rng = np.random.default_rng(7)
    prefix = ColumnPrefix(rng.random((64, 64)))
    sites = rng.uniform(1, 63, size=(6, 2))
    points, idx, valid, _ = world_competitors(sites)
    boxes = np.broadcast_to(np.array([0.0, 0.0, 64.0, 64.0]), (6, 4))
    mass, _, cost = cell_sums(sites, points, idx, valid, boxes, prefix=prefix)
    assert mass.sum() > 0 and not cost.any()
    assert cell_sums(sites, points, idx, valid, boxes, prefix=prefix, with_cost=True)[2].min() > 0
    for kw in ({}, {"prefix": prefix, "block_sums": (np.zeros((1, 1)), np.zeros((1, 1)))}):
        with pytest.raises(ValueError, match="^give exactly one of prefix and block_sums$"):
            cell_sums(sites, points, idx, valid, boxes, **kw)


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
