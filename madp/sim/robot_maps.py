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

BLOCK = 16  # rows per block of the block prefix sums
_OFFSETS = np.arange(BLOCK, dtype=np.float32) + np.float32(0.5)  # a row's centre within its block


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

    # --- prefix sums along y, in blocks of 16 rows -------------------------------------------------
    def _running_sums(self, robots: np.ndarray, cols: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        """Within-block running sums of (map, map·(t + 0.5)), t the row's offset in its block, for
        the consecutive blocks first[R] .. first + B - 1 of columns [R, C]: [R, C, B, 16, 2] float32;
        entry t sums rows 0..t of its block."""
        wp = self.maps_padded.shape[1]
        nrows = blocks.shape[1] * BLOCK
        start = (robots[:, None] * wp + cols + self.pad) * wp + self.pad + blocks[:, :1] * BLOCK  # [R, C]
        vals = np.take(self.maps_padded.reshape(-1), start[:, :, None] + np.arange(nrows))
        vals = vals.reshape(*cols.shape, blocks.shape[1], BLOCK)
        out = np.empty(vals.shape + (2,), np.float32)
        np.cumsum(vals, axis=-1, out=out[..., 0])
        np.cumsum(vals * _OFFSETS, axis=-1, out=out[..., 1])
        return out

    def _refresh(self) -> tuple[np.ndarray, np.ndarray]:
        n, w = len(self.maps_padded), self.world_size
        nb = w // BLOCK
        if self._cum is None:
            self._within = np.empty((n, w, nb, BLOCK, 2), np.float32)
            self._tot = np.empty((n, w, nb, 2))
            all_cols = np.arange(w)
            for r in range(n):  # once per episode
                self._within[r] = self._within_of(r, all_cols)
                self._tot[r] = self._block_totals(self._within[r], 0)
            self._cum = np.zeros((n, w, nb + 1, 2))
            np.cumsum(self._tot, axis=2, out=self._cum[:, :, 1:])
            self._stale.clear()
        within = self._within.reshape(-1, BLOCK, 2)
        tot, cum = self._tot.reshape(-1, nb, 2), self._cum.reshape(-1, nb + 1, 2)
        for cells in self._stale:
            robots = np.flatnonzero(cells[:, 0] > -(1 << 39))
            c = cells[robots]
            cols = np.clip(c[:, 0:1] - self.sensor_half + np.arange(2 * self.sensor_half), 0, w - 1)  # [R, 64]
            first = np.clip(c[:, 1] - self.sensor_half, 0, w - 1) // BLOCK
            nblk = min(2 * self.sensor_half // BLOCK + 1, nb)  # a sensor square may span the whole world
            first = np.minimum(first, nb - nblk)  # keep the 5 consecutive blocks inside the map
            blocks = first[:, None] + np.arange(nblk)  # [R, 5]
            line = robots[:, None] * w + cols  # [R, 64]
            rs = self._running_sums(robots, cols, blocks)
            within[(line[:, :, None] * nb + blocks[:, None, :]).reshape(-1)] = rs.reshape(-1, BLOCK, 2)
            tot_lines = tot[line.reshape(-1)]  # [R·64, nb, 2]
            tl = tot_lines.reshape(*line.shape, nb, 2)
            np.put_along_axis(tl, blocks[:, None, :, None], self._block_totals(rs, blocks[:, None, :]), axis=2)
            tot[line.reshape(-1)] = tot_lines
            cum[line.reshape(-1), 1:] = np.cumsum(tot_lines, axis=1)
        self._stale.clear()
        return self._cum, self._within

    def _within_of(self, r: int, cols: np.ndarray) -> np.ndarray:
        nb = self.world_size // BLOCK
        m = self.robot_map(r)[cols].reshape(len(cols), nb, BLOCK)
        out = np.empty((len(cols), nb, BLOCK, 2), np.float32)
        np.cumsum(m, axis=-1, out=out[..., 0])
        np.cumsum(m * _OFFSETS, axis=-1, out=out[..., 1])
        return out

    @staticmethod
    def _block_totals(running: np.ndarray, blocks) -> np.ndarray:
        """Per-block totals [..., B, 2] float64 of (map, map·(y + 0.5)) from running sums
        [..., B, 16, 2]; ``blocks`` (broadcastable to [..., B]) are the blocks' indices (0: all from 0)."""
        tot = running[..., BLOCK - 1, :].astype(np.float64)
        if np.isscalar(blocks):
            blocks = np.arange(tot.shape[-2])
        tot[..., 1] += np.asarray(blocks) * BLOCK * tot[..., 0]
        return tot

    def row_sums(self, robot: np.ndarray, column: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Σ robot's map over world rows [lo, hi) of world column, and Σ map·(y + 0.5): float64 [P] each.

        Prefix at row h = (whole blocks below h) + (running sum inside h's block up to row h - 1)."""
        cum, within = self._refresh()
        p = len(robot)
        r, c, h = np.concatenate([robot, robot]), np.concatenate([column, column]), np.concatenate([hi, lo])
        b, t = np.divmod(h, BLOCK)
        nb = within.shape[2]
        line = r * within.shape[1] + c
        cell = (line * nb + np.minimum(b, nb - 1)) * BLOCK + np.maximum(t - 1, 0)
        part = np.take(within.reshape(-1, 2), cell, axis=0).astype(np.float64)
        part[:, 1] += b * BLOCK * part[:, 0]  # block-local offsets → world rows
        part[t == 0] = 0.0
        total = np.take(cum.reshape(-1, 2), line * (nb + 1) + b, axis=0) + part
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
