"""Per-robot observation tensors O [N, 4, 32, 32]: local map, neighbours' x, neighbours' y, boundary.

Channel order is the Coverage Control Library's (``local_map, comm_x, comm_y, obstacle_map``), the
order of the reference vectors; ``CHANNELS`` names it. Local and boundary maps are 256 × 256 crops
resized to 32 × 32 by antialiased bilinear interpolation. That resize is linear and separable: one
fixed [32, 256] matrix R gives R · M · Rᵀ, equal to torch's ``F.interpolate(mode='bilinear',
antialias=True)`` (tested), without importing torch here.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

CHANNELS = ("local_map", "comm_x", "comm_y", "obstacle_map")


@lru_cache(maxsize=8)
def resize_matrix(in_size: int = 256, out_size: int = 32) -> np.ndarray:
    """[out, in] float32 weights of torch's antialiased bilinear downscale (align_corners=False)."""
    scale = in_size / out_size
    support = scale if scale >= 1.0 else 1.0
    inv = 1.0 / scale if scale >= 1.0 else 1.0
    weights = np.zeros((out_size, in_size), dtype=np.float64)
    for i in range(out_size):  # a 32-row table built once, not per pixel at run time
        centre = scale * (i + 0.5)
        lo = max(int(centre - support + 0.5), 0)
        hi = min(int(centre + support + 0.5), in_size)
        j = np.arange(lo, hi)
        w = np.clip(1.0 - np.abs((j - centre + 0.5) * inv), 0.0, None)
        weights[i, lo:hi] = w / w.sum()
    return weights.astype(np.float32)


def resize_maps(maps: np.ndarray, out_size: int = 32) -> np.ndarray:
    """Antialiased bilinear resize of [..., S, S] maps to [..., out, out] (float32)."""
    r = resize_matrix(maps.shape[-1], out_size)
    lead, s = maps.shape[:-2], maps.shape[-1]
    # One large GEMM over every row of every map (y direction), then the small x-direction products.
    half = (maps.astype(np.float32, copy=False).reshape(-1, s) @ r.T).reshape(-1, s, out_size)
    return (r @ half).reshape(*lead, out_size, out_size)


def boundary_maps(cells_xy: np.ndarray, world_size: int, local_size: int = 256, out_size: int = 32) -> np.ndarray:
    """Resized boundary maps [N, out, out]: 1 outside the world, 0 inside, around each robot cell.

    cells_xy [N, 2] int: the robots' rounded cells c; the local window covers c-S/2 .. c+S/2-1.
    The raw map is 1 - inside_x ⊗ inside_y, so its resize is 1 - (R·inside_x) ⊗ (R·inside_y).
    """
    r = resize_matrix(local_size, out_size)
    offs = np.arange(local_size) - local_size // 2
    idx = cells_xy[:, :, None] + offs  # [N, 2, S]
    inside = ((idx >= 0) & (idx < world_size)).astype(np.float32)
    rx = inside[:, 0] @ r.T  # [N, out]
    ry = inside[:, 1] @ r.T
    return 1.0 - rx[:, :, None] * ry[:, None, :]


def raw_boundary_maps(cells_xy: np.ndarray, world_size: int, local_size: int = 256) -> np.ndarray:
    """Unresized boundary maps [N, S, S] float32 (for inspection and tests)."""
    offs = np.arange(local_size) - local_size // 2
    idx = cells_xy[:, :, None] + offs
    inside = (idx >= 0) & (idx < world_size)
    return 1.0 - (inside[:, 0, :, None] & inside[:, 1, None, :]).astype(np.float32)


def neighbour_maps(positions_m: np.ndarray, comm_radius_m: float, out_size: int = 32) -> np.ndarray:
    """Neighbour maps [N, 2, out, out]: relative positions r = x_j - x_i of neighbours within r_c.

    Pixel round(r · out / (2 r_c) + out/2 - 0.5) per axis (round half to even, as torch.round),
    value r / r_c; values of neighbours sharing a pixel add up.
    """
    n = len(positions_m)
    rel = (positions_m[None, :, :] - positions_m[:, None, :]).astype(np.float32)  # [i, j, 2]
    dist = np.linalg.norm(positions_m[None, :, :] - positions_m[:, None, :], axis=2)
    mask = (dist < comm_radius_m) & ~np.eye(n, dtype=bool)
    scale = np.float32(out_size / (comm_radius_m * 2.0))
    pix = np.round(rel * scale + np.float32(out_size / 2.0 - 0.5)).astype(np.int64)
    pix = np.clip(pix, 0, out_size - 1)
    i, j = np.nonzero(mask)
    out = np.zeros((n, 2, out_size, out_size), dtype=np.float32)
    vals = rel[i, j] / np.float32(comm_radius_m)
    np.add.at(out, (i, 0, pix[i, j, 0], pix[i, j, 1]), vals[:, 0])
    np.add.at(out, (i, 1, pix[i, j, 0], pix[i, j, 1]), vals[:, 1])
    return out


def observation_tensor(
    local_maps: np.ndarray,
    cells_xy: np.ndarray,
    positions_m: np.ndarray,
    world_size: int,
    comm_radius_m: float,
    out_size: int = 32,
) -> np.ndarray:
    """Stack O [N, 4, out, out] float32 from raw local maps [N, S, S] and the robots' state."""
    n = len(positions_m)
    obs = np.empty((n, 4, out_size, out_size), dtype=np.float32)
    obs[:, 0] = resize_maps(local_maps, out_size)
    obs[:, 1:3] = neighbour_maps(positions_m, comm_radius_m, out_size)
    obs[:, 3] = boundary_maps(cells_xy, world_size, local_maps.shape[-1], out_size)
    return obs
