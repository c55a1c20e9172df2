"""The geometry of the city importer: WGS84 degrees to local metres and back, and the exact search
for the square holding the most points.

**Projection**: to local metres (east x, north y) with a local equirectangular projection on the WGS84
ellipsoid about a reference point (lat0, lon0)::

    x = N(lat0) cos(lat0) (lon - lon0),      y = M(lat0) (lat - lat0)      (angles in radians)

with N and M the prime-vertical and meridional radii of curvature at lat0. Offsets within a
1024 m square about the reference agree with the WGS84 geodesic to about 0.046 m * tan|lat0|
(2-5 cm for U.S. cities, under 10 cm up to 60°; the tests check against Vincenty's formula), and
the map is globally one-to-one with an exact inverse. A spherical model with radius
6378137 m would be off by up to 0.7 % (7 m over the square) in the north-south direction, which
is why the ellipsoid's radii are used. The projection degenerates near the poles (|lat| > ~85°).

**The square**: the axis-aligned ``side x side`` square (half-open ``[x0, x0 + side) x
[y0, y0 + side)``) holding the most signals, found exactly by :func:`find_best_square`. Ties are
broken by the square whose centre is nearest the centroid of all signals, then the lowest x0, then
the lowest y0. (``cities/SOURCES.md`` lists the same best counts, computed on a sphere, for 39 of
the 40 cities; Milpitas holds 15 signals on the ellipsoid where the sphere's 0.3 % longer
north-south distances give 14.) :func:`madp.cities.importer.import_city` repeats the search in a frame
re-projected about the chosen square's centre until that centre sits within 1 cm of the frame's
reference point (normally 2-3 rounds), so the square and the features are expressed in a projection
accurate about the square itself.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["WGS84_A", "WGS84_F", "WORLD_SIDE_M", "find_best_square", "project_local", "unproject_local"]

#: Side of the coverage world in metres (the paper's world).
WORLD_SIDE_M = 1024.0
#: WGS84 semi-major axis (m) and flattening.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
# Upper bound on the number of int32 cells one block of the square search materialises.
_SEARCH_BLOCK_CELLS = 1 << 22


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
