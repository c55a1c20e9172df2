"""What each robot has sensed: its own copy of the world map, zero where it has not looked.

Maps are kept zero-padded by half a local window on every side, [N, W + S, W + S] float32 with
S = local_map_size, so every sensor update and every local-map crop is one rectangular slice with
no clipping (cells outside the world are zero in the world map too).

For sums over rows of a robot's own map (DCVT's Voronoi cells) the maps also keep, once asked for,
prefix sums along y in two levels: ``cum[n, c, k]`` = Σ over world rows < 16·k of (map,
map·(y + 0.5)) in column c (float64), and running sums inside each 16-row block (float32, sums of
at most 16 cells). A sum over any rows [lo, hi) is then four lookups. Sensing changes a robot's map
only inside its 64 × 64 square, so after each step only the blocks under the squares of robots that
moved to a new cell are recomputed.
"""

from __future__ import annotations

import numpy as np

from . import kernels
from .kernels import BLOCK  # rows per block of the block prefix sums
from .observations import resize_windows

#: Side (m) of the blocks of a robot's explored map (:attr:`RobotMaps.explored`).
EXPLORED_BLOCK_M = 4


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
        self._cum: np.ndarray | None = None  # [N, W, W/16 + 1, 2] float64 sums of whole blocks below
        self._within: np.ndarray | None = None  # [N, W, W/16, 16, 2] float32 running sums in a block
        self._tot: np.ndarray | None = None  # [N, W, W/16, 2] float64 block totals
        self._stale: list[np.ndarray] = []  # sensed cells [N, 2] since the block sums were updated
        self._last_cells: np.ndarray | None = None
        self._last_lo = self._last_hi = np.zeros((num_robots, 2), dtype=np.int64)  # last sensed squares (padded)
        # Bounding box of what each robot has sensed, in padded coordinates: (x0, y0) [N, 2] and
        # (x1, y1) [N, 2]; its map is zero outside it (maps_padded is written by sense() alone).
        self.seen_lo = np.full((num_robots, 2), self.maps_padded.shape[1], dtype=np.int64)
        self.seen_hi = np.zeros((num_robots, 2), dtype=np.int64)
        # What each robot has looked at (the library's exploration map), in blocks of
        # EXPLORED_BLOCK_M cells of the padded grid: [N, B, B] bool, block b covering padded cells
        # [4b, 4b + 4) per axis; True once a sensor square has covered the whole block.
        b = self.maps_padded.shape[1] // EXPLORED_BLOCK_M
        self.explored = np.zeros((num_robots, b, b), dtype=bool)

    def sense(self, cells_xy: np.ndarray) -> None:
        """Copy the world's cells c-s/2 .. c+s/2-1 (per axis) into each robot's map."""
        cells_xy = np.asarray(cells_xy, dtype=np.int64)
        lo = cells_xy - self.sensor_half + self.pad
        hi = cells_xy + self.sensor_half + self.pad
        # Robots farther than half a sensor outside the world see nothing (library rule); positions
        # are clamped inside the world, so the clip below only guards hand-made states.
        lo = np.clip(lo, 0, self.world_padded.shape[0])
        hi = np.clip(hi, 0, self.world_padded.shape[0])
        moved = np.ones(len(cells_xy), bool) if self._last_cells is None else (cells_xy != self._last_cells).any(1)
        self._last_cells = cells_xy.copy()
        kernels.sense_squares(self.maps_padded, self.world_padded, lo, hi, self._last_lo, self._last_hi)
        self._last_lo, self._last_hi = lo, hi
        np.minimum(self.seen_lo, lo, out=self.seen_lo)
        np.maximum(self.seen_hi, hi, out=self.seen_hi)
        kernels.mark_explored(self.explored, lo, hi, EXPLORED_BLOCK_M)
        if self._cum is not None and moved.any():
            self._stale.append(np.where(moved[:, None], cells_xy, -(1 << 40)))

    # --- prefix sums along y, in blocks of 16 rows -------------------------------------------------
    def block_sums(self) -> tuple[np.ndarray, np.ndarray]:
        """(cum [N, W, W/16 + 1, 2] float64, within [N, W, W/16, 16, 2] float32), up to date: built
        whole the first time, then recomputed under the sensor squares of the robots that moved
        (:func:`madp.sim.kernels.refresh_blocks`, bit-identical to a fresh build)."""
        if self._cum is None:
            n, w = len(self.maps_padded), self.world_size
            nb = w // BLOCK
            self._within = np.empty((n, w, nb, BLOCK, 2), np.float32)
            self._tot = np.empty((n, w, nb, 2))
            self._cum = np.zeros((n, w, nb + 1, 2))
            kernels.refresh_all(self.maps_padded, self.pad, self._within, self._tot, self._cum)
            self._stale.clear()
        for cells in self._stale:
            kernels.refresh_blocks(self.maps_padded, self.pad, self._within, self._tot, self._cum, cells,
                                   self.sensor_half)
        self._stale.clear()
        return self._cum, self._within

    def row_sums(self, robot: np.ndarray, column: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Σ robot's map over world rows [lo, hi) of world column, and Σ map·(y + 0.5): float64 [P] each.

        Prefix at row h = (whole blocks below h) + (running sum inside h's block up to row h - 1)."""
        cum, within = self.block_sums()
        i64 = lambda a: np.ascontiguousarray(a, dtype=np.int64)  # noqa: E731
        return kernels.block_row_sums(within, cum, i64(robot), i64(column), i64(lo), i64(hi))

    def local_maps(self, cells_xy: np.ndarray) -> np.ndarray:
        """Raw local maps [N, S, S] float32: cells c-S/2 .. c+S/2-1 of each robot's map, zero outside."""
        s = self.local_size
        out = np.empty((len(cells_xy), s, s), dtype=np.float32)
        starts = cells_xy - s // 2 + self.pad
        for n, (x0, y0) in enumerate(starts):  # one slice per robot
            out[n] = self.maps_padded[n, x0 : x0 + s, y0 : y0 + s]
        return out

    def resized_local_maps(self, cells_xy: np.ndarray, out_size: int) -> np.ndarray:
        """The local maps resized to [N, out, out] float32, read straight from the padded maps: bit for
        bit ``resize_maps(self.local_maps(cells_xy), out_size)``, without the crops' copy, and
        skipping what lies outside each robot's sensed box (zeros either way)."""
        starts = np.asarray(cells_xy, dtype=np.int64) - self.local_size // 2 + self.pad
        box = np.concatenate([self.seen_lo[:, :1], self.seen_hi[:, :1], self.seen_lo[:, 1:], self.seen_hi[:, 1:]], 1)
        return resize_windows(self.maps_padded, starts, self.local_size, out_size, box)

    def robot_map(self, n: int) -> np.ndarray:
        """Robot n's full map [W, W] (a view)."""
        p, w = self.pad, self.world_size
        return self.maps_padded[n, p : p + w, p : p + w]
