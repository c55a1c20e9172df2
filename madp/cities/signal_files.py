"""The city importer's file readers: traffic-signal locations (WGS84 degrees) from one of three formats:

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

Every input error raises :class:`madp.errors.InputError` with a single line naming the file and what was expected.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
from pathlib import Path

import numpy as np

from madp.errors import InputError

__all__ = ["SUPPORTED_SUFFIXES", "read_signals", "read_signals_csv", "read_signals_geojson", "read_signals_overpass",
           "strip_suffixes"]

#: File suffixes the importer reads (each optionally followed by ``.gz``).
SUPPORTED_SUFFIXES = (".csv", ".geojson", ".json")

_LAT_NAMES = ("lat", "latitude")
_LON_NAMES = ("lon", "lng", "long", "longitude")
_SIGNAL_TAG = "traffic_signals"


def strip_suffixes(path: Path) -> tuple[str, str, bool]:
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
        raise InputError(f"{path}: file not found (expected a .csv, .geojson or .json file of signals)")
    if not path.is_file():
        raise InputError(f"{path}: not a regular file (expected a .csv, .geojson or .json file of signals)")
    try:
        raw = path.read_bytes()
        if path.name.lower().endswith(".gz"):
            raw = gzip.decompress(raw)
        return raw.decode("utf-8-sig")
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise InputError(f"{path}: cannot read the file ({exc.__class__.__name__}: {exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text (expected a .csv, .geojson or .json file of signals)") from None


def _as_float(value, path: Path, where: str) -> float:
    """Parse a coordinate value (number or numeric string) or raise a one-line ValueError."""
    if isinstance(value, bool) or value is None:
        raise InputError(f"{path}: {where}: expected a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond float range: out of range below, like inf
        return math.inf
    except (TypeError, ValueError):
        raise InputError(f"{path}: {where}: expected a number, got {str(value)[:40]!r}") from None


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
        raise InputError(f"{path}: malformed CSV ({e})") from None


def _parse_csv(path: Path, rows) -> np.ndarray:
    header = None
    for header in rows:
        if any(cell.strip() for cell in header):
            break
    else:
        raise InputError(f"{path}: empty CSV (expected a header 'lat,lon' and one signal per row)")
    names = [cell.strip().lower() for cell in header]
    lat_col = next((names.index(c) for c in _LAT_NAMES if c in names), None)
    lon_col = next((names.index(c) for c in _LON_NAMES if c in names), None)
    if lat_col is None or lon_col is None:
        raise InputError(
            f"{path}: CSV header {','.join(names)!r} has no lat/lon columns (expected a header like 'lat,lon')"
        )
    out = []
    need = max(lat_col, lon_col) + 1
    for row in rows:
        if not any(cell.strip() for cell in row):
            continue
        line = rows.line_num
        if len(row) < need:
            raise InputError(f"{path}: line {line}: expected {need} columns, got {len(row)}")
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
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


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
            raise InputError(f"{path}: {where}: expected a position [lon, lat], got {coords!r}")
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
                raise InputError(f"{path}: {where}: expected a list of positions, got {coords!r}")
            for k, c in enumerate(coords):
                points.append(position(c, f"{where} point {k}"))
                tags.append(_highway_tag(props))
        elif kind == "GeometryCollection":
            for k, g in enumerate(geom.get("geometries") or []):
                visit(g, props, f"{where} geometry {k}")

    if not isinstance(doc, dict) or not isinstance(doc.get("type"), str):
        raise InputError(f"{path}: expected a GeoJSON object with a 'type' (e.g. a FeatureCollection of Points)")
    kind = doc["type"]
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise InputError(f"{path}: expected a 'features' list in the GeoJSON FeatureCollection")
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
        raise InputError(f"{path}: expected an Overpass JSON object with an 'elements' list")
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
    _, suffix, _ = strip_suffixes(path)
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(
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
            raise InputError(
                f"{path}: unrecognised JSON (expected a GeoJSON FeatureCollection of Points "
                "or an Overpass JSON with an 'elements' list)"
            )
    if latlon.shape[0] == 0:
        raise InputError(f"{path}: no traffic signals found (expected at least one point with lat/lon)")
    bad = ~np.isfinite(latlon).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(
            f"{path}: {int(bad.sum())} non-finite coordinate(s), first (lat, lon) = "
            f"({latlon[k, 0]}, {latlon[k, 1]}) (expected finite WGS84 degrees)"
        )
    bad = (np.abs(latlon[:, 0]) > 90.0) | (np.abs(latlon[:, 1]) > 180.0)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(
            f"{path}: {int(bad.sum())} coordinate(s) out of range, first (lat, lon) = "
            f"({latlon[k, 0]}, {latlon[k, 1]}) (expected |lat| <= 90 and |lon| <= 180 degrees)"
        )
    return np.unique(latlon, axis=0)
