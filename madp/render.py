"""RGB frames of a coverage world: importance map, Voronoi cells and robots, vectorised numpy.

The frame is ``size × size`` pixels with north up (image row 0 is the world's top edge, y = W);
each pixel shows the world at its centre. Maps in madp are indexed ``[x, y]``, so the map is
transposed and flipped to image order.
"""

from __future__ import annotations

import numpy as np

BACKGROUND = np.array([255, 255, 255], dtype=np.float32)
IMPORTANCE = np.array([200, 60, 20], dtype=np.float32)  # colour of importance 1
CELL_EDGE = np.array([40, 40, 160], dtype=np.uint8)
ROBOT = np.array([0, 0, 0], dtype=np.uint8)


def _downsample(world_map: np.ndarray, size: int) -> np.ndarray:
    """Block means of the [W, W] map to [size, size] (nearest sampling when W is not a multiple)."""
    w = world_map.shape[0]
    if w % size == 0:
        k = w // size
        return world_map.reshape(size, k, size, k).mean(axis=(1, 3))
    idx = ((np.arange(size) + 0.5) * w / size).astype(np.int64)
    return world_map[np.ix_(idx, idx)]


def render_frame(world_map: np.ndarray, positions_m: np.ndarray, size: int = 512, robot_radius_px: float = 4.0) -> np.ndarray:
    """[size, size, 3] uint8: importance shaded from white, Voronoi edges, robots as black discs."""
    w = world_map.shape[0]
    phi = _downsample(world_map, size)  # [x, y]
    peak = float(phi.max()) or 1.0
    shade = (phi / peak).T[::-1]  # image [row, col] = [top-down y, x]
    img = BACKGROUND + shade[..., None] * (IMPORTANCE - BACKGROUND)
    img = img.astype(np.uint8)

    centres = (np.arange(size, dtype=np.float32) + 0.5) * (w / size)  # world coordinate of a pixel
    xs, ys = centres[None, :], centres[::-1, None]  # [1, size] columns, [size, 1] rows (y up)
    p = positions_m.astype(np.float32)
    best = np.full((size, size), np.inf, dtype=np.float32)
    label = np.zeros((size, size), dtype=np.int32)
    for i, (px, py) in enumerate(p):  # N passes over the frame, each vectorised
        d2 = (xs - px) ** 2 + (ys - py) ** 2
        closer = d2 < best
        best = np.where(closer, d2, best)
        label = np.where(closer, i, label)
    edge = np.zeros((size, size), dtype=bool)
    edge[:, 1:] |= label[:, 1:] != label[:, :-1]
    edge[1:, :] |= label[1:, :] != label[:-1, :]
    img[edge] = CELL_EDGE
    img[np.sqrt(best) * (size / w) <= robot_radius_px] = ROBOT
    return img
