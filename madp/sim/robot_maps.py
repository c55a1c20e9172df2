"""What each robot has sensed: its own copy of the world map, zero where it has not looked.

A robot's map is written from its sensor's readings alone (:class:`SensorReading`,
:meth:`RobotMaps.record`); the world's side reads them (:meth:`RobotMaps.read`), and the simulator's
step does both at once (:meth:`RobotMaps.sense`, the same kernel and bookkeeping). The simulator
keeps every robot's map in one :class:`RobotMaps`; a robot holds its own in one of one robot with no
world map (:class:`madp.robot.RobotAgent`).

Maps are kept zero-padded by half a local window on every side, [N, W + S, W + S] float32 with
S = local_map_size, so every sensor update and every local-map crop is one rectangular slice with
no clipping (cells outside the world are zero in the world map too). They are written by
:meth:`RobotMaps.record` (and :meth:`RobotMaps.sense`) alone, which keep each robot's sensed box
(:attr:`RobotMaps.seen_lo`, :attr:`RobotMaps.seen_hi`): what reads a map whole (the block sums
below, the resized local windows, the selection rules' block sums) reads only inside that box, the
rest being zero. A map's memory is made when first written, in small pages (:func:`sparse_zeros`).

For sums over rows of a robot's own map (DCVT's Voronoi cells) the maps also keep, once asked for,
prefix sums along y in two levels: ``cum[n, c, k]`` = Σ over world rows < 16·k of (map,
map·(y + 0.5)) in column c (float64), and running sums inside each 16-row block (float32, sums of
at most 16 cells). A sum over any rows [lo, hi) is then four lookups. Sensing changes a robot's map
only inside its 64 × 64 square, so after each step only the blocks under the squares of robots that
moved to a new cell are recomputed.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from . import kernels
from .kernels import BLOCK  # rows per block of the block prefix sums
from .observations import resize_windows, stack_observations

#: Side (m) of the blocks of a robot's explored map (:attr:`RobotMaps.explored`).
EXPLORED_BLOCK_M = 4


def sparse_zeros(shape: tuple[int, ...], dtype) -> np.ndarray:
    """A zero array of ``shape`` in the system's small pages, each made (and zeroed) when first written:
    for the robots' maps, each written only where its robot has sensed (a 64-cell square per step
    in a map of 1280² cells), where 2 MiB pages, which numpy asks for, would each be zeroed whole."""
    count = int(np.prod(shape))
    buf = mmap.mmap(-1, max(count * np.dtype(dtype).itemsize, 1))  # anonymous memory: zeros until written
    if hasattr(mmap, "MADV_NOHUGEPAGE"):  # Linux
        buf.madvise(mmap.MADV_NOHUGEPAGE)
    return np.frombuffer(buf, dtype, count).reshape(shape)


def robot_cells(positions_m: np.ndarray) -> np.ndarray:
    """The cell a robot is 'at', as the library rounds it: round half away from zero. [N, 2] int64."""
    return np.floor(np.asarray(positions_m) + 0.5).astype(np.int64)


@dataclass(frozen=True)
class SensorReading:
    """One reading of a robot's sensor at one control step, as a real sensor returns it:
    ``lo_cell [2]`` int64: the world cell (x, y) of the sensor window's lower corner (the robot's
    rounded true position − sensor_size // 2 per axis); ``values [s, s]`` float32: the importance of
    the world cells lo .. lo + s − 1, indexed [x, y], 0 for cells outside the world
    (s = sensor_size). :meth:`RobotMaps.read` reads every robot's at once."""

    lo_cell: np.ndarray
    values: np.ndarray


