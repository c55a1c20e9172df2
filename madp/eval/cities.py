"""City importer: traffic-signal locations -> features of a coverage scenario.

The paper's real-world suite (SPEC §5, ``cities/README.md``) builds one scenario per city: a
1024 m x 1024 m neighbourhood with one Gaussian feature of the importance density function at every
traffic signal inside it. This module turns a file of signal locations into such a scenario:

1. **Read** the signals (WGS84 degrees) from one of three formats:

   * the CSV form of ``shared/cities`` (header with ``lat`` and ``lon`` columns; the aliases
     ``latitude`` / ``lng`` / ``long`` / ``longitude`` are accepted, case-insensitively);
   * a GeoJSON ``FeatureCollection`` (or a single ``Feature`` / geometry) of ``Point`` and
     ``MultiPoint`` geometries, coordinates ``[lon, lat]``; other geometries are ignored;
   * an Overpass API JSON (``{"elements": [{"type": "node", "lat": .., "lon": ..}, ...]}``);
     elements without ``lat``/``lon`` (ways, relations, ``out center`` results) are ignored.

   Any of them may be gzip-compressed (``.gz`` suffix). Exact duplicate coordinates are merged (one
   signal per location). **Tag filter**: if at least one point of a GeoJSON / Overpass file carries a
   ``highway`` tag (Overpass ``tags``, GeoJSON ``properties`` or ``properties.tags``), only the points
   tagged ``highway=traffic_signals`` are kept; a file without any ``highway`` tags (e.g. ``out skel``)
   is taken as a list of signals.

2. **Project** to local metres (east x, north y) with a local equirectangular projection on the WGS84
   ellipsoid about a reference point (lat0, lon0)::

       x = N(lat0) cos(lat0) (lon - lon0),      y = M(lat0) (lat - lat0)      (angles in radians)

   with N and M the prime-vertical and meridional radii of curvature at lat0. Offsets within a
   1024 m square about the reference agree with the WGS84 geodesic to about 0.046 m * tan|lat0|
   (2-5 cm for U.S. cities, under 10 cm up to 60°; the tests check against Vincenty's formula), and
   the map is globally one-to-one with an exact inverse. A spherical model with radius
   6378137 m would be off by up to 0.7 % (7 m over the square) in the north-south direction, which
   is why the ellipsoid's radii are used. The projection degenerates near the poles (|lat| > ~85°).

3. **Choose the square**: the axis-aligned ``side x side`` square (half-open ``[x0, x0 + side) x
   [y0, y0 + side)``) holding the most signals, found exactly by :func:`find_best_square`. Ties are
   broken by the square whose centre is nearest the centroid of all signals, then the lowest x0, then
   the lowest y0. (``cities/SOURCES.md`` lists the same best counts, computed on a sphere, for 39 of
   the 40 cities; Milpitas holds 15 signals on the ellipsoid where the sphere's 0.3 % longer
   north-south distances give 14.) The search is repeated in a frame re-projected about the chosen square's centre
   until that centre sits within 1 cm of the frame's reference point (normally 2-3 rounds), so the
   square and the features are expressed in a projection accurate about the square itself.

4. **Features**: one per signal in the square, ``(mu_x, mu_y, sigma, peak)`` with the mean in the
   square's frame ``[0, side)`` metres, ``sigma ~ U(sigma_range)`` and ``peak ~ U(peak_range)`` drawn
   from ``numpy.random.default_rng(seed)`` (first all sigmas, then all peaks). Features are ordered
   by (mu_x, mu_y), so the scenario depends only on the set of signals, not on the file's row order.

All input errors raise :class:`ValueError` with a single line naming the file and what was expected.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "WORLD_SIDE_M",
    "WGS84_A",
    "WGS84_F",
    "SUPPORTED_SUFFIXES",
    "CityScenarioSource",
    "load_city_dir",
    "import_city",
    "read_signals",
    "read_signals_csv",
    "read_signals_geojson",
    "read_signals_overpass",
    "project_local",
    "unproject_local",
    "find_best_square",
]

#: Side of the coverage world in metres (SPEC §2).
WORLD_SIDE_M = 1024.0
#: WGS84 semi-major axis (m) and flattening.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

#: File suffixes the importer reads (each optionally followed by ``.gz``).
SUPPORTED_SUFFIXES = (".csv", ".geojson", ".json")

_LAT_NAMES = ("lat", "latitude")
_LON_NAMES = ("lon", "lng", "long", "longitude")
_SIGNAL_TAG = "traffic_signals"
# Upper bound on the number of int32 cells one block of the square search materialises.
_SEARCH_BLOCK_CELLS = 1 << 22
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


# --------------------------------------------------------------------------------------------------
# Projection
# --------------------------------------------------------------------------------------------------


def _local_scales(lat0: float) -> tuple[float, float]:
    """Metres per radian of longitude and of latitude at geodetic latitude ``lat0`` (degrees)."""
    phi = math.radians(lat0)
    w2 = 1.0 - _WGS84_E2 * math.sin(phi) ** 2
    n_radius = WGS84_A / math.sqrt(w2)  # prime vertical radius of curvature
    m_radius = WGS84_A * (1.0 - _WGS84_E2) / (w2 * math.sqrt(w2))  # meridional radius
    return n_radius * math.cos(phi), m_radius


def project_local(lat, lon, lat0: float, lon0: float) -> np.ndarray:
    """Project WGS84 ``lat``/``lon`` (degrees) to local metres about ``(lat0, lon0)``.

    Local equirectangular projection on the WGS84 ellipsoid: east ``x`` and north ``y`` in metres,
    ``(0, 0)`` at the reference. Longitude differences are wrapped to [-180, 180) so data across the
    antimeridian stays contiguous.

    Args:
        lat, lon: array-likes of equal shape, degrees.
        lat0, lon0: reference point, degrees.

    Returns:
        float64 array of shape ``lat.shape + (2,)`` holding ``(x, y)``.
    """
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    kx, ky = _local_scales(lat0)
    dlon = np.mod(lon - lon0 + 180.0, 360.0) - 180.0
    return np.stack([kx * np.radians(dlon), ky * np.radians(lat - lat0)], axis=-1)


def unproject_local(x, y, lat0: float, lon0: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`project_local`: local metres about ``(lat0, lon0)`` -> ``(lat, lon)`` degrees.

    Longitudes are wrapped to [-180, 180).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    kx, ky = _local_scales(lat0)
    lat = lat0 + np.degrees(y / ky)
    lon = np.mod(lon0 + np.degrees(x / kx) + 180.0, 360.0) - 180.0
    return lat, lon


# --------------------------------------------------------------------------------------------------
# Square search
# --------------------------------------------------------------------------------------------------


def find_best_square(
    xy: np.ndarray, side: float = WORLD_SIDE_M, tie_point: np.ndarray | None = None
) -> tuple[float, float, int]:
    """Exact axis-aligned ``side x side`` square holding the most points.

    A square is half-open, ``[x0, x0 + side) x [y0, y0 + side)``. Any optimal square can be shifted
    right and up until its left edge touches the leftmost and its bottom edge the lowest point it
    holds without losing a point, so it suffices to try ``x0`` among the points' x and ``y0`` among
    their y. With the points sorted by y, a prefix count over that order of the points inside the
    vertical strip of each candidate ``x0`` answers every ``y0`` by two look-ups, so all ``n^2``
    candidates are counted with vectorised numpy in blocks of strips (O(n^2) time, bounded memory).

    Ties are broken by the distance of the square's centre to ``tie_point`` (default: the centroid of
    the points), then by the lowest ``x0``, then the lowest ``y0``.

    Args:
        xy: ``[n, 2]`` point coordinates, n >= 1.
        side: side of the square (> 0).
        tie_point: ``(x, y)`` used for the tie-break.

    Returns:
        ``(x0, y0, count)``: the chosen square's lower-left corner and the number of points inside.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] == 0:
        raise ValueError(f"find_best_square: expected a non-empty [n, 2] array, got shape {xy.shape}")
    if not side > 0:
        raise ValueError(f"find_best_square: side must be positive, got {side}")
    if tie_point is None:
        tie_point = xy.mean(axis=0)
    tie_point = np.asarray(tie_point, dtype=np.float64)

    order = np.argsort(xy[:, 1], kind="stable")
    ys = xy[order, 1]
    xs_in_y_order = xy[order, 0]
    cand_x = np.unique(xy[:, 0])
    cand_y = np.unique(xy[:, 1])
    # Rank range of the points with cand_y <= y < cand_y + side in the y-sorted order.
    lo = np.searchsorted(ys, cand_y, side="left")
    hi = np.searchsorted(ys, cand_y + side, side="left")

    n = ys.size
    block = max(1, _SEARCH_BLOCK_CELLS // (n + 1))
    best = -1
    winners_i: list[np.ndarray] = []
    winners_j: list[np.ndarray] = []
    for start in range(0, cand_x.size, block):
        x0 = cand_x[start : start + block, None]
        in_strip = (xs_in_y_order >= x0) & (xs_in_y_order < x0 + side)
        prefix = np.zeros((in_strip.shape[0], n + 1), dtype=np.int32)
        np.cumsum(in_strip, axis=1, out=prefix[:, 1:])
        counts = prefix[:, hi] - prefix[:, lo]
        block_best = int(counts.max())
        if block_best < best:
            continue
        if block_best > best:
            best = block_best
            winners_i, winners_j = [], []
        bi, bj = np.nonzero(counts == block_best)
        winners_i.append(bi + start)
        winners_j.append(bj)

    wx = cand_x[np.concatenate(winners_i)]
    wy = cand_y[np.concatenate(winners_j)]
    dist2 = (wx + 0.5 * side - tie_point[0]) ** 2 + (wy + 0.5 * side - tie_point[1]) ** 2
    k = np.lexsort((wy, wx, dist2))[0]
    return float(wx[k]), float(wy[k]), best


# --------------------------------------------------------------------------------------------------
# Readers
# --------------------------------------------------------------------------------------------------


def _strip_suffixes(path: Path) -> tuple[str, str, bool]:
    """Return ``(name, format_suffix, gzipped)`` for ``path`` (e.g. ``a.geojson.gz`` -> a, .geojson)."""
    name = path.name
    gz = name.lower().endswith(".gz")
    if gz:
        name = name[:-3]
    stem, dot, ext = name.rpartition(".")
    if not dot:
        return name, "", gz
    return stem, "." + ext.lower(), gz


def _read_text(path: Path) -> str:
    """Read a (possibly gzipped) UTF-8 text file, mapping I/O errors to one-line ValueErrors."""
    if not path.exists():
        raise ValueError(f"{path}: file not found (expected a .csv, .geojson or .json file of signals)")
    if not path.is_file():
        raise ValueError(f"{path}: not a regular file (expected a .csv, .geojson or .json file of signals)")
    try:
        raw = path.read_bytes()
        if path.name.lower().endswith(".gz"):
            raw = gzip.decompress(raw)
        return raw.decode("utf-8-sig")
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise ValueError(f"{path}: cannot read the file ({exc.__class__.__name__}: {exc})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text (expected a .csv, .geojson or .json file of signals)") from None


def _as_float(value, path: Path, where: str) -> float:
    """Parse a coordinate value (number or numeric string) or raise a one-line ValueError."""
    if isinstance(value, bool) or value is None:
        raise ValueError(f"{path}: {where}: expected a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond float range: out of range below, like inf
        return math.inf
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {where}: expected a number, got {str(value)[:40]!r}") from None


def read_signals_csv(path: str | Path, text: str | None = None) -> np.ndarray:
    """Read signals from a CSV with a header naming ``lat`` and ``lon`` columns.

    Args:
        path: the file (used for reading when ``text`` is None, and in error messages).
        text: the file's content, if already read.

    Returns:
        ``[n, 2]`` float64 array of ``(lat, lon)`` degrees, in file order (not yet validated).
    """
    path = Path(path)
    if text is None:
        text = _read_text(path)
    try:
        return _parse_csv(path, csv.reader(io.StringIO(text, newline="")))
    except csv.Error as e:
        raise ValueError(f"{path}: malformed CSV ({e})") from None


def _parse_csv(path: Path, rows) -> np.ndarray:
    header = None
    for header in rows:
        if any(cell.strip() for cell in header):
            break
    else:
        raise ValueError(f"{path}: empty CSV (expected a header 'lat,lon' and one signal per row)")
    names = [cell.strip().lower() for cell in header]
    lat_col = next((names.index(c) for c in _LAT_NAMES if c in names), None)
    lon_col = next((names.index(c) for c in _LON_NAMES if c in names), None)
    if lat_col is None or lon_col is None:
        raise ValueError(
            f"{path}: CSV header {','.join(names)!r} has no lat/lon columns (expected a header like 'lat,lon')"
        )
    out = []
    need = max(lat_col, lon_col) + 1
    for row in rows:
        if not any(cell.strip() for cell in row):
            continue
        line = rows.line_num
        if len(row) < need:
            raise ValueError(f"{path}: line {line}: expected {need} columns, got {len(row)}")
        out.append(
            (
                _as_float(row[lat_col].strip(), path, f"line {line} lat"),
                _as_float(row[lon_col].strip(), path, f"line {line} lon"),
            )
        )
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _highway_tag(props) -> object:
    """The ``highway`` tag of a GeoJSON properties / Overpass tags dict (flat or nested ``tags``)."""
    if not isinstance(props, dict):
        return None
    if "highway" in props:
        return props["highway"]
    tags = props.get("tags")
    if isinstance(tags, dict):
        return tags.get("highway")
    return None


def _filter_by_tag(points: list[tuple[float, float]], tags: list[object]) -> np.ndarray:
    """Keep ``highway=traffic_signals`` points when any point carries a highway tag; else keep all."""
    if any(t is not None for t in tags):
        points = [p for p, t in zip(points, tags) if t == _SIGNAL_TAG]
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


def _load_json(path: Path, text: str | None):
    """Parse a JSON document (read from ``path`` when ``text`` is None) or raise a one-line ValueError."""
    if text is None:
        text = _read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


def read_signals_geojson(path: str | Path, text: str | None = None) -> np.ndarray:
    """Read signals from GeoJSON Point / MultiPoint geometries (coordinates ``[lon, lat, ...]``).

    Accepts a ``FeatureCollection``, a single ``Feature``, a bare geometry or a
    ``GeometryCollection``; non-point geometries and null geometries are ignored.

    Returns:
        ``[n, 2]`` float64 array of ``(lat, lon)`` degrees (not yet validated).
    """
    path = Path(path)
    return _geojson_points(path, _load_json(path, text))


def _geojson_points(path: Path, doc) -> np.ndarray:
    """Points of a parsed GeoJSON document (see :func:`read_signals_geojson`)."""
    points: list[tuple[float, float]] = []
    tags: list[object] = []

    def position(coords, where: str) -> tuple[float, float]:
        if not isinstance(coords, (list, tuple)) or len(coords) < 2:
            raise ValueError(f"{path}: {where}: expected a position [lon, lat], got {coords!r}")
        return _as_float(coords[1], path, f"{where} lat"), _as_float(coords[0], path, f"{where} lon")

    def visit(geom, props, where: str) -> None:
        if not isinstance(geom, dict):
            return
        kind = geom.get("type")
        if kind == "Point":
            points.append(position(geom.get("coordinates"), where))
            tags.append(_highway_tag(props))
        elif kind == "MultiPoint":
            coords = geom.get("coordinates")
            if not isinstance(coords, list):
                raise ValueError(f"{path}: {where}: expected a list of positions, got {coords!r}")
            for k, c in enumerate(coords):
                points.append(position(c, f"{where} point {k}"))
                tags.append(_highway_tag(props))
        elif kind == "GeometryCollection":
            for k, g in enumerate(geom.get("geometries") or []):
                visit(g, props, f"{where} geometry {k}")

    if not isinstance(doc, dict) or not isinstance(doc.get("type"), str):
        raise ValueError(f"{path}: expected a GeoJSON object with a 'type' (e.g. a FeatureCollection of Points)")
    kind = doc["type"]
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise ValueError(f"{path}: expected a 'features' list in the GeoJSON FeatureCollection")
        for k, feat in enumerate(features):
            if isinstance(feat, dict):
                visit(feat.get("geometry"), feat.get("properties"), f"feature {k}")
    elif kind == "Feature":
        visit(doc.get("geometry"), doc.get("properties"), "feature")
    else:
        visit(doc, None, "geometry")
    return _filter_by_tag(points, tags)


def read_signals_overpass(path: str | Path, text: str | None = None) -> np.ndarray:
    """Read signals from an Overpass API JSON (``{"elements": [...]}``).

    Elements without ``lat``/``lon`` are ignored. When any element carries a ``highway`` tag, only
    elements tagged ``highway=traffic_signals`` are kept.

    Returns:
        ``[n, 2]`` float64 array of ``(lat, lon)`` degrees (not yet validated).
    """
    path = Path(path)
    return _overpass_points(path, _load_json(path, text))


def _overpass_points(path: Path, doc) -> np.ndarray:
    """Points of a parsed Overpass JSON document (see :func:`read_signals_overpass`)."""
    if not isinstance(doc, dict) or not isinstance(doc.get("elements"), list):
        raise ValueError(f"{path}: expected an Overpass JSON object with an 'elements' list")
    points: list[tuple[float, float]] = []
    tags: list[object] = []
    for k, el in enumerate(doc["elements"]):
        if not isinstance(el, dict) or "lat" not in el or "lon" not in el:
            continue
        points.append((_as_float(el["lat"], path, f"element {k} lat"), _as_float(el["lon"], path, f"element {k} lon")))
        tags.append(_highway_tag(el.get("tags")))
    return _filter_by_tag(points, tags)


def read_signals(path: str | Path) -> np.ndarray:
    """Read, validate and deduplicate the signals of a CSV, GeoJSON or Overpass JSON file.

    ``.csv`` files are read as CSV; ``.json`` and ``.geojson`` files are told apart by content (an
    ``elements`` list means Overpass, a GeoJSON ``type`` means GeoJSON). A ``.gz`` suffix is
    decompressed first.

    Returns:
        ``[n, 2]`` float64 array of distinct ``(lat, lon)`` degrees, n >= 1, sorted by (lat, lon).

    Raises:
        ValueError: one line naming the file, for a missing or unreadable file, an unsupported
            format, missing columns, a non-finite or out-of-range coordinate, or no signals.
    """
    path = Path(path)
    _, suffix, _ = _strip_suffixes(path)
    if suffix not in SUPPORTED_SUFFIXES:
        raise ValueError(
            f"{path}: unsupported file type {suffix or '(none)'!r} "
            f"(expected {', '.join(SUPPORTED_SUFFIXES)}, optionally gzipped as .gz)"
        )
    text = _read_text(path)
    if suffix == ".csv":
        latlon = read_signals_csv(path, text)
    else:
        doc = _load_json(path, text)
        if isinstance(doc, dict) and "elements" in doc:
            latlon = _overpass_points(path, doc)
        elif isinstance(doc, dict) and isinstance(doc.get("type"), str):
            latlon = _geojson_points(path, doc)
        else:
            raise ValueError(
                f"{path}: unrecognised JSON (expected a GeoJSON FeatureCollection of Points "
                "or an Overpass JSON with an 'elements' list)"
            )
    if latlon.shape[0] == 0:
        raise ValueError(f"{path}: no traffic signals found (expected at least one point with lat/lon)")
    bad = ~np.isfinite(latlon).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"{path}: {int(bad.sum())} non-finite coordinate(s), first (lat, lon) = "
            f"({latlon[k, 0]}, {latlon[k, 1]}) (expected finite WGS84 degrees)"
        )
    bad = (np.abs(latlon[:, 0]) > 90.0) | (np.abs(latlon[:, 1]) > 180.0)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"{path}: {int(bad.sum())} coordinate(s) out of range, first (lat, lon) = "
            f"({latlon[k, 0]}, {latlon[k, 1]}) (expected |lat| <= 90 and |lon| <= 180 degrees)"
        )
    return np.unique(latlon, axis=0)


