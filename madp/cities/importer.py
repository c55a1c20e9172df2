"""City importer: traffic-signal locations -> features of a coverage scenario.

The paper's real-world suite (``cities/README.md``) builds one scenario per city: a
1024 m x 1024 m neighbourhood with one Gaussian feature of the importance density function at every
traffic signal inside it. This module turns a file of signal locations into such a scenario:

1. **Read** the signals (WGS84 degrees) from a CSV, GeoJSON or Overpass JSON file, optionally
   gzipped (:mod:`madp.cities.signal_files`).
2. **Project** them to local metres about a reference point, on the WGS84 ellipsoid
   (:mod:`madp.cities.geometry`).
3. **Choose the square**: the ``side x side`` square holding the most signals, found exactly
   (:func:`madp.cities.geometry.find_best_square`), the search repeated in a frame re-projected about
   the chosen square's centre until that centre sits within 1 cm of the frame's reference point
   (normally 2-3 rounds), so the square and the features are expressed in a projection accurate
   about the square itself.
4. **Features**: one per signal in the square, ``(mu_x, mu_y, sigma, peak)`` with the mean in the
   square's frame ``[0, side)`` metres, ``sigma ~ U(sigma_range)`` and ``peak ~ U(peak_range)`` drawn
   from ``numpy.random.default_rng(seed)`` (first all sigmas, then all peaks). Features are ordered
   by (mu_x, mu_y), so the scenario depends only on the set of signals, not on the file's row order.
5. **Scenario** (:func:`city_scenario`): those features and N robots launched uniformly.

All input errors raise :class:`madp.errors.InputError` with a single line naming the file and what was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from madp.errors import InputError
from madp.sim import Scenario, SimParams

from .geometry import WORLD_SIDE_M, find_best_square, project_local, unproject_local
from .signal_files import SUPPORTED_SUFFIXES, read_signals, strip_suffixes

__all__ = ["CityScenarioSource", "city_scenario", "import_city", "load_city_dir"]

_MAX_REFRAME_ROUNDS = 8
_REFRAME_TOL_M = 0.01


@dataclass(frozen=True)
class CityScenarioSource:
    """A city's coverage scenario features and where they came from.

    Attributes:
        name: scenario name, the file name without its suffixes (e.g. ``"boston_massachusetts"``).
        source_file: path of the file the signals were read from.
        features: ``[F, 4]`` float64 array of ``(mu_x, mu_y, sigma, peak)``; means in metres in the
            square's frame, each coordinate in ``[0, side_m)``.
        square_origin_latlon: ``(lat, lon)`` of the square's south-west corner (frame origin).
        square_center_latlon: ``(lat, lon)`` of the square's centre.
        num_signals_total: distinct signals read from the file (after the tag filter).
        num_signals_in_square: signals inside the chosen square (= F).
        side_m: side of the square in metres.
        seed: seed the sigmas and peaks were drawn with.
    """

    name: str
    source_file: str
    features: np.ndarray
    square_origin_latlon: tuple[float, float]
    square_center_latlon: tuple[float, float]
    num_signals_total: int
    num_signals_in_square: int
    side_m: float = WORLD_SIDE_M
    seed: int | None = None


def load_city_dir(directory: str | Path) -> list[str]:
    """List the importable signal files in ``directory`` (CSV, GeoJSON, JSON, optionally ``.gz``).

    Returns:
        Paths as strings, sorted by file name. Other files (README, SOURCES, ...) are skipped.

    Raises:
        ValueError: if ``directory`` is not a directory.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{directory}: not a directory (expected a folder of city signal files)")
    files = [
        p
        for p in directory.iterdir()
        if p.is_file() and strip_suffixes(p)[1] in SUPPORTED_SUFFIXES
    ]
    return [str(p) for p in sorted(files, key=lambda p: p.name)]


def _check_range(path: Path, label: str, rng: tuple[float, float], positive: bool) -> tuple[float, float]:
    """Validate a ``(low, high)`` sampling range (finite, ordered, optionally positive)."""
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {label} must be a (low, high) pair of numbers, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi) or (positive and lo <= 0):
        raise InputError(f"{path}: {label} must satisfy {'0 < ' if positive else ''}low <= high, got {rng!r}")
    return lo, hi


