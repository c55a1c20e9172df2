"""Synthetic, realistically compressible samples and a read-throughput benchmark of the encodings.

:func:`synthetic_episodes` makes data shaped like the real thing (so compression ratios are
meaningful): channel 0 (local importance map) a smooth sum of Gaussian blobs, zero where the robot
has not sensed; channels 1–2 (neighbour x/y) a few non-zero pixels; channel 3 (boundary) zero
except where the 256 m window leaves the 1024 m world. :func:`bench_io` writes the same samples as
MCAP, Parquet and a plain float16 ``.npy`` memmap of the observations, then times full decoding
into numpy (median of several passes, warm page cache).
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path
from typing import Optional, Union

import numpy as np

from .schema import OBS_SIZE, Episode
from .shard_io import iter_shard, write_shard

PathLike = Union[str, os.PathLike]

WORLD_M = 1024.0
LOCAL_WINDOW_M = 256.0
COMM_RADIUS_M = 256.0
U_MAX = 5.0
DT = 0.2


def synthetic_world_map(size: int, rng: np.random.Generator, num_features: int = 32) -> np.ndarray:
    """A ``[size, size]`` float32 importance map indexed ``[x, y]``: Gaussian features, max 1."""
    c = np.arange(size) + 0.5
    mu = rng.uniform(0, size, (num_features, 2))
    sigma = rng.uniform(40, 60, num_features) * size / WORLD_M
    gx = np.exp(-((c[None, :] - mu[:, :1]) ** 2) / (2 * sigma[:, None] ** 2))  # [F, size]
    gy = np.exp(-((c[None, :] - mu[:, 1:]) ** 2) / (2 * sigma[:, None] ** 2))
    peak = rng.uniform(0.6, 1.0, num_features)
    m = np.einsum("f,fx,fy->xy", peak, gx, gy)
    return (m / m.max()).astype(np.float32)


def synthetic_observations(positions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Observations ``[T, N, 4, 32, 32]`` float16 for ``positions [T, N, 2]`` (m), vectorised."""
    t, n, _ = positions.shape
    pix = LOCAL_WINDOW_M / OBS_SIZE  # 8 m per pixel
    idx = np.arange(OBS_SIZE)
    obs = np.zeros((t, n, 4, OBS_SIZE, OBS_SIZE), dtype=np.float32)

    # channel 0: smooth blobs, zero outside a sensed disc around the robot
    k = 3
    centres = rng.uniform(0, OBS_SIZE, (t, n, k, 2))
    widths = rng.uniform(3.0, 7.0, (t, n, k))
    gx = np.exp(-((idx - centres[..., 0:1]) ** 2) / (2 * widths[..., None] ** 2))  # [t, n, k, 32]
    gy = np.exp(-((idx - centres[..., 1:2]) ** 2) / (2 * widths[..., None] ** 2))
    blob = np.einsum("tnkx,tnky->tnxy", gx, gy) * rng.uniform(0.3, 1.0, (t, n, 1, 1))
    r2 = (idx[:, None] - 15.5) ** 2 + (idx[None, :] - 15.5) ** 2
    sensed = r2[None, None] <= rng.uniform(6, 16, (t, n, 1, 1)) ** 2
    obs[:, :, 0] = np.where(sensed, np.minimum(blob, 1.0), 0.0)

    # channels 1-2: neighbours' relative positions within the comm radius, one pixel each
    rel = positions[:, None, :, :] - positions[:, :, None, :]  # [t, i, j, 2]
    dist = np.linalg.norm(rel, axis=-1)
    near = (dist < COMM_RADIUS_M) & (dist > 0)
    ti, ii, jj = np.nonzero(near)
    r = rel[ti, ii, jj]
    px = np.clip(np.round(r * OBS_SIZE / (2 * COMM_RADIUS_M) + 15.5).astype(int), 0, OBS_SIZE - 1)
    np.add.at(obs, (ti, ii, 1, px[:, 0], px[:, 1]), r[:, 0] / COMM_RADIUS_M)
    np.add.at(obs, (ti, ii, 2, px[:, 0], px[:, 1]), r[:, 1] / COMM_RADIUS_M)

    # channel 3: 1 where the local window is outside the world
    lo = positions - LOCAL_WINDOW_M / 2  # [t, n, 2] window corner
    cell = lo[..., None] + (idx + 0.5) * pix  # [t, n, 2, 32] pixel centres per axis
    outside = (cell < 0) | (cell > WORLD_M)
    obs[:, :, 3] = (outside[:, :, 0, :, None] | outside[:, :, 1, None, :]).astype(np.float32)
    return obs.astype(np.float16)


def synthetic_episodes(
    num_samples: int,
    num_robots: int = 32,
    steps_per_episode: int = 64,
    seed: int = 0,
    world_size: Optional[int] = None,
    record_every: int = 5,
) -> list[Episode]:
    """Episodes totalling ``num_samples`` samples of random-walk robots with realistic observations.

    ``world_size`` (cells) adds a synthetic ``world_map`` and ``goals`` to each episode for the
    visualisation topics; ``None`` leaves them out.
    """
    rng = np.random.default_rng(seed)
    episodes = []
    eid = 0
    remaining = num_samples
    while remaining > 0:
        t = min(steps_per_episode, remaining)
        start = rng.uniform(0, WORLD_M, (1, num_robots, 2))
        vel = rng.uniform(-U_MAX, U_MAX, (t, num_robots, 2))
        positions = np.clip(start + np.cumsum(vel * DT * record_every, axis=0), 1e-4, WORLD_M - 1e-4)
        extras = {}
        if world_size is not None:
            extras["world_map"] = synthetic_world_map(world_size, rng)
            extras["goals"] = np.clip(positions + rng.normal(0, 20, positions.shape), 0, WORLD_M).astype(np.float32)
        episodes.append(
            Episode(
                episode_id=eid,
                scenario_seed=1_000_000 + 7 * eid,
                actions=vel.astype(np.float32),
                positions=positions.astype(np.float32),
                observations=synthetic_observations(positions, rng),
                steps=np.arange(t, dtype=np.int64) * record_every,
                **extras,
            )
        )
        eid += 1
        remaining -= t
    return episodes