# --------------------------------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------------------------------


def load_city_dir(directory: str | Path) -> list[str]:
    """List the importable signal files in ``directory`` (CSV, GeoJSON, JSON, optionally ``.gz``).

    Returns:
        Paths as strings, sorted by file name. Other files (README, SOURCES, ...) are skipped.

    Raises:
        ValueError: if ``directory`` is not a directory.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a directory (expected a folder of city signal files)")
    files = [
        p
        for p in directory.iterdir()
        if p.is_file() and _strip_suffixes(p)[1] in SUPPORTED_SUFFIXES
    ]
    return [str(p) for p in sorted(files, key=lambda p: p.name)]


def _check_range(path: Path, label: str, rng: tuple[float, float], positive: bool) -> tuple[float, float]:
    """Validate a ``(low, high)`` sampling range (finite, ordered, optionally positive)."""
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {label} must be a (low, high) pair of numbers, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi) or (positive and lo <= 0):
        raise ValueError(f"{path}: {label} must satisfy {'0 < ' if positive else ''}low <= high, got {rng!r}")
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
        raise ValueError(f"{path}: side_m must be a positive number, got {side_m!r}")
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
        name=_strip_suffixes(path)[0],
        source_file=str(path),
        features=features,
        square_origin_latlon=(float(o_lat), float(o_lon)),
        square_center_latlon=(float(c_lat), float(c_lon)),
        num_signals_total=int(latlon.shape[0]),
        num_signals_in_square=int(f),
        side_m=side,
        seed=seed,
    )
