"""The I/O benchmark runs and reports what the CLI prints; synthetic data looks like the real thing."""

from __future__ import annotations

import numpy as np
import pytest

from madp.data_schema.bench import bench_io, synthetic_episodes


def test_bench_io_reports_all_formats(tmp_path):
    """Every reported figure is what it claims: sizes are the files' sizes per sample, MB/s counts the
    decoded float16 observations at the measured sample rate, the memmap is the raw array plus its
    .npy header (fails on a size or rate derived from the wrong quantity)."""
    r = bench_io(tmp_path, num_samples=8, num_robots=4, repeats=1, batch_size=4)
    assert (r["num_samples"], r["num_robots"]) == (8, 4)
    files = {"mcap": "bench.mcap", "parquet": "bench.parquet", "npy_memmap": "bench_observations.npy"}
    obs_mb = 4 * 4 * 32 * 32 * 2 / 1e6
    for fmt, name in files.items():
        size = (tmp_path / name).stat().st_size
        assert r[fmt]["bytes"] == size and r[fmt]["bytes_per_sample"] == size / 8
        assert r[fmt]["read_mb_per_s"] == pytest.approx(r[fmt]["read_samples_per_s"] * obs_mb)
        assert r[fmt]["read_samples_per_s"] > 0 and r[fmt]["write_s"] > 0
    assert 0 < r["npy_memmap"]["bytes"] - 8 * 4 * 4 * 32 * 32 * 2 <= 4096  # raw float16 + header
    # compression works on realistic data: both encodings are well below the raw float16 size
    raw = 4 * 4 * 32 * 32 * 2
    assert r["parquet"]["bytes_per_sample"] < 0.5 * raw
    assert r["npy_memmap"]["bytes_per_sample"] >= raw


def test_synthetic_observations_are_realistic():
    (ep,) = synthetic_episodes(4, num_robots=16, steps_per_episode=4, seed=1)
    o = ep.observations.astype(np.float32)
    assert o.dtype == np.float32 and np.isfinite(o).all()
    assert 0 <= o[:, :, 0].min() and o[:, :, 0].max() <= 1  # local importance map
    assert (o[:, :, 1:3] != 0).mean() < 0.05  # neighbour channels are sparse
    assert set(np.unique(o[:, :, 3]).tolist()) <= {0.0, 1.0}  # boundary mask
