"""Importance density function (IDF): circular Gaussian features rasterised on the world grid.

A feature (μx, μy, σ, peak) contributes, to cell [i, i+1) x [j, j+1), the integral over the cell of
peak · exp(-|v - μ|² / 2σ²) — the library's erfc formula with mass 2πσ²·peak — and nothing to cells
whose centre lies farther than ``truncation`` σ from μ. Features are summed and the map is scaled so
its largest cell is 1. The integral separates into x and y factors, so each feature costs one outer
product over its bounding box. Maps are indexed [x, y] (first index east), float64.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erfc

FEATURE_COLUMNS = ("mean_x_m", "mean_y_m", "sigma_m", "peak")


def random_features(
    rng: np.random.Generator,
    num_features: int,
    world_size_m: float,
    sigma_range_m: tuple[float, float],
    peak_range: tuple[float, float],
) -> np.ndarray:
    """Draw F features [F, 4] = (μx, μy, σ, peak): μ ~ U(0, W)², σ ~ U(σ range), peak ~ U(peak range)."""
    mean = rng.uniform(0.0, world_size_m, size=(num_features, 2))
    sigma = rng.uniform(*sigma_range_m, size=num_features)
    peak = rng.uniform(*peak_range, size=num_features)
    return np.column_stack([mean, sigma, peak])


def _axis_integral(edges: np.ndarray, mu: float, sigma: float) -> np.ndarray:
    """∫ over each cell [e_k, e_k+1] of exp(-(v-μ)²/2σ²) dv / (σ√(2π)): [len(edges) - 1]."""
    e = erfc((edges - mu) / (sigma * np.sqrt(2.0)))
    return 0.5 * (e[:-1] - e[1:])


def importance_map(
    features: np.ndarray, world_size: int = 1024, truncation: float = 2.0
) -> np.ndarray:
    """Normalised importance map [W, W] float64 (max 1) from features [F, 4]."""
    features = np.asarray(features, dtype=np.float64).reshape(-1, 4)
    out = np.zeros((world_size, world_size))
    centres_f32 = np.arange(world_size, dtype=np.float32) + np.float32(0.5)
    for mx, my, sigma, peak in features:
        reach = truncation * sigma
        x0, x1 = max(int(np.floor(mx - reach)) - 1, 0), min(int(np.ceil(mx + reach)) + 1, world_size)
        y0, y1 = max(int(np.floor(my - reach)) - 1, 0), min(int(np.ceil(my + reach)) + 1, world_size)
        if x0 >= x1 or y0 >= y1:
            continue
        mass = 2.0 * np.pi * sigma * sigma * peak
        ix = _axis_integral(np.arange(x0, x1 + 1, dtype=np.float64), mx, sigma)
        iy = _axis_integral(np.arange(y0, y1 + 1, dtype=np.float64), my, sigma)
        # Truncation test in float32, as the library evaluates it (cells exactly at 2σ agree).
        s32 = np.float32(sigma)
        with np.errstate(divide="ignore", invalid="ignore"):  # σ below float32's range: no cell inside
            tx = (centres_f32[x0:x1] - np.float32(mx)) / s32
            ty = (centres_f32[y0:y1] - np.float32(my)) / s32
        inside = (tx[:, None] * tx[:, None] + ty[None, :] * ty[None, :]) <= np.float32(truncation**2)
        out[x0:x1, y0:y1] += np.where(inside, mass * np.outer(ix, iy), 0.0)
    peak_value = out.max()
    if peak_value > 1e-10:
        out /= peak_value
    return out
