"""Observation building blocks beyond the 256 -> 32 default: other sizes, any leading dimensions,
float32 throughout, and the neighbour-map pixel rule at its edges (float32 rounding, the border
pixels).

Written against the mutants mutmut left alive in ``madp/sim/observations.py``; each test
names the mutants it kills. ``tests/sim/test_geometry.py`` already checks the default resize against
torch and the boundary map's closed form at the default sizes. The tests from
``test_resize_windows_reads_every_row_of_a_tall_map`` on are from the campaign on the numba simulator
(2026-12-02): ``resize_windows`` on maps that are not square and with starts and boxes of other
integer dtypes, ``resize_maps`` of float64 maps, and ``stack_observations``' default local size.
"""

from __future__ import annotations

import numpy as np
import pytest

from madp.sim.observations import (boundary_maps, neighbour_maps, observation_tensor, raw_boundary_maps,
                                   resize_maps, resize_matrix, resize_windows, stack_observations)


def test_resize_any_leading_dims_any_output_size_float32():
    """[..., S, S] with two leading dimensions, 64 -> 16, float64 input: the antialiased bilinear
    resize of every map (Pillow's BILINEAR reduce, the filter torch's ``antialias=True`` copies; a
    matplotlib dependency, so always installed), returned as float32. Guards
    resize_maps__mutmut_6 (out_size not passed to the matrix: 32 rows), _7/_12 (``shape[+1]``, a
    leading dimension, taken as S) and _25 (``astype(None)``: float64 out)."""
    image = pytest.importorskip("PIL.Image")
    maps = np.random.default_rng(0).random((2, 3, 64, 64))
    ref = np.array([[np.asarray(image.fromarray(m.astype(np.float32), mode="F").resize((16, 16), image.BILINEAR))
                     for m in row] for row in maps])
    out = resize_maps(maps, 16)
    assert out.shape == (2, 3, 16, 16) and out.dtype == np.float32
    np.testing.assert_allclose(out, ref, atol=1e-6)


def brute_force_raw_boundary(cells, world, s):
    """1 where cell c - s/2 + (a, b) of the local window lies outside [0, world)², else 0."""
    out = np.zeros((len(cells), s, s), np.float32)
    for n, (cx, cy) in enumerate(cells):
        for a in range(s):
            for b in range(s):
                x, y = cx - s // 2 + a, cy - s // 2 + b
                out[n, a, b] = not (0 <= x < world and 0 <= y < world)
    return out


def test_boundary_maps_other_sizes_float32():
    """A 32-cell window on a 64 m world resized to 8 × 8: the raw map is the brute-force "outside
    the world" indicator, both maps are float32, and the closed-form resized map equals the resize
    of the raw one at that output size. Guards boundary_maps__mutmut_7 (out_size not passed: 32 × 32),
    _16 and raw_boundary_maps__mutmut_16 (``astype(None)``: float64)."""
    cells = np.array([[0, 0], [5, 60], [32, 32], [63, 10], [40, 63]])
    raw = raw_boundary_maps(cells, 64, 32)
    assert raw.dtype == np.float32
    np.testing.assert_array_equal(raw, brute_force_raw_boundary(cells, 64, 32))
    resized = boundary_maps(cells, 64, 32, 8)
    assert resized.shape == (5, 8, 8) and resized.dtype == np.float32
    np.testing.assert_allclose(resized, resize_maps(raw, 8), atol=1e-6)


def test_neighbour_maps_default_size_and_values():
    """Default 32 × 32, float32; a neighbour 64 m east (r_c = 256, 1/16 pixel per m) sits at pixel
    round(4 + 15.5) = 20 (half to even) in x and round(15.5) = 16 in y with value 64/256, one 64 m
    south at (16, round(11.5) = 12) with value -0.25. Guards neighbour_maps__mutmut_1 (default
    out_size 33) and _50/_52 (float64 maps)."""
    pos = np.array([[100.0, 100.0], [164.0, 100.0], [100.0, 36.0]])
    m = neighbour_maps(pos, 256.0)
    assert m.shape == (3, 2, 32, 32) and m.dtype == np.float32
    expect = np.zeros((2, 32, 32), np.float32)
    expect[0, 20, 16] = 0.25
    expect[1, 16, 12] = -0.25
    np.testing.assert_array_equal(m[0], expect)


def test_neighbour_pixel_is_computed_in_float32():
    """The library computes the pixel in float32 (torch): a neighbour 16 + 1e-7 m east is 16 m in
    float32, so 16/16 + 15.5 = 16.5 is a tie and rounds (half to even) to 16; float64 arithmetic
    would give 16.5000000063 -> 17. Guards neighbour_maps__mutmut_4 (offsets kept in float64)."""
    m = neighbour_maps(np.array([[100.0, 100.0], [116.0000001, 100.0]]), 256.0)
    assert np.argwhere(m[0, 0]).tolist() == [[16, 16]]
    assert m[0, 0, 16, 16] == np.float32(16.0) / np.float32(256.0)


