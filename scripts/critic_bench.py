"""One robot's critic step, timed: what it computes to choose among K joint copies with the exported critic.

On a dataset scenario (never an evaluation suite's), the state after --steps steps of the deployed
policy, robot 0 computes its inputs (its window and its neighbours' offsets,
:func:`madp.robot.critic.critic_inputs` on its own row), runs the exported critic graph on
onnxruntime's CPU provider (one thread, no torch) and scores its K candidates
(:func:`madp.robot.critic.copy_scores`). Each part is timed --reps times, interleaved, and the medians
are printed (ms), with the ``explore`` rule's whole choice for the same robot beside them.

    python scripts/critic_bench.py --graph docs/results/critic-2026-12-07/critic.onnx --candidates 16
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph", required=True, help="The exported critic (madp critic export).")
    ap.add_argument("--candidates", type=int, default=16, help="K candidates per robot.")
    ap.add_argument("--steps", type=int, default=40, help="Steps of the deployed policy before the timed state.")
    ap.add_argument("--reps", type=int, default=300, help="Timed calls of each part.")
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    from madp.controllers import make_controller
    from madp.policies import SamplingSettings
    from madp.policies.madp import noise_generator
    from madp.robot.choice import explore_prior, local_cell_costs, local_views
    from madp.robot.critic import copy_scores, critic_inputs, displacements_m, onnx_predictor
    from madp.sim import CoverageEnv, SimParams
    from madp.sim.rollout import run
    from madp.training.map_prior import _scenario

    params = SimParams()
    env = CoverageEnv(_scenario(0, 0, params))
    ctrl = make_controller("madp", sampling=SamplingSettings.of())
    gen = noise_generator(env.scenario.seed)
    run([env], lambda es: ctrl.act_batch(es, [gen]), steps=args.steps)
    predict = onnx_predictor(args.graph, threads=1)
    views = local_views(env).row(0)  # robot 0's own row: its maps are row 0 of env.maps
    cand = np.random.default_rng(0).uniform(-5, 5, size=(1, args.candidates, 2))

    def inputs():
        return critic_inputs(env.maps, views, params.comm_radius_m)

    x = inputs()

    def forward():
        return predict(*x)

    mass, offset = forward()

    def score():
        return copy_scores(mass, offset, displacements_m(views, cand, params)).argmin(1)

    def explore():
        return local_cell_costs(explore_prior(env, views), cand, params).argmin(1)

    parts = {"inputs": inputs, "forward": forward, "scores": score, "explore_choice": explore}
    times = {k: [] for k in parts}
    for _ in range(10):
        for f in parts.values():
            f()
    for _ in range(args.reps):
        for k, f in parts.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    med = {k: round(1e3 * float(np.median(v)), 3) for k, v in times.items()}
    med["critic_total"] = round(med["inputs"] + med["forward"] + med["scores"], 3)
    print(json.dumps({"candidates": args.candidates, "reps": args.reps, "median_ms": med}))


if __name__ == "__main__":
    main()
