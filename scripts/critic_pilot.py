"""A closed-loop pilot of the critic on a few dataset scenarios (never an evaluation suite's): not a suite.

The deployed policy (MADP at the evaluation default) draws K joint copies per step with each rollout's own
noise, as ``act_batch`` does, and a selection rule keeps one action per robot: ``explore`` (the default),
``critic`` or ``critic_hood`` (:func:`madp.policies.select.select_actions`). Each rule runs the same
scenarios from the same noise seed; printed and written: J(T)/J(0) per scenario and rule.

    python scripts/critic_pilot.py --critic docs/results/critic-2026-12-07/policy.safetensors --first 40 \
        --envs 4 --out docs/results/critic-2026-12-07/pilot.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--critic", required=True, help="Policy file carrying a critic (madp critic train).")
    ap.add_argument("--first", type=int, default=40, help="First dataset scenario index (seed 0).")
    ap.add_argument("--envs", type=int, default=4, help="Scenarios, run as one batch.")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--candidates", type=int, default=4, help="K joint copies per step.")
    ap.add_argument("--rules", default="explore,critic_hood,critic", help="Selection rules, comma-separated.")
    ap.add_argument("--out", required=True, help="JSON to write.")
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    from madp.controllers import make_controller
    from madp.io.atomic import write_json_atomic
    from madp.models.critic import load_critic
    from madp.policies import SamplingSettings
    from madp.policies.madp import noise_generator
    from madp.policies.select import select_actions
    from madp.sim import CoverageEnv, SimParams
    from madp.sim.rollout import run
    from madp.training.critic import draw_copies
    from madp.training.map_prior import _scenario

    params = SimParams()
    policy = make_controller("madp", sampling=SamplingSettings.of())
    net = load_critic(args.critic)
    idx = list(range(args.first, args.first + args.envs))
    result = {"critic": args.critic, "scenarios": idx, "steps": args.steps, "candidates": args.candidates,
              "seed": 0, "final": {}}
    for rule in args.rules.split(","):
        t0 = time.perf_counter()
        envs = [CoverageEnv(_scenario(0, i, params)) for i in idx]
        gens = [noise_generator(e.scenario.seed) for e in envs]

        def act(es, rule=rule, gens=gens):
            copies = draw_copies(policy, es, args.candidates, gens)  # [B, K, N, 2]
            return np.stack([select_actions(rule, e, c, net) for e, c in zip(es, copies)])

        run(envs, act, steps=args.steps)
        result["final"][rule] = [float(e.normalized_cost()) for e in envs]
        print(rule, np.round(result["final"][rule], 4), f"mean {np.mean(result['final'][rule]):.4f}",
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()
