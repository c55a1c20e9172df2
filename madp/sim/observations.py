"""Per-robot observation tensors O [N, 4, 32, 32]: local map, neighbours' x, neighbours' y, boundary.

Channel order is the Coverage Control Library's (local map, comm x, comm y, obstacle map), the order
of the reference vectors; the sample schema names the channels (``madp.data_schema.OBS_CHANNELS``). Local and boundary maps are 256 × 256 crops
resized to 32 × 32 by antialiased bilinear interpolation. That resize is linear and separable: one
fixed [32, 256] matrix R gives R · M · Rᵀ, equal to torch's ``F.interpolate(mode='bilinear',
antialias=True)`` (tested), without importing torch here. R is banded (16 taps a row), so the
compiled kernel applies it as a band, along x then y, reading each robot's window straight from
its padded map (:meth:`RobotMaps.resized_local_maps`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import kernels
from .rules import closer_than


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


@lru_cache(maxsize=8)
def resize_band(in_size: int = 256, out_size: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`resize_matrix` as a band: (first [out] int64, taps [out] int64, weights [out, T] float32),
    row i's non-zero weights ``weights[i, :taps[i]]`` starting at column ``first[i]``."""
    r = resize_matrix(in_size, out_size)
    nz = r != 0
    first = nz.argmax(1)
    taps = in_size - nz[:, ::-1].argmax(1) - first
    weights = np.zeros((out_size, int(taps.max())), np.float32)
    for i in range(out_size):
        weights[i, : taps[i]] = r[i, first[i] : first[i] + taps[i]]
    return first.astype(np.int64), taps.astype(np.int64), weights


def resize_windows(maps: np.ndarray, starts: np.ndarray, size: int, out_size: int, box: np.ndarray | None = None) -> np.ndarray:
    """Resize the windows maps[k, x0 : x0 + size, y0 : y0 + size], (x0, y0) = starts[k], of float32
    maps [K, H, W] to [K, out, out] (:func:`madp.sim.kernels.resize_windows`). ``box`` [K, 4]
    (x0, x1, y0, y1 in the maps' coordinates) bounds where map k may be non-zero."""
    first, taps, weights = resize_band(size, out_size)
    if box is None:
        box = np.broadcast_to(np.array([0, maps.shape[1], 0, maps.shape[2]]), (len(maps), 4))
    out = np.empty((len(maps), out_size, out_size), np.float32)
    kernels.resize_windows(maps, np.ascontiguousarray(starts, dtype=np.int64), size, first, taps, weights,
                           np.ascontiguousarray(box, dtype=np.int64), out)
    return out


def resize_maps(maps: np.ndarray, out_size: int = 32) -> np.ndarray:
    """Antialiased bilinear resize of [..., S, S] maps to [..., out, out] (float32)."""
    lead, s = maps.shape[:-2], maps.shape[-1]
    flat = np.ascontiguousarray(maps, dtype=np.float32).reshape(-1, s, s)
    out = resize_windows(flat, np.zeros((len(flat), 2), np.int64), s, out_size)
    return out.reshape(*lead, out_size, out_size)


def boundary_maps(cells_xy: np.ndarray, world_size: int, local_size: int = 256, out_size: int = 32) -> np.ndarray:
    """Resized boundary maps [N, out, out]: 1 outside the world, 0 inside, around each robot cell.

    cells_xy [N, 2] int: the robots' rounded cells c; the local window covers c-S/2 .. c+S/2-1.
    The raw map is 1 - inside_x ⊗ inside_y, so its resize is 1 - (R·inside_x) ⊗ (R·inside_y). Each
    R·inside sums float32 taps in float64 (exactly: a few taps within a few powers of two) and is
    rounded once to float32, so a robot's map does not depend on the other rows of ``cells_xy``
    (a float32 matrix product's rounding does: a robot computing its own gets the swarm's row).
    """
    r = resize_matrix(local_size, out_size).astype(np.float64)
    offs = np.arange(local_size) - local_size // 2
    idx = cells_xy[:, :, None] + offs  # [N, 2, S]
    inside = ((idx >= 0) & (idx < world_size)).astype(np.float64)
    rx = (inside[:, 0] @ r.T).astype(np.float32)  # [N, out]
    ry = (inside[:, 1] @ r.T).astype(np.float32)
    return 1.0 - rx[:, :, None] * ry[:, None, :]


