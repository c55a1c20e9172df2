"""Symmetry augmentation: the square world's 8 rotations and reflections (the dihedral group D4).

The coverage problem is equivariant under every map ``p -> A (p - c) + c`` of the world onto itself,
``c`` the world's centre and ``A`` a signed permutation matrix: the importance map, the sensor and
local-map windows, the boundary, the Voronoi cells and so the expert's actions all transform along.
(The library's half-open windows ``c-128 .. c+127`` around the rounded cell c map onto each other
exactly: a reflection sends cell j to ``W-1-j`` and the rounded position c to ``W-c``.) A sample
``(O [N, 4, 32, 32], X [N, 2], U [N, 2])`` therefore has 8 equally valid images:

* positions ``X' = A (X - c) + c`` and actions ``U' = A U``;
* every channel of O is an image over the robot's local window indexed ``[x, y]``: it is moved as
  the window is (transpose for the axis swap, flip for a reflected axis);
* the neighbour channels hold the offset vector ``r / r_c`` (channels 1, 2 = x, y), so at every
  pixel they are also multiplied by A: swapped with the axes, negated with a reflected axis.

An element is ``g`` in 0..7, bits ``(swap, flip_x, flip_y)``: ``A = F S`` with S the axis swap
(if ``g & 1``) applied first, then F negating x (``g & 2``) and y (``g & 4``). ``g = 0`` is the
identity. Rounding of positions to cells can differ at exact ties only (measure zero).

Training applies the elements to samples (``madp train --augment d4``); MADP's policy applies them
to the state it acts on and the inverse to its actions (``frame="d4"``,
:class:`madp.policies.SamplingSettings`): :func:`transform_state` and :func:`inverse_actions`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from madp.sim.launch import D4_SIZE, d4_matrix

__all__ = ["D4_SIZE", "d4_matrix", "transform_image", "transform_sample", "transform_state", "transform_points",
           "inverse_actions", "AUGMENTATIONS"]

AUGMENTATIONS = ("none", "d4")


def _vectors(v: Tensor, g: int) -> Tensor:
    """``A v`` for ``v [..., 2]``."""
    if g & 1:
        v = v.flip(-1)
    sign = torch.tensor([-1.0 if g & 2 else 1.0, -1.0 if g & 4 else 1.0], dtype=v.dtype, device=v.device)
    return v * sign


def inverse_actions(actions: Tensor, g: int) -> Tensor:
    """``A^-1 u = A^T u`` for ``actions [..., 2]``: an action chosen in the image g of the world, in
    the world's own axes."""
    a = torch.as_tensor(d4_matrix(g), dtype=actions.dtype, device=actions.device)
    return actions @ a


def transform_state(obs: Tensor, pos_m: Tensor, g: int, world_size: float) -> tuple[Tensor, Tensor]:
    """Element g applied to a state: ``obs [..., N, 4, S, S]`` and ``pos_m [..., N, 2]``."""
    o, x, _ = transform_sample(obs, pos_m, pos_m, g, world_size)
    return o, x


def transform_sample(obs: Tensor, pos_m: Tensor, actions: Tensor, g: int, world_size: float = 1024.0
                     ) -> tuple[Tensor, Tensor, Tensor]:
    """Element g of D4 applied to ``obs [..., N, 4, S, S]`` (channels local, comm_x, comm_y, boundary),
    ``pos_m [..., N, 2]`` (m) and ``actions [..., N, 2]`` (m/s). Returns new tensors."""
    if not 0 <= g < D4_SIZE:
        raise ValueError(f"D4 element must be in 0..7, got {g}")
    if g == 0:
        return obs, pos_m, actions
    img = transform_image(obs, g)
    comm = img[..., 1:3, :, :].movedim(-3, -1)  # [..., S, S, 2] offset vectors per pixel
    comm = _vectors(comm, g).movedim(-1, -3)
    img = torch.cat([img[..., :1, :, :], comm, img[..., 3:, :, :]], dim=-3)
    return img.contiguous(), transform_points(pos_m, g, world_size), _vectors(actions, g)


def transform_image(img: Tensor, g: int) -> Tensor:
    """Element g applied to images ``[..., S, S]`` indexed ``[x, y]`` over a square window: transposed
    for the axis swap, flipped along each reflected axis (values unchanged)."""
    img = img.transpose(-1, -2) if g & 1 else img
    dims = [d for d, bit in ((-2, 2), (-1, 4)) if g & bit]
    return img.flip(dims) if dims else img


def transform_points(pos_m: Tensor, g: int, world_size: float) -> Tensor:
    """Element g applied to points ``pos_m [..., 2]`` (m), about the world's centre."""
    if g == 0:
        return pos_m
    centre = world_size / 2.0
    return _vectors(pos_m - centre, g) + centre