@pytest.mark.parametrize("radius,offset,pixel", [
    (256.0, 256.0 - 1e-6, 31),  # 255.999999 m is 256 in float32: 16 + 15.5 = 31.5 -> 32, clipped to 31
    (61.2, -61.2 + 1e-6, 0),   # float32 rounding gives -0.5000019 -> -1, clipped to 0
])
def test_neighbour_just_inside_r_c_lands_on_the_border_pixel(radius, offset, pixel):
    """A neighbour just inside r_c whose pixel rounds one past the map's edge (float32 rounding)
    is put on the edge pixel, not dropped, wrapped round or out of bounds. Guards
    neighbour_maps__mutmut_38 (no lower clip: pixel -1 wraps to 31) and _39/_44 (no upper clip, or
    clip at out + 1: index 32 out of bounds)."""
    m = neighbour_maps(np.array([[100.0, 100.0], [100.0 + offset, 100.0]]), radius)
    assert np.argwhere(m[0, 0]).tolist() == [[pixel, 16]]
    assert m[0, 0, pixel, 16] == pytest.approx(offset / radius, abs=1e-6)


def test_observation_tensor_other_sizes_and_default():
    """The stack at out_size 16 from 64-cell local maps is (resized local map, neighbour maps,
    boundary map) each at 16 × 16, float32; at the default it is [N, 4, 32, 32]. Guards
    observation_tensor__mutmut_1 (default 33), _5/_7 (float64 stack), _14/_23/_33 (out_size not
    passed to one of the three parts)."""
    rng = np.random.default_rng(1)
    pos = np.array([[10.0, 20.0], [40.0, 30.0], [60.0, 5.0]])
    cells = np.floor(pos + 0.5).astype(np.int64)
    local = rng.random((3, 64, 64)).astype(np.float32)
    obs = observation_tensor(local, cells, pos, 64, 50.0, 16)
    assert obs.shape == (3, 4, 16, 16) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs[:, 0], resize_maps(local, 16))
    np.testing.assert_array_equal(obs[:, 1:3], neighbour_maps(pos, 50.0, 16))
    np.testing.assert_array_equal(obs[:, 3], boundary_maps(cells, 64, 64, 16))
    assert obs[:, 1:3].any() and obs[:, 3].any()
    default = observation_tensor(local, cells, pos, 64, 50.0)
    assert default.shape == (3, 4, 32, 32) and default.dtype == np.float32


def _dense_resize(window: np.ndarray, out: int) -> np.ndarray:
    r = resize_matrix(window.shape[-1], out).astype(np.float64)
    return r @ window.astype(np.float64) @ r.T


def test_resize_windows_reads_every_row_of_a_tall_map():
    """resize_windows__mutmut_14 (the default box's row bound taken from ``shape[2]``: rows of a
    [K, H, W] map past W skipped). The windows of maps taller than wide, without a box, resize
    everything under them: the dense R · window · Rᵀ (float64, to float32 rounding)."""
    rng = np.random.default_rng(5)
    maps = rng.random((2, 80, 40), dtype=np.float32)
    starts = np.array([[40, 4], [8, 0]])
    got = resize_windows(maps, starts, 32, 8)
    for k, (x0, y0) in enumerate(starts):
        np.testing.assert_allclose(got[k], _dense_resize(maps[k, x0:x0 + 32, y0:y0 + 32], 8), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("dtype", [np.uint64, np.float64, np.int32])
def test_resize_windows_takes_starts_and_boxes_of_any_number_type(dtype):
    """resize_windows__mutmut_40 / _42 (the starts not cast to int64: the kernel cannot index with
    float64). Window corners and box bounds are cell coordinates, whole numbers of whatever array
    type; the result is the same as with int64 ones. (The box's _44 / _46 are equivalent: the
    kernel only compares with its bounds, which works for any number type.)"""
    rng = np.random.default_rng(6)
    maps = rng.random((2, 64, 64), dtype=np.float32)
    starts = np.array([[0, 16], [32, 8]])
    box = np.array([[0, 64, 20, 50], [40, 64, 0, 64]])
    want = resize_windows(maps, starts, 32, 8, box)
    assert np.array_equal(resize_windows(maps, starts.astype(dtype), 32, 8, box), want)
    assert np.array_equal(resize_windows(maps, starts, 32, 8, box.astype(dtype)), want)
    assert want.any()


def test_resize_maps_reads_float64_maps_as_float32():
    """resize_maps__mutmut_15 / _17 (the maps not cast to float32: the kernel then multiplies the
    float32 weights by float64 values and rounds differently). The resize is a float32 computation
    on the float32 maps: float64 input gives, bit for bit, what its float32 values give."""
    maps = np.random.default_rng(7).random((3, 64, 64))
    assert np.array_equal(resize_maps(maps, 8), resize_maps(maps.astype(np.float32), 8))


def test_stack_observations_defaults_to_256_cell_windows():
    """stack_observations__mutmut_1 (default ``local_size`` 257). The default is the library's
    256-cell local window: resized 256 × 256 local maps stacked without ``local_size`` are exactly
    ``observation_tensor`` of the raw maps (whose size it reads), boundary channel included."""
    rng = np.random.default_rng(8)
    pos = np.array([[10.0, 20.0], [100.0, 150.0], [250.0, 3.0]])
    cells = np.floor(pos + 0.5).astype(np.int64)
    local = rng.random((3, 256, 256), dtype=np.float32)
    stacked = stack_observations(resize_maps(local), cells, pos, 256, 128.0)
    assert np.array_equal(stacked, observation_tensor(local, cells, pos, 256, 128.0))
    np.testing.assert_array_equal(stacked[:, 3], boundary_maps(cells, 256, 256, 32))
    assert stacked[:, 3].any()
