"""``madp bench sim``: medians of the simulator's hot paths at N = F = 32 on a 1024² world.

Each figure is the median over ``steps`` consecutive steps of one rollout. The baseline measured in
the same run is the brute-force nearest-robot pass (:mod:`madp.sim.bruteforce`) for J; the Coverage
Control Library's own figures on this machine (from the issue) are printed beside ours for reference.
"""

from __future__ import annotations

import time

import numpy as np

from .bruteforce import brute_force_sums
from .controllers import ClairvoyantCVT, DecentralizedCVT
from .env import CoverageEnv
from .scenario import Scenario

LIBRARY_MS = {"clairvoyant_step": 21.0, "dcvt_step": 31.0, "cost_J": 18.0, "observations": 28.0}
TARGET_MS = {"clairvoyant_step": 4.0, "dcvt_step": 6.0, "cost_J": 3.5, "observations": 5.0}


def _timed(fn, repeats: int) -> np.ndarray:
    out = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out * 1e3


def bench_sim(steps: int = 200, seed: int = 12345, progress=None) -> dict:
    """Return {name: {"median_ms", "p90_ms", "library_ms", "speedup_vs_library", ...}}."""
    env = CoverageEnv(Scenario.random(seed))
    expert, dcvt = ClairvoyantCVT(), DecentralizedCVT()
    results: dict[str, np.ndarray] = {}

    env.reset()
    results["clairvoyant_step"] = _timed(lambda: env.step(expert(env)), steps)
    # J and observations along the same trajectory the expert produced.
    env.reset()
    j_times, o_times = [], []
    for _ in range(steps):
        j_times.append(_timed(env.cost, 1)[0])
        o_times.append(_timed(env.observations, 1)[0])
        env.step(expert(env))
    results["cost_J"] = np.array(j_times)
    results["observations"] = np.array(o_times)
    env.reset()
    results["dcvt_step"] = _timed(lambda: env.step(dcvt(env)), steps)

    # Baseline in the same process: brute-force J (nearest robot for each of the W² cells).
    env.reset()
    brute = _timed(lambda: brute_force_sums(env.world_map, env.positions_m), 5)

    out = {}
    for name, t in results.items():
        med = float(np.median(t))
        out[name] = {
            "median_ms": med,
            "p90_ms": float(np.percentile(t, 90)),
            "samples": len(t),
            "library_ms": LIBRARY_MS[name],
            "speedup_vs_library": LIBRARY_MS[name] / med,
            "target_ms": TARGET_MS[name],
            "meets_target": med <= TARGET_MS[name],
        }
    out["cost_J"]["brute_force_median_ms"] = float(np.median(brute))
    out["cost_J"]["speedup_vs_brute_force"] = float(np.median(brute)) / out["cost_J"]["median_ms"]
    return out
