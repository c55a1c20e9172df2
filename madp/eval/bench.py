"""``madp bench infer``: MADP's control-step latency, and the fewest DDIM steps that cost nothing.

Latency: one control step for N = 32 (uniform launch) in decentralized and centralized-masked mode,
for the ``paper`` and ``cpu`` presets (random weights: latency does not depend on them), at S = 50
and at S*. S* is the smallest S in the candidates whose mean normalised cost after ``steps`` steps,
over ``envs`` uniform-suite environments, is within 0.01 of S = 50's, measured with a trained
``cpu`` checkpoint (the shipped one by default). The paper reports 0.36 s per step on an RTX 3090.
"""

from __future__ import annotations

import numpy as np

from madp.models.bench import bench_infer
from madp.sim import CoverageEnv

from .policies import MADPPolicy, load, shipped_checkpoint
from .suites import suite_envs

PAPER_LATENCY_S = 0.36


def cost_at(model, num_steps: int, envs: int, steps: int) -> float:
    costs = []
    for spec in suite_envs("uniform", envs):
        env = CoverageEnv(spec.scenario())
        policy = MADPPolicy(model, "decentralized", num_steps, 0.0, seed=spec.seed)
        for _ in range(steps):
            env.step(policy(env))
        costs.append(env.normalized_cost())
    return float(np.mean(costs))


def bench_infer_all(checkpoint: str | None = None, candidates=(5, 10, 20, 50), envs: int = 2, steps: int = 200,
                    repeats: int = 5) -> dict:
    out: dict = {"paper_latency_s": PAPER_LATENCY_S, "s_star": None, "costs": {}}
    path = checkpoint or (str(shipped_checkpoint("madp")) if shipped_checkpoint("madp") else None)
    if path:
        model, _ = load(path, "madp")
        costs = {s: cost_at(model, s, envs, steps) for s in sorted(set(candidates) | {50})}
        out["costs"] = {str(s): c for s, c in costs.items()}
        out["s_star"] = min(s for s, c in costs.items() if abs(c - costs[50]) <= 0.01)
        out["checkpoint"] = path
    s_values = sorted({50, out["s_star"] or 50})
    out["latency"] = [bench_infer(preset, mode, num_steps=s, repeats=repeats)
                      for preset in ("cpu", "paper") for mode in ("decentralized", "centralized") for s in s_values]
    return out