class RobotMaps:
    """Per-robot sensed maps, built from sensor readings alone: :meth:`record` writes readings into
    the maps; :meth:`read` is the world's side, what each robot's sensor returns from ``world_map_f32``;
    :meth:`sense` is both (the simulator's step). ``world_map_f32=None``: maps with no world (what a
    robot holds of itself, :class:`madp.robot.RobotAgent`); ``world_size`` is then required."""

    def __init__(self, world_map_f32: np.ndarray | None, num_robots: int, sensor_size: int, local_size: int,
                 world_size: int | None = None):
        w = int(world_size) if world_map_f32 is None else world_map_f32.shape[0]
        self.world_size = w
        self.pad = local_size // 2
        self.sensor_half = sensor_size // 2
        self.local_size = local_size
        self.world_padded: np.ndarray | None = None
        if world_map_f32 is not None:
            self.world_padded = np.zeros((w + 2 * self.pad, w + 2 * self.pad), dtype=np.float32)
            self.world_padded[self.pad : self.pad + w, self.pad : self.pad + w] = world_map_f32
        self.maps_padded = sparse_zeros((num_robots, w + 2 * self.pad, w + 2 * self.pad), np.float32)
        self._cum: np.ndarray | None = None  # [N, W, W/16 + 1, 2] float64 sums of whole blocks below
        self._within: np.ndarray | None = None  # [N, W, W/16, 16, 2] float32 running sums in a block
        self._tot: np.ndarray | None = None  # [N, W, W/16, 2] float64 block totals
        self._stale: list[np.ndarray] = []  # sensed cells [N, 2] since the block sums were updated
        self._last_cells: np.ndarray | None = None
        self._last_lo = self._last_hi = np.zeros((num_robots, 2), dtype=np.int64)  # last sensed squares (padded)
        # Bounding box of what each robot has sensed, in padded coordinates: (x0, y0) [N, 2] and
        # (x1, y1) [N, 2]; its map is zero outside it (maps_padded is written by record() alone: a
        # caller writing it otherwise widens the box to what it wrote).
        self.seen_lo = np.full((num_robots, 2), self.maps_padded.shape[1], dtype=np.int64)
        self.seen_hi = np.zeros((num_robots, 2), dtype=np.int64)
        # What each robot has looked at (the library's exploration map), in blocks of
        # EXPLORED_BLOCK_M cells of the padded grid: [N, B, B] bool, block b covering padded cells
        # [4b, 4b + 4) per axis; True once a sensor square has covered the whole block.
        b = self.maps_padded.shape[1] // EXPLORED_BLOCK_M
        self.explored = np.zeros((num_robots, b, b), dtype=bool)

    def read(self, cells_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What each robot's sensor returns at cells ``cells_xy [N, 2]`` (the world's side):
        ``(lo_cell [N, 2] int64, values [N, s, s] float32)``, the world's cells c − s/2 .. c + s/2 − 1
        per axis, 0 outside the world (robot n's :class:`SensorReading`)."""
        world = self._world()
        lo_cell = np.asarray(cells_xy, dtype=np.int64).reshape(-1, 2) - self.sensor_half
        s, size = 2 * self.sensor_half, world.shape[0]
        lo = lo_cell + self.pad
        if ((lo >= 0) & (lo <= size - s)).all():  # every square inside the padded world (the rule): one gather
            return lo_cell, sliding_window_view(world, (s, s))[lo[:, 0], lo[:, 1]]
        values = np.zeros((len(lo), s, s), np.float32)
        a, b = np.clip(lo, 0, size), np.clip(lo + s, 0, size)
        for n in np.flatnonzero((b > a).all(1)):  # squares reaching past the padding (hand-made states)
            values[n, a[n, 0] - lo[n, 0] : b[n, 0] - lo[n, 0], a[n, 1] - lo[n, 1] : b[n, 1] - lo[n, 1]] = \
                world[a[n, 0] : b[n, 0], a[n, 1] : b[n, 1]]
        return lo_cell, values

    def record(self, lo_cell: np.ndarray, values: np.ndarray) -> None:
        """Write robot n's sensor reading (``lo_cell [N, 2]``, ``values [N, s, s]`` float32, as
        :meth:`read` returns them) into its map; mark what it has seen and explored."""
        lo_cell = np.asarray(lo_cell, dtype=np.int64).reshape(-1, 2)
        values = np.ascontiguousarray(values, dtype=np.float32)
        s = 2 * self.sensor_half
        if values.shape != (len(lo_cell), s, s):
            raise ValueError(f"expected readings of shape {(len(lo_cell), s, s)}, got {values.shape}")
        self._store(lo_cell, values, lo_cell + self.pad)

    def sense(self, cells_xy: np.ndarray) -> None:
        """Each robot at ``cells_xy [N, 2]`` senses: the world's cells c − s/2 .. c + s/2 − 1 (per axis)
        land in its map, as :meth:`record` of :meth:`read` writes them (without building the readings)."""
        lo_cell = np.asarray(cells_xy, dtype=np.int64).reshape(-1, 2) - self.sensor_half
        self._store(lo_cell, self._world()[None], np.zeros_like(lo_cell))

    def _world(self) -> np.ndarray:
        if self.world_padded is None:
            raise ValueError("these maps hold no world map: there is nothing to read")
        return self.world_padded

    def _store(self, lo_cell: np.ndarray, sources: np.ndarray, origins: np.ndarray) -> None:
        """The squares at ``lo_cell [N, 2]`` into the maps, padded cell p of robot n's from
        ``sources[n or 0][p - origins[n]]`` (:func:`madp.sim.kernels.sense_squares`), and the bookkeeping."""
        cells_xy = lo_cell + self.sensor_half
        size = self.maps_padded.shape[1]
        # Robots farther than half a sensor outside the world see nothing (library rule); positions
        # are clamped inside the world, so the clip below only guards hand-made states.
        lo = np.clip(lo_cell + self.pad, 0, size)
        hi = np.clip(lo_cell + self.pad + 2 * self.sensor_half, 0, size)
        moved = np.ones(len(cells_xy), bool) if self._last_cells is None else (cells_xy != self._last_cells).any(1)
        self._last_cells = cells_xy.copy()
        kernels.sense_squares(self.maps_padded, sources, origins, lo, hi, self._last_lo, self._last_hi)
        self._last_lo, self._last_hi = lo, hi
        np.minimum(self.seen_lo, lo, out=self.seen_lo)
        np.maximum(self.seen_hi, hi, out=self.seen_hi)
        kernels.mark_explored(self.explored, lo, hi, EXPLORED_BLOCK_M)
        if self._cum is not None and moved.any():
            self._stale.append(np.where(moved[:, None], cells_xy, -(1 << 40)))

    def observations(self, positions_m: np.ndarray, comm_radius_m: float, out_size: int,
                     view: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """O [N, 4, out, out] float32 of the robots at (their own estimates of) ``positions_m [N, 2]``:
        each one's own map and the border in the window around its rounded position, and its
        neighbours: ``view = (known [N, M] bool, positions_m [N, M, 2])``, those it knows of
        (:func:`madp.sim.observations.stack_observations`; None: every robot's true neighbours)."""
        cells = robot_cells(positions_m)
        return stack_observations(self.resized_local_maps(cells, out_size), cells, positions_m, self.world_size,
                                  comm_radius_m, self.local_size, view=view)

    # --- prefix sums along y, in blocks of 16 rows -------------------------------------------------
    def block_sums(self) -> tuple[np.ndarray, np.ndarray]:
        """(cum [N, W, W/16 + 1, 2] float64, within [N, W, W/16, 16, 2] float32), up to date: built
        the first time (inside each robot's sensed box: zero outside it), then recomputed under the
        sensor squares of the robots that moved (:func:`madp.sim.kernels.refresh_blocks`,
        bit-identical to a fresh build)."""
        if self._cum is None:
            n, w = len(self.maps_padded), self.world_size
            nb = w // BLOCK
            self._within = np.zeros((n, w, nb, BLOCK, 2), np.float32)
            self._tot = np.zeros((n, w, nb, 2))
            self._cum = np.zeros((n, w, nb + 1, 2))
            kernels.refresh_all(self.maps_padded, self.pad, self._within, self._tot, self._cum, self.seen_lo,
                                self.seen_hi)
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