def _time_reads(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_io(
    tmpdir: PathLike,
    num_samples: int = 512,
    num_robots: int = 32,
    repeats: int = 3,
    batch_size: int = 256,
    seed: int = 0,
    episodes: Optional[list[Episode]] = None,
) -> dict:
    """Write ``num_samples`` synthetic samples as MCAP, Parquet and a float16 ``.npy`` memmap of
    the observations, then measure full read-and-decode throughput of each.

    Returns a dict: ``{"num_samples", "num_robots", "batch_size", "repeats",
    "mcap"|"parquet"|"npy_memmap": {"bytes", "bytes_per_sample", "write_s",
    "read_samples_per_s", "read_mb_per_s"}}`` (the two codecs also report
    ``read_samples_per_s_no_crc``, reading with CRC verification off). Read rates are medians over ``repeats`` passes with a
    warm page cache; ``read_mb_per_s`` counts decoded observation bytes. The memmap only holds
    observations, the largest part of a sample, as a raw-I/O ceiling for comparison.
    ``episodes`` replaces the synthetic data (e.g. real expert rollouts); then ``num_samples`` and
    ``num_robots`` are taken from them.
    """
    tmp = Path(tmpdir)
    tmp.mkdir(parents=True, exist_ok=True)
    if episodes is None:
        episodes = synthetic_episodes(num_samples, num_robots, seed=seed, world_size=1024)
    else:
        num_samples = sum(ep.num_steps for ep in episodes)
        num_robots = episodes[0].num_robots
    obs_bytes_per_sample = num_robots * 4 * OBS_SIZE * OBS_SIZE * 2
    result: dict = {"num_samples": num_samples, "num_robots": num_robots, "batch_size": batch_size, "repeats": repeats}

    def report(path: Path, write_s: float, read_s: float) -> dict:
        size = path.stat().st_size
        return {
            "bytes": size,
            "bytes_per_sample": size / num_samples,
            "write_s": write_s,
            "read_samples_per_s": num_samples / read_s,
            "read_mb_per_s": num_samples * obs_bytes_per_sample / read_s / 1e6,
        }

    for fmt in ("mcap", "parquet"):
        path = tmp / f"bench.{fmt}"
        t0 = time.perf_counter()
        write_shard(path, episodes)
        write_s = time.perf_counter() - t0

        def read_all(path=path, verify_crc=True) -> None:
            total = 0
            for batch in iter_shard(path, batch_size=batch_size, verify_crc=verify_crc):
                total += len(batch)
            assert total == num_samples

        result[fmt] = report(path, write_s, _time_reads(read_all, repeats))
        no_crc_s = _time_reads(lambda: read_all(verify_crc=False), repeats)
        result[fmt]["read_samples_per_s_no_crc"] = num_samples / no_crc_s

    npy = tmp / "bench_observations.npy"
    t0 = time.perf_counter()
    mm = np.lib.format.open_memmap(npy, mode="w+", dtype=np.float16, shape=(num_samples, num_robots, 4, OBS_SIZE, OBS_SIZE))
    row = 0
    for ep in episodes:
        mm[row : row + ep.num_steps] = ep.observations
        row += ep.num_steps
    mm.flush()
    del mm
    write_s = time.perf_counter() - t0

    def read_npy() -> None:
        m = np.load(npy, mmap_mode="r")
        for s in range(0, num_samples, batch_size):
            np.array(m[s : s + batch_size])  # copy into memory, like a decoded batch
        del m

    result["npy_memmap"] = report(npy, write_s, _time_reads(read_npy, repeats))
    return result


__all__ = ["bench_io", "synthetic_episodes", "synthetic_observations", "synthetic_world_map"]


def format_table(r: dict, repeats: int) -> list[str]:
    """The lines ``madp bench io`` prints for a :func:`bench_io` result (``repeats`` reads per format)."""
    base = r["npy_memmap"]["read_samples_per_s"]
    lines = [f"{r['num_samples']} real samples, N = {r['num_robots']}, median of {repeats} warm reads",
             f"{'format':<12}{'kB/sample':>10}{'read samples/s':>16}{'vs memmap':>11}{'no-CRC samples/s':>18}"]
    for fmt in ("mcap", "parquet", "npy_memmap"):
        x = r[fmt]
        nocrc = f"{x['read_samples_per_s_no_crc']:>18.0f}" if "read_samples_per_s_no_crc" in x else f"{'-':>18}"
        lines.append(f"{fmt:<12}{x['bytes_per_sample'] / 1e3:>10.1f}{x['read_samples_per_s']:>16.0f}"
                     f"{x['read_samples_per_s'] / base:>10.2f}x{nocrc}")
    return lines
