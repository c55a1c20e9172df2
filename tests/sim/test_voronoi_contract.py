"""ColumnPrefix reads its map as float64, whatever the map's array type.

Written against the campaign on the numba simulator (2026-12-02): the mutants mutmut left alive in
``madp/sim/voronoi.py``; each test names the mutants it kills.
"""

import numpy as np
import pytest

from madp.sim.voronoi import ColumnPrefix


def _table(m: np.ndarray) -> np.ndarray:
    """Prefix sums along y of (Φ, Φ·y, Φ·y²), y the row centre, by plain Python float64 loops."""
    w, h = m.shape
    t = np.zeros((w, h + 1, 4))
    for c in range(w):
        acc = [0.0, 0.0, 0.0]
        for r in range(h):
            v, y = float(m[c, r]), r + 0.5
            acc = [acc[0] + v, acc[1] + v * y, acc[2] + v * (y * y)]
            t[c, r + 1, :3] = acc
    return t


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int32, np.longdouble])
def test_column_prefix_reads_the_map_as_float64(dtype):
    """__init___3 / _5 (the map not cast to float64: an extended-precision ``longdouble`` map's
    products Φ·y and Φ·y² would be taken before rounding to float64). The table holds the prefix
    sums of the map's float64 values, bit for bit those of the map cast to float64 first (and, for
    these small maps, of plain sequential sums); float32 and integer maps give them too."""
    rng = np.random.default_rng(2)
    m = (rng.random((6, 40)) * 50).astype(dtype)
    if dtype == np.longdouble:
        m = m / np.longdouble(3)  # values a float64 cannot hold (where longdouble is wider)
    want = ColumnPrefix(m.astype(np.float64)).table
    got = ColumnPrefix(m).table
    assert got.dtype == np.float64 and np.array_equal(got, want)
    assert np.array_equal(want, _table(m.astype(np.float64)))
