"""The d4 frame of one robot, in numpy: the element of the world's symmetry group a swarm acts in at a
control step, and that element applied to what one robot holds (its observation, positions) and,
inversely, to its action.

The same maps as :mod:`madp.models.symmetry` (which moves whole batches of torch tensors), computed
in the same float32 operations, so a robot moving its own state gets the bits the PyTorch policy gets
when it moves the swarm's. Element ``g`` in 0..7, bits ``(swap, flip_x, flip_y)``
(:func:`madp.sim.launch.d4_matrix`).
"""

from __future__ import annotations

import numpy as np

from madp.sim.launch import D4_SIZE, d4_matrix

__all__ = ["frame_element", "transform_observation", "transform_points", "inverse_action"]


def frame_element(seed: int, step: int) -> int:
    """The element of D4 (0..7) an episode of seed ``seed`` acts in at control step ``step``
    (``frame="d4"``): a hash of both, independent of the sampling noise, so every robot that knows the
    episode's seed and the step computes the same one."""
    return int(np.random.SeedSequence([int(seed) & ((1 << 63) - 1), int(step), 0xD4]).generate_state(1)[0] % D4_SIZE)


def _check(g: int) -> int:
    if not 0 <= int(g) < D4_SIZE:
        raise ValueError(f"D4 element must be in 0..7, got {g}")
    return int(g)


def _vectors(v: np.ndarray, g: int) -> np.ndarray:
    """``A v`` for ``v [..., 2]`` (a swap, then sign flips: exact in any float type)."""
    if g & 1:
        v = v[..., ::-1]
    sign = np.array([-1.0 if g & 2 else 1.0, -1.0 if g & 4 else 1.0], dtype=v.dtype)
    return v * sign


def transform_observation(obs: np.ndarray, g: int) -> np.ndarray:
    """Element g applied to one robot's observation ``obs [4, S, S]`` (channels local map, comm x,
    comm y, boundary; each an image indexed ``[x, y]``): the images moved as the window is, and the
    comm channels' offset vectors multiplied by A. Returns a new C-contiguous array."""
    g = _check(g)
    img = obs.swapaxes(-1, -2) if g & 1 else obs
    if g & 2:
        img = img[..., ::-1, :]
    if g & 4:
        img = img[..., :, ::-1]
    comm = _vectors(np.moveaxis(img[..., 1:3, :, :], -3, -1), g)
    return np.ascontiguousarray(np.concatenate([img[..., :1, :, :], np.moveaxis(comm, -1, -3), img[..., 3:, :, :]],
                                               axis=-3))


def transform_points(points_m: np.ndarray, g: int, world_size_m: float) -> np.ndarray:
    """``points_m [..., 2]`` float32 moved by element g about the world's centre, ``A (p - c) + c``, in
    float32 arithmetic (as the PyTorch policy moves its float32 positions)."""
    g = _check(g)
    p = np.asarray(points_m, dtype=np.float32)
    if g == 0:
        return p
    c = np.float32(world_size_m / 2.0)
    return _vectors(p - c, g) + c


def inverse_action(action: np.ndarray, g: int) -> np.ndarray:
    """``A^T u`` for ``action [..., 2]``: an action chosen in image g of the world, in the world's axes."""
    return np.asarray(action) @ d4_matrix(_check(g)).astype(np.asarray(action).dtype)
