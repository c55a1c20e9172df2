"""Where a swarm starts, and the world's symmetries.

Launch layouts of *training* datasets (``madp datagen --launch``; the evaluation suites' own
rectangles are fixed in :mod:`madp.eval.suites` and never drawn here):

* ``uniform``: every robot anywhere in the world (the library's default draw, what
  :meth:`Scenario.random` does).
* ``packed``: a packed or clustered start, one of three kinds with probability 1/3 each:

  - **box**: a rectangle of sides 32-320 m each (so any aspect from square to 1:10), rotated by
    any angle, centred anywhere in the world;
  - **band**: the robots within a strip of width 48-320 m through a random point of the world, at
    any orientation (a band along an edge, across the middle, or diagonal);
  - **clusters**: 2-4 boxes of sides 24-160 m around random centres, each robot in one of them.

  Every position is clipped into the world (1e-4 m inside its border, as the simulator puts
  robots back).

The world's symmetries (the dihedral group D4 of the square): :func:`d4_matrix` and
:func:`d4_points` move points by element ``g`` in 0..7, bits ``(swap, flip_x, flip_y)``: the
axis swap first, then the reflections (``g = 0`` is the identity). :mod:`madp.models.symmetry`
applies the same elements to samples and :meth:`Scenario.d4_image` to scenarios.
"""

from __future__ import annotations

import numpy as np

from madp.errors import SettingError

__all__ = ["TRAINING_LAUNCHES", "D4_SIZE", "d4_matrix", "d4_points", "draw_launch"]

TRAINING_LAUNCHES = ("uniform", "packed")
D4_SIZE = 8
BORDER_EPS_M = 1e-4


def d4_matrix(g: int) -> np.ndarray:
    """``A [2, 2]`` of element g: ``F S`` with S the axis swap (``g & 1``), then F negating x
    (``g & 2``) and y (``g & 4``)."""
    if not 0 <= g < D4_SIZE:
        raise ValueError(f"D4 element must be in 0..7, got {g}")
    a = np.array([[0.0, 1.0], [1.0, 0.0]]) if g & 1 else np.eye(2)
    return np.diag([-1.0 if g & 2 else 1.0, -1.0 if g & 4 else 1.0]) @ a


def d4_points(points_m: np.ndarray, g: int, world_size_m: float) -> np.ndarray:
    """``points_m [..., 2]`` moved by element g about the world's centre: ``A (p - c) + c``."""
    c = world_size_m / 2.0
    return (np.asarray(points_m, dtype=np.float64) - c) @ d4_matrix(g).T + c


def _clip(points_m: np.ndarray, world_size_m: float) -> np.ndarray:
    return np.clip(points_m, BORDER_EPS_M, world_size_m - BORDER_EPS_M)


def _rotation(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s], [s, c]])


def _box(rng: np.random.Generator, n: int, w: float, side_range_m: tuple[float, float]) -> np.ndarray:
    """``n`` points uniform in a rotated rectangle of random sides, centred anywhere in the world."""
    sides = rng.uniform(*side_range_m, size=2)
    centre = rng.uniform(0.0, w, size=2)
    local = (rng.uniform(-0.5, 0.5, size=(n, 2)) * sides) @ _rotation(rng.uniform(0.0, np.pi)).T
    return local + centre


def _band(rng: np.random.Generator, n: int, w: float) -> np.ndarray:
    """``n`` points uniform over the part of the world within a strip of random width through a
    random point at a random orientation (rejection from uniform draws)."""
    width = rng.uniform(48.0, 320.0)
    through = rng.uniform(0.0, w, size=2)
    normal = _rotation(rng.uniform(0.0, np.pi)) @ np.array([0.0, 1.0])
    kept: list[np.ndarray] = []
    count = 0
    while count < n:
        cand = rng.uniform(0.0, w, size=(8 * n, 2))
        cand = cand[np.abs((cand - through) @ normal) <= width / 2]
        kept.append(cand)
        count += len(cand)
    return np.concatenate(kept)[:n]


def _clusters(rng: np.random.Generator, n: int, w: float) -> np.ndarray:
    k = int(rng.integers(2, 5))
    which = rng.integers(0, k, size=n)
    out = np.empty((n, 2))
    for j in range(k):
        members = which == j
        out[members] = _box(rng, int(members.sum()), w, (24.0, 160.0))
    return out


def draw_launch(rng: np.random.Generator, launch: str, num_robots: int, world_size_m: float) -> np.ndarray:
    """Start positions ``[num_robots, 2]`` (m) of a training launch layout (module docstring)."""
    w = float(world_size_m)
    if launch == "uniform":
        return rng.uniform(BORDER_EPS_M, w - BORDER_EPS_M, size=(num_robots, 2))
    if launch != "packed":
        raise SettingError("launch", f"expected one of {', '.join(TRAINING_LAUNCHES)}, got {launch!r}")
    kind = int(rng.integers(0, 3))
    if kind == 0:
        pts = _box(rng, num_robots, w, (32.0, 320.0))
    elif kind == 1:
        pts = _band(rng, num_robots, w)
    else:
        pts = _clusters(rng, num_robots, w)
    return _clip(pts, w)