def raw_boundary_maps(cells_xy: np.ndarray, world_size: int, local_size: int = 256) -> np.ndarray:
    """Unresized boundary maps [N, S, S] float32 (for inspection and tests)."""
    offs = np.arange(local_size) - local_size // 2
    idx = cells_xy[:, :, None] + offs
    inside = (idx >= 0) & (idx < world_size)
    return 1.0 - (inside[:, 0, :, None] & inside[:, 1, None, :]).astype(np.float32)


def neighbour_maps(positions_m: np.ndarray, comm_radius_m: float, out_size: int = 32) -> np.ndarray:
    """Neighbour maps [N, 2, out, out]: relative positions r = x_j - x_i of neighbours within r_c
    (every robot's true state; :func:`relative_neighbour_maps` draws them)."""
    n = len(positions_m)
    rel = (positions_m[None, :, :] - positions_m[:, None, :]).astype(np.float32)  # [i, j, 2]
    mask = closer_than(positions_m[None, :, :] - positions_m[:, None, :], comm_radius_m) & ~np.eye(n, dtype=bool)
    return relative_neighbour_maps(rel, mask, comm_radius_m, out_size)


def view_neighbour_maps(own_m: np.ndarray, known: np.ndarray, positions_m: np.ndarray, comm_radius_m: float,
                        out_size: int = 32) -> np.ndarray:
    """Neighbour maps [N, 2, out, out] of what each robot knows: its own position ``own_m [N, 2]`` and
    the positions it holds of the others, ``positions_m [N, N, 2]`` where ``known [N, N]``."""
    rel = (positions_m - own_m[:, None, :]).astype(np.float32)
    return relative_neighbour_maps(rel, known, comm_radius_m, out_size)


def relative_neighbour_maps(rel_m: np.ndarray, mask: np.ndarray, comm_radius_m: float, out_size: int = 32) -> np.ndarray:
    """Neighbour maps [N, 2, out, out] from offsets ``rel_m [N, N, 2]`` float32 (r = x_j - x_i) of the
    neighbours ``mask [N, N]``: pixel round(r · out / (2 r_c) + out/2 - 0.5) per axis (round half to
    even, as torch.round), value r / r_c; values of neighbours sharing a pixel add up."""
    n = len(rel_m)
    scale = np.float32(out_size / (comm_radius_m * 2.0))
    pix = np.round(rel_m * scale + np.float32(out_size / 2.0 - 0.5)).astype(np.int64)
    pix = np.clip(pix, 0, out_size - 1)
    i, j = np.nonzero(mask)
    out = np.zeros((n, 2, out_size, out_size), dtype=np.float32)
    vals = rel_m[i, j] / np.float32(comm_radius_m)
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
    return stack_observations(resize_maps(local_maps, out_size), cells_xy, positions_m, world_size, comm_radius_m,
                              local_maps.shape[-1])


def stack_observations(resized_local: np.ndarray, cells_xy: np.ndarray, positions_m: np.ndarray, world_size: int,
                       comm_radius_m: float, local_size: int = 256,
                       view: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """O [N, 4, out, out] float32 from the already resized local maps [N, out, out] and the robots' state:
    ``positions_m`` [N, 2] the robots' (own) positions; ``view`` = (known [N, N], positions [N, N, 2]):
    the neighbours each robot knows of (:func:`view_neighbour_maps`; None: every robot's true state)."""
    n, out_size = len(positions_m), resized_local.shape[-1]
    obs = np.empty((n, 4, out_size, out_size), dtype=np.float32)
    obs[:, 0] = resized_local
    if view is None:
        obs[:, 1:3] = neighbour_maps(positions_m, comm_radius_m, out_size)
    else:
        obs[:, 1:3] = view_neighbour_maps(positions_m, view[0], view[1], comm_radius_m, out_size)
    obs[:, 3] = boundary_maps(cells_xy, world_size, local_size, out_size)
    return obs
