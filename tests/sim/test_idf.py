"""The importance map and the features it is made of (``madp.sim.idf``): each feature adds peak·2πσ²
times the Gaussian's integral over each cell inside the truncation disc (tested in float32, boundary
included), the map is divided by its maximum only when that exceeds 1e-10, features outside the world
are skipped without stopping the loop, a σ below float32's range gives no warning, and the random
features cover the given ranges.

Written against the mutants mutmut left alive in ``madp/sim/idf.py``; each test names the mutants it
kills (``importance_map`` mutants are written ``_N``). Expectations are computed here with
``math.erf``, independently of the module."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from madp.sim.idf import importance_map, random_features


def cell_value(mx, my, sigma, peak, x, y):
    """peak·2πσ² · ∫∫ over cell (x, y) of the unit Gaussian density centred at (mx, my)."""
    def axis(lo, mu):
        return 0.5 * (math.erf((lo + 1 - mu) / (sigma * math.sqrt(2))) - math.erf((lo - mu) / (sigma * math.sqrt(2))))
    return peak * 2 * math.pi * sigma * sigma * axis(x, mx) * axis(y, my)


def test_unnormalised_values_below_the_threshold():
    """_axis_integral_9 (the 0.5 factor), _75 / _76 (the mass 2πσ²·peak): a map whose maximum is
    ≤ 1e-10 is returned as it is, so its values are the features' integrals themselves."""
    f = [(10.3, 12.7, 2.5, 1e-12), (20.0, 8.0, 1.5, 3e-13)]
    m = importance_map(np.array(f), 32)
    assert m.max() <= 1e-10
    for x, y in [(10, 12), (11, 13), (8, 11), (20, 8), (19, 7)]:
        want = sum(cell_value(*ft, x, y) for ft in f if (x + 0.5 - ft[0]) ** 2 + (y + 0.5 - ft[1]) ** 2 <= 4 * ft[2] ** 2)
        assert m[x, y] == pytest.approx(want, rel=1e-9, abs=0)


def test_normalised_to_max_one_above_the_threshold():
    """_149 (threshold 1.0000000001): a map with maximum 0.5 is normalised to 1."""
    m = importance_map(np.array([[16.0, 16.0, 3.0, 0.5]]), 32)
    assert m.max() == 1.0
    assert m[17, 15] == pytest.approx(cell_value(16, 16, 3, 0.5, 17, 15) / cell_value(16, 16, 3, 0.5, 16, 16), rel=1e-9, abs=0)


def test_threshold_is_strict():
    """_148 (``>=``): a map whose maximum is exactly 1e-10 is not normalised. The peak below was
    found by stepping through floats until the map's maximum was 1e-10 exactly."""
    m = importance_map(np.array([[16.5, 16.5, 3.0, 1.0092849679628258e-10]]), 32)
    assert m.max() == 1e-10


def test_float32_features_give_the_float64_map():
    """_9 / _11 (the features not converted to float64: a float32 array's σ and peak would make
    the mass float32)."""
    f = np.array([[10.3, 12.7, 2.7, 0.9], [20.1, 8.3, 1.9, 0.35]], dtype=np.float32)
    assert np.array_equal(importance_map(f, 32), importance_map(f.astype(np.float64), 32))


def test_a_feature_outside_the_world_does_not_stop_the_rest():
    """_70 (``continue`` → ``break``)."""
    m = importance_map(np.array([[-100.0, -100.0, 2.0, 1.0], [16.0, 16.0, 2.0, 1.0]]), 32)
    assert m.max() == 1.0 and m[16, 16] == 1.0


def test_truncation_disc_includes_its_boundary():
    """_129 (``<=`` → ``<``): a cell centre exactly 2σ away is inside; _131 (``truncation * 2``):
    with truncation 3, a cell 2.83σ away is inside and one 3.16σ away is not."""
    m = importance_map(np.array([[10.5, 10.5, 1.0, 1.0]]), 32)
    assert m[12, 10] > 0 and m[8, 10] > 0 and m[13, 10] == 0
    m = importance_map(np.array([[10.5, 10.5, 1.0, 1e-12]]), 32, truncation=3.0)
    assert m[12, 12] == pytest.approx(cell_value(10.5, 10.5, 1.0, 1e-12, 12, 12), rel=1e-9, abs=0)  # 2.83σ
    assert m[12, 11] == pytest.approx(cell_value(10.5, 10.5, 1.0, 1e-12, 12, 11), rel=1e-9, abs=0)  # 2.24σ
    assert m[13, 11] == 0 and m[14, 10] == 0  # 3.16σ and 3.5σ: outside


def test_sigma_below_float32_range_gives_no_warning():
    """_109.._112 (``divide`` / ``invalid`` no longer silenced): σ = 1e-50 is 0 in float32, so
    the truncation test divides by 0 (and 0/0 at the feature's own cell centre)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = importance_map(np.array([[5.5, 5.5, 1e-50, 1.0]]), 16)
    assert not m.any()


def test_truncation_test_is_evaluated_in_float32():
    """_20 / _22 (cell centres in float64: the truncation test then rounds differently). Here the
    centre of cell 3 is 2σ away up to float32 rounding: (3.5 - μx)/σ is 2.00000012 exactly but 2 in
    float32, so the cell is inside (the reference library's float32 rule). The values are float32
    numbers, found by stepping σ and μx through floats."""
    mx, sigma = 1.4957088232040405, 1.002145528793335
    assert np.float32(mx) == mx and np.float32(sigma) == sigma
    m = importance_map(np.array([[mx, 3.5, sigma, 1e-12]]), 16)
    assert m[3, 3] == pytest.approx(cell_value(mx, 3.5, sigma, 1e-12, 3, 3), rel=1e-9, abs=0)
    assert m[3, 4] == 0


def test_random_features_cover_the_given_ranges():
    """μ ~ U(0, W)², σ ~ U(σ range), peak ~ U(peak range): 400 draws on a 2 m world with σ in
    [3, 4) and peaks in [5, 6) fill each range (some μ below 0.05 m and above 1.95 m). Guards
    random_features__mutmut_6 (μ ~ U(0, 1)), _8 (μ ~ U(1, W)) and _16 (peak ~ U(0, 1))."""
    f = random_features(np.random.default_rng(0), 400, 2.0, (3.0, 4.0), (5.0, 6.0))
    assert f.shape == (400, 4)
    mean, sigma, peak = f[:, :2], f[:, 2], f[:, 3]
    assert (mean >= 0).all() and (mean < 2).all() and mean.min() < 0.05 and mean.max() > 1.95
    assert (sigma >= 3).all() and (sigma < 4).all()
    assert (peak >= 5).all() and (peak < 6).all()
