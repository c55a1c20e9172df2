"""``madp bench datagen`` and ``madp bench io``.

datagen: one real run of the datagen pipeline at N = F = 32 (all workers), timed end to end, plus
per-stage medians measured in the same process (expert step, observations, float16 conversion).
The baseline is the Coverage Control Library's cost model on this machine (21 ms per clairvoyant
step, 28 ms per observation tensor; one sample = 5 steps + 1 observation), which puts 100k samples
at about 3.7 hours.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario

from .plan import DatagenConfig, ShardTask
from .episodes import shard_episodes
from .runner import run_datagen

LIB_STEP_MS, LIB_OBS_MS = 21.0, 28.0


def stage_medians(steps: int = 200, seed: int = 7) -> dict:
    env = CoverageEnv(Scenario.random(seed))
    expert = ClairvoyantCVT()
    step_ms, obs_ms, f16_ms = [], [], []
    for _ in range(steps):
        t0 = time.perf_counter()
        u = expert(env)
        env.step(u)
        t1 = time.perf_counter()
        o = env.observations()
        t2 = time.perf_counter()
        o.astype(np.float16)
        t3 = time.perf_counter()
        step_ms.append(t1 - t0)
        obs_ms.append(t2 - t1)
        f16_ms.append(t3 - t2)
    med = lambda v: float(np.median(v) * 1e3)  # noqa: E731
    return {"expert_step_ms": med(step_ms), "observations_ms": med(obs_ms), "float16_ms": med(f16_ms)}


def bench_datagen(num_samples: int = 1024, workers: int = 0, fmt: str = "mcap", seed: int = 0) -> dict:
    stages = stage_medians()
    with tempfile.TemporaryDirectory() as d:
        cfg = DatagenConfig(num_samples, seed=seed, format=fmt, samples_per_shard=128)
        t0 = time.perf_counter()
        m = run_datagen(cfg, Path(d), workers=workers, progress=False)
        wall = time.perf_counter() - t0
        size = sum(s.bytes for sp in m.splits.values() for s in sp.shards)
    rate = num_samples / wall
    lib_sample_ms = 5 * LIB_STEP_MS + LIB_OBS_MS
    our_sample_ms = 5 * stages["expert_step_ms"] + stages["observations_ms"] + stages["float16_ms"]
    return {
        "num_samples": num_samples,
        "format": fmt,
        "wall_s": wall,
        "samples_per_s": rate,
        "projected_100k_min": 100_000 / rate / 60,
        "bytes_per_sample": size / num_samples,
        "stages": stages,
        "per_sample_ms_one_core": our_sample_ms,
        "library_per_sample_ms_one_core": lib_sample_ms,
        "library_projected_100k_h": 100_000 * lib_sample_ms / 1e3 / 3600,
        "stage_speedup_vs_library": lib_sample_ms / our_sample_ms,
    }


def real_episodes(num_samples: int = 512, seed: int = 0) -> list:
    """Real expert episodes (N = F = 32) holding ``num_samples`` samples, for the I/O benchmark."""
    cfg = DatagenConfig(num_samples, seed=seed)
    return list(shard_episodes(cfg, ShardTask("train", 0, num_samples)))


def _noop(item):
    return item


def _timed_worker(args) -> tuple[dict, float]:
    """The datagen worker function, and the seconds it took where it ran."""
    from .runner import _worker

    t = time.perf_counter()
    return _worker(args), time.perf_counter() - t


def bench_ray_overhead(address: str | None = None, shard_samples: int = 128, repeats: int = 5, trivial: int = 20,
                       fmt: str = "mcap", seed: int = 0) -> dict:
    """Per-task overhead of the Ray backend (:mod:`madp.io.ray_backend`), measured in this run.

    * the round trip of a trivial task through the backend (submit, wait, get), median of ``trivial``;
    * one shard task of ``shard_samples`` samples (the datagen worker function, the same shard each
      time) run in this process and as a Ray task, alternately, ``repeats`` times each: the medians,
      their difference (the overhead per shard task) and their ratio, and the median dispatch cost
      (a Ray task's round trip less the time the function took inside the worker).

    Workers are warmed up first (one tiny shard task each), so imports are not counted; the time to
    start or join Ray is reported on its own (a fixed cost per run)."""
    from madp.io.ray_backend import import_ray, ray_imap_unordered, ray_session

    from .runner import _worker

    import_ray()
    t0 = time.perf_counter()
    with ray_session(address) as ray, tempfile.TemporaryDirectory() as d:
        start_s = time.perf_counter() - t0
        cpus = int(ray.cluster_resources().get("CPU", 0))
        cfg = DatagenConfig(shard_samples, seed=seed, format=fmt, samples_per_shard=shard_samples).to_dict()
        tiny = (DatagenConfig(8, seed=seed, format=fmt).to_dict(), ShardTask("train", 0, 8), str(Path(d) / "warm"))
        list(ray_imap_unordered(_timed_worker, [tiny] * max(cpus, 1), address))
        _worker(tiny)
        list(ray_imap_unordered(_noop, [0], address))
        trips = []
        for i in range(trivial):
            t = time.perf_counter()
            list(ray_imap_unordered(_noop, [i], address))
            trips.append(time.perf_counter() - t)
        task = ShardTask("train", 0, shard_samples)
        local, remote, dispatch = [], [], []
        for _ in range(repeats):
            t = time.perf_counter()
            a = _worker((cfg, task, str(Path(d) / "local")))
            local.append(time.perf_counter() - t)
            t = time.perf_counter()
            ((b, inside),) = ray_imap_unordered(_timed_worker, [(cfg, task, str(Path(d) / "ray"))], address)
            remote.append(time.perf_counter() - t)
            dispatch.append(remote[-1] - inside)
            if a != b:  # a bug, not a measurement
                raise RuntimeError("a shard task made other bytes on Ray than in this process")
    local_s, ray_s = float(np.median(local)), float(np.median(remote))
    return {"address": address or "local", "cpus": cpus, "start_s": start_s,
            "trivial_task_ms": float(np.median(trips) * 1e3), "trivial_tasks": trivial,
            "shard_samples": shard_samples, "repeats": repeats, "shard_local_s": local_s, "shard_ray_s": ray_s,
            "shard_overhead_s": ray_s - local_s, "shard_ratio": ray_s / local_s,
            "shard_dispatch_ms": float(np.median(dispatch) * 1e3)}


def bench_datagen_and_ray(num_samples: int = 1024, workers: int = 0, fmt: str = "mcap", address: str | None = None) -> dict:
    """What ``madp bench datagen`` measures: :func:`bench_datagen`, and under ``"ray"`` the Ray backend's
    overhead (:func:`bench_ray_overhead`) or None when Ray is not installed and no ``address`` was given."""
    from madp.io.ray_backend import RayUnavailable

    r = bench_datagen(num_samples, workers, fmt)
    try:
        r["ray"] = bench_ray_overhead(address, fmt=fmt)
    except RayUnavailable:
        if address is not None:
            raise
        r["ray"] = None
    return r


def format_table(r: dict, num_samples: int, fmt: str) -> list[str]:
    """The lines ``madp bench datagen`` prints for a :func:`bench_datagen_and_ray` result."""
    s = r["stages"]
    lines = [f"stage medians (one core): expert step {s['expert_step_ms']:.2f} ms, observations "
             f"{s['observations_ms']:.2f} ms, float16 {s['float16_ms']:.2f} ms -> {r['per_sample_ms_one_core']:.1f} ms/sample "
             f"(library: {r['library_per_sample_ms_one_core']:.0f} ms/sample, {r['stage_speedup_vs_library']:.1f}x)",
             f"datagen {num_samples} samples ({fmt}): {r['wall_s']:.1f} s wall, {r['samples_per_s']:.1f} samples/s, "
             f"{r['bytes_per_sample'] / 1e3:.1f} kB/sample",
             f"projected 100k samples: {r['projected_100k_min']:.1f} min "
             f"(library cost model: {r['library_projected_100k_h']:.1f} h)"]
    x = r["ray"]
    if x is None:
        return lines + ['Ray backend: not measured (Ray is not installed; pip install "madp[ray]")']
    return lines + [
        f"Ray backend ({x['address']}, {x['cpus']} CPUs): start {x['start_s']:.1f} s once per run; trivial task "
        f"round trip {x['trivial_task_ms']:.1f} ms (median of {x['trivial_tasks']})",
        f"Ray shard task ({x['shard_samples']} samples): {x['shard_ray_s']:.2f} s on Ray vs {x['shard_local_s']:.2f} s "
        f"in this process (medians of {x['repeats']}): {x['shard_ratio']:.3f}x ({1e3 * x['shard_overhead_s']:+.0f} ms); "
        f"dispatch (round trip less the task's own time) {x['shard_dispatch_ms']:.1f} ms per task"]
