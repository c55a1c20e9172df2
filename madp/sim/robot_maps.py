"""What each robot has sensed: its own copy of the world map, zero where it has not looked.

Maps are kept zero-padded by half a local window on every side, [N, W + S, W + S] float32 with
S = local_map_size, so every sensor update and every local-map crop is one rectangular slice with
no clipping (cells outside the world are zero in the world map too).

For sums over rows of a robot's own map (DCVT's Voronoi cells) the maps also keep, once asked for,
block prefix sums along y: ``cum[n, c, k]`` = Σ over world rows < 16·k of (map, map·(y + 0.5)) in
column c. Sensing changes a robot's map only inside its 64 × 64 square, so after each step only the
blocks under the squares of robots that moved to a new cell are recomputed.
"""

from __future__ import annotations

import numpy as np

BLOCK = 16  # rows per block of the block prefix sums


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
        self._cum: np.ndarray | None = None  # [N, W, W/16 + 1, 2] float64, built on first use
        self._blocks: np.ndarray | None = None  # [N, W, W/16, 2] float64 block sums
        self._stale: list[np.ndarray] = []  # sensed cells [N, 2] since the block sums were updated
        self._last_cells: np.ndarray | None = None

    def sense(self, cells_xy: np.ndarray) -> None:
        """Copy the world's cells c-s/2 .. c+s/2-1 (per axis) into each robot's map."""
        lo = cells_xy - self.sensor_half + self.pad
        hi = cells_xy + self.sensor_half + self.pad
        # Robots farther than half a sensor outside the world see nothing (library rule); positions
        # are clamped inside the world, so the clip below only guards hand-made states.
        lo = np.clip(lo, 0, self.world_padded.shape[0])
        hi = np.clip(hi, 0, self.world_padded.shape[0])
        moved = np.ones(len(cells_xy), bool) if self._last_cells is None else (cells_xy != self._last_cells).any(1)
        self._last_cells = cells_xy.copy()
        for n in np.flatnonzero(moved):  # one slice per robot that reached a new cell
            (x0, y0), (x1, y1) = lo[n], hi[n]
            self.maps_padded[n, x0:x1, y0:y1] = self.world_padded[x0:x1, y0:y1]
        if self._cum is not None and moved.any():
            self._stale.append(np.where(moved[:, None], cells_xy, -(1 << 40)))

    # --- block prefix sums along y -----------------------------------------------------------------
    def _block_sums(self, robots: np.ndarray, cols: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        """(Σ map, Σ map·(y+0.5)) of blocks [R, B] in columns [R, C] of robots [R]: [R, C, B, 2]."""
        rows = blocks[:, None, :, None] * BLOCK + np.arange(BLOCK)  # [R, 1, B, 16] world rows
        vals = self.maps_padded[robots[:, None, None, None], cols[:, :, None, None] + self.pad, rows + self.pad]
        vals = vals.astype(np.float64)
        return np.stack([vals.sum(-1), (vals * (rows + 0.5)).sum(-1)], -1)

    def _refresh(self) -> np.ndarray:
        n, w = len(self.maps_padded), self.world_size
        nb = w // BLOCK
        if self._cum is None:
            self._blocks = np.empty((n, w, nb, 2))
            for r in range(n):  # once per episode
                m = self.robot_map(r).astype(np.float64).reshape(w, nb, BLOCK)
                y = np.arange(w, dtype=np.float64).reshape(nb, BLOCK) + 0.5
                self._blocks[r, :, :, 0] = m.sum(-1)
                self._blocks[r, :, :, 1] = (m * y).sum(-1)
            self._cum = np.zeros((n, w, nb + 1, 2))
            np.cumsum(self._blocks, axis=2, out=self._cum[:, :, 1:])
            self._stale.clear()
        for cells in self._stale:
            robots = np.flatnonzero(cells[:, 0] > -(1 << 39))
            c = cells[robots]
            cols = np.clip(c[:, 0:1] - self.sensor_half + np.arange(2 * self.sensor_half), 0, w - 1)  # [R, 64]
            first = np.clip(c[:, 1] - self.sensor_half, 0, w - 1) // BLOCK
            blocks = np.minimum(first[:, None] + np.arange(2 * self.sensor_half // BLOCK + 1), nb - 1)  # [R, 5]
            ri = robots[:, None]
            self._blocks[ri[:, :, None], cols[:, :, None], blocks[:, None, :]] = self._block_sums(robots, cols, blocks)
            self._cum[ri, cols, 1:] = np.cumsum(self._blocks[ri, cols], axis=2)
        self._stale.clear()
        return self._cum

    def row_sums(self, robot: np.ndarray, column: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Σ robot's map over world rows [lo, hi) of world column, and Σ map·(y + 0.5): float64 [P] each."""
        cum = self._refresh()
        p = len(robot)
        r, c, h = np.concatenate([robot, robot]), np.concatenate([column, column]), np.concatenate([hi, lo])
        b = h // BLOCK
        t = np.arange(BLOCK)
        rows = b[:, None] * BLOCK + t  # [2P, 16]
        wp = self.maps_padded.shape[1]
        flat = ((r * wp + c + self.pad) * wp + self.pad)[:, None] + np.minimum(rows, self.world_size - 1)
        vals = np.take(self.maps_padded.reshape(-1), flat)
        vals = np.where(t < (h - b * BLOCK)[:, None], vals, np.float32(0)).astype(np.float64)
        part = np.stack([vals.sum(1), (vals * (rows + 0.5)).sum(1)], 1)
        total = cum[r, c, b] + part
        d = total[:p] - total[p:]
        return d[:, 0], d[:, 1]

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
