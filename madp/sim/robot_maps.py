"""What each robot has sensed: its own copy of the world map, zero where it has not looked.

Maps are kept zero-padded by half a local window on every side, [N, W + S, W + S] float32 with
S = local_map_size, so every sensor update and every local-map crop is one rectangular slice with
no clipping (cells outside the world are zero in the world map too).
"""

from __future__ import annotations

import numpy as np


def robot_cells(positions_m: np.ndarray) -> np.ndarray:
    """The cell a robot is 'at', as the library rounds it: round half away from zero. [N, 2] int64."""
    return np.floor(np.asarray(positions_m) + 0.5).astype(np.int64)


class RobotMaps:
    """Per-robot sensed maps. ``sense`` copies each robot's sensor square from the world map."""

    def __init__(self, world_map_f32: np.ndarray, num_robots: int, sensor_size: int, local_size: int):
        w = world_map_f32.shape[0]
        self.world_size = w
        self.pad = local_size // 2
        self.sensor_half = sensor_size // 2
        self.local_size = local_size
        self.world_padded = np.zeros((w + 2 * self.pad, w + 2 * self.pad), dtype=np.float32)
        self.world_padded[self.pad : self.pad + w, self.pad : self.pad + w] = world_map_f32
        self.maps_padded = np.zeros((num_robots, w + 2 * self.pad, w + 2 * self.pad), dtype=np.float32)

    def sense(self, cells_xy: np.ndarray) -> None:
        """Copy the world's cells c-s/2 .. c+s/2-1 (per axis) into each robot's map."""
        lo = cells_xy - self.sensor_half + self.pad
        hi = cells_xy + self.sensor_half + self.pad
        # Robots farther than half a sensor outside the world see nothing (library rule); positions
        # are clamped inside the world, so the clip below only guards hand-made states.
        lo = np.clip(lo, 0, self.world_padded.shape[0])
        hi = np.clip(hi, 0, self.world_padded.shape[0])
        for n, ((x0, y0), (x1, y1)) in enumerate(zip(lo, hi)):  # one slice per robot
            self.maps_padded[n, x0:x1, y0:y1] = self.world_padded[x0:x1, y0:y1]

    def local_maps(self, cells_xy: np.ndarray) -> np.ndarray:
        """Raw local maps [N, S, S] float32: cells c-S/2 .. c+S/2-1 of each robot's map, zero outside."""
        s = self.local_size
        out = np.empty((len(cells_xy), s, s), dtype=np.float32)
        starts = cells_xy - s // 2 + self.pad
        for n, (x0, y0) in enumerate(starts):  # one slice per robot
            out[n] = self.maps_padded[n, x0 : x0 + s, y0 : y0 + s]
        return out

    def robot_map(self, n: int) -> np.ndarray:
        """Robot n's full map [W, W] (a view)."""
        p, w = self.pad, self.world_size
        return self.maps_padded[n, p : p + w, p : p + w]
