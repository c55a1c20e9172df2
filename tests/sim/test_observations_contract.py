"""Observation building blocks beyond the 256 -> 32 default: other sizes, any leading dimensions,
float32 throughout, and the neighbour-map pixel rule at its edges (float32 rounding, the border
pixels).

Written against the mutants mutmut left alive in ``madp/sim/observations.py`` (issue 17); each test
names the mutants it kills. ``tests/sim/test_geometry.py`` already checks the default resize against
torch and the boundary map's closed form at the default sizes.
"""

from __future__ import annotations

import numpy as np
import pytest

from madp.sim.observations import (boundary_maps, neighbour_maps, observation_tensor, raw_boundary_maps,
                                   resize_maps)


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
