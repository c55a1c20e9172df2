"""Column-sum Voronoi against an independent brute-force nearest-robot pass, and the resize matrix
against torch."""

import numpy as np
import pytest

from madp.sim import ColumnPrefix, coverage_cost, importance_map, random_features, resize_matrix, voronoi_sums
from madp.sim.bruteforce import brute_force_sums
from madp.sim.observations import boundary_maps, raw_boundary_maps, resize_maps


@pytest.mark.parametrize("seed", range(6))
def test_column_sums_equal_brute_force(seed):
    rng = np.random.default_rng(seed)
    w = 256
    feats = random_features(rng, 8, w, (10, 30), (0.6, 1.0))
    phi = importance_map(feats, w)
    n = [1, 2, 3, 7, 16, 40][seed]
    sites = rng.uniform(0, w, (n, 2))
    s = voronoi_sums(ColumnPrefix(phi), sites)
    mass, centroid, cost = brute_force_sums(phi, sites)
    np.testing.assert_allclose(s.mass, mass, rtol=1e-9, atol=1e-9)
    has = mass > 1e-10
    np.testing.assert_allclose(s.centroid_m[has], centroid[has], rtol=1e-9)
    np.testing.assert_allclose(s.cost, cost, rtol=1e-9, atol=1e-6)
    assert coverage_cost(ColumnPrefix(phi), sites) == pytest.approx(cost.sum(), rel=1e-9)


def test_collinear_and_clustered_sites():
    rng = np.random.default_rng(7)
    w = 256
    phi = importance_map(random_features(rng, 6, w, (20, 40), (0.6, 1.0)), w)
    for sites in (np.column_stack([np.linspace(10, 240, 6), np.full(6, 100.0)]),  # collinear
                  100 + rng.normal(0, 0.5, (12, 2))):  # tightly clustered
        s = voronoi_sums(ColumnPrefix(phi), sites)
        mass, _, cost = brute_force_sums(phi, sites)
        np.testing.assert_allclose(s.mass, mass, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(s.cost, cost, rtol=1e-9, atol=1e-6)


@pytest.mark.parametrize("n", [3, 12, 32])
def test_robots_on_one_point_share_a_cell_counted_once(n):
    """Two robots put back into one corner (or otherwise on one point) share that point's cell: J is
    still the nearest-robot integral (the lowest index owns the cell), and both head for its centroid."""
    rng = np.random.default_rng(n)
    w = 256
    phi = importance_map(random_features(rng, 6, w, (20, 40), (0.6, 1.0)), w)
    sites = rng.uniform(0, w, (n, 2))
    sites[1] = sites[n - 1] = [1e-4, 1e-4]
    if n > 3:
        sites[5] = sites[2]
    s = voronoi_sums(ColumnPrefix(phi), sites)
    mass, centroid, cost = brute_force_sums(phi, sites)
    np.testing.assert_allclose(s.mass, mass, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s.cost, cost, rtol=1e-9, atol=1e-6)
    assert coverage_cost(ColumnPrefix(phi), sites) == pytest.approx(cost.sum(), rel=1e-9)
    assert s.mass[n - 1] == 0.0 and s.mass[1] == pytest.approx(mass[1])
    np.testing.assert_array_equal(s.centroid_m[n - 1], s.centroid_m[1])


def test_empty_cell_goes_to_polygon_vertex_mean():
    """A robot whose cell holds no importance heads for the mean of its polygon's vertices."""
    phi = np.zeros((256, 256))
    phi[200:210, 200:210] = 1.0
    sites = np.array([[50.0, 50.0], [220.0, 220.0]])
    s = voronoi_sums(ColumnPrefix(phi), sites)
    # Bisector x + y = 270 clips the box: robot 0's polygon is (0,0) (256,0) (256,14) (14,256) (0,256).
    expected = np.array([[0, 0], [256, 0], [256, 14], [14, 256], [0, 256]], float).mean(0)
    np.testing.assert_allclose(s.centroid_m[0], expected, atol=1e-9)
    assert s.mass[0] == 0.0 and s.mass[1] == pytest.approx(100.0)


def test_resize_matrix_matches_torch():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(0)
    maps = rng.random((5, 256, 256)).astype(np.float32)
    ref = torch.nn.functional.interpolate(torch.from_numpy(maps)[:, None], size=(32, 32), mode="bilinear",
                                          antialias=True, align_corners=False)[:, 0].numpy()
    np.testing.assert_allclose(resize_maps(maps), ref, atol=2e-6)
    assert resize_matrix().shape == (32, 256)
    np.testing.assert_allclose(resize_matrix().sum(1), 1.0, rtol=1e-6)


def test_boundary_map_closed_form_equals_resized_raw_map():
    cells = np.array([[0, 0], [5, 1000], [512, 512], [1023, 300], [130, 900]])
    np.testing.assert_allclose(boundary_maps(cells, 1024), resize_maps(raw_boundary_maps(cells, 1024)), atol=1e-6)