def import_city(
    path: str | Path,
    seed: int,
    sigma_range: tuple[float, float] = (40.0, 60.0),
    peak_range: tuple[float, float] = (0.6, 1.0),
    *,
    side_m: float = WORLD_SIDE_M,
) -> CityScenarioSource:
    """Build a city scenario's features from a file of traffic-signal locations.

    Reads the signals (:func:`read_signals`), chooses the ``side_m`` square holding the most signals
    (:func:`find_best_square`, re-projected about the square's centre until it is centred within
    1 cm), and places one feature at every signal inside it (see the module docstring).

    Args:
        path: a ``.csv`` / ``.geojson`` / ``.json`` (optionally ``.gz``) file of signals.
        seed: seed of ``numpy.random.default_rng`` for the sigmas and peaks.
        sigma_range: feature sigma ~ U(low, high), metres.
        peak_range: feature peak ~ U(low, high).
        side_m: side of the square (the world), metres.

    Returns:
        A :class:`CityScenarioSource`.

    Raises:
        ValueError: one line naming the file (see :func:`read_signals`), or invalid ranges.
    """
    path = Path(path)
    sig_lo, sig_hi = _check_range(path, "sigma_range", sigma_range, positive=True)
    pk_lo, pk_hi = _check_range(path, "peak_range", peak_range, positive=True)
    if not (isinstance(side_m, (int, float)) and math.isfinite(side_m) and side_m > 0):
        raise InputError(f"{path}: side_m must be a positive number, got {side_m!r}")
    side = float(side_m)
    latlon = read_signals(path)
    lat, lon = latlon[:, 0], latlon[:, 1]

    # Initial reference: median latitude, circular mean longitude (robust at the antimeridian).
    lam = np.radians(lon)
    lon0 = math.degrees(math.atan2(np.sin(lam).mean(), np.cos(lam).mean()))
    lat0 = float(np.median(lat))
    # Tie-break target: the signals' centroid, fixed geographically across re-projections.
    xy = project_local(lat, lon, lat0, lon0)
    cen_lat, cen_lon = unproject_local(*xy.mean(axis=0), lat0, lon0)

    for _ in range(_MAX_REFRAME_ROUNDS):
        xy = project_local(lat, lon, lat0, lon0)
        tie = project_local(cen_lat, cen_lon, lat0, lon0)
        x0, y0, count = find_best_square(xy, side, tie_point=tie)
        cx, cy = x0 + 0.5 * side, y0 + 0.5 * side
        if math.hypot(cx, cy) <= _REFRAME_TOL_M:
            break
        new_lat, new_lon = unproject_local(cx, cy, lat0, lon0)
        lat0, lon0 = float(new_lat), float(new_lon)

    # Same comparisons as the search (so the count agrees exactly); the subtraction is clamped at
    # the ulp level so that every mean lies in [0, side).
    x, y = xy[:, 0], xy[:, 1]
    inside = (x >= x0) & (x < x0 + side) & (y >= y0) & (y < y0 + side)
    means = np.clip(xy[inside] - np.array([x0, y0]), 0.0, np.nextafter(side, 0.0))
    means = means[np.lexsort((means[:, 1], means[:, 0]))]
    f = means.shape[0]
    if f != count:  # internal invariant: the search and the membership test use the same frame
        raise RuntimeError(f"{path}: square membership ({f}) disagrees with the search count ({count})")

    rng = np.random.default_rng(seed)
    sigma = rng.uniform(sig_lo, sig_hi, size=f)
    peak = rng.uniform(pk_lo, pk_hi, size=f)
    features = np.column_stack([means, sigma, peak]).astype(np.float64)

    o_lat, o_lon = unproject_local(x0, y0, lat0, lon0)
    c_lat, c_lon = unproject_local(x0 + 0.5 * side, y0 + 0.5 * side, lat0, lon0)
    return CityScenarioSource(
        name=strip_suffixes(path)[0],
        source_file=str(path),
        features=features,
        square_origin_latlon=(float(o_lat), float(o_lon)),
        square_center_latlon=(float(c_lat), float(c_lon)),
        num_signals_total=int(latlon.shape[0]),
        num_signals_in_square=int(f),
        side_m=side,
        seed=seed,
    )


def city_scenario(path: str | Path, seed: int, params: SimParams) -> tuple[Scenario, CityScenarioSource]:
    """The coverage scenario of a city file: the features of :func:`import_city` (σ and peak ranges
    from ``params``) and ``params.num_robots`` robots launched uniformly over the world (drawn from
    ``default_rng([seed, 1])``); ``params.num_features`` becomes the number of signals in the square.
    Returns the scenario and where its features came from."""
    src = import_city(path, seed=seed, sigma_range=params.sigma_range_m, peak_range=params.peak_range)
    params = replace(params, num_features=len(src.features))
    robots = np.random.default_rng([seed, 1]).uniform(1e-4, params.world_size - 1e-4, (params.num_robots, 2))
    return Scenario(src.features, robots, params, name=src.name, seed=seed,
                    source=f"{Path(path).name}: {src.num_signals_in_square} of {src.num_signals_total} signals, "
                           f"square SW corner {src.square_origin_latlon}, centre {src.square_center_latlon}"), src
