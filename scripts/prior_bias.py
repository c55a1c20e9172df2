"""How well a map prior and `explore`'s mean predict the unexplored map, by launch layout and step.

The deployed policy (MADP at the evaluation default, `explore`) drives --envs swarms per layout from
the `launch` suite's rectangles (uniform, square, line) on *dataset* scenario seeds (never an
evaluation suite's), for --steps steps. Every 20 steps each robot's window is an example, as
`madp value collect` takes them. Per layout and step range it prints, over the unexplored part of
the windows inside the world (per m²): the squared error and the mean signed error (positive: the
prediction is above the truth) of the map prior that --policy carries and of `explore`'s mean, and
the true mean importance.

    python scripts/prior_bias.py --policy docs/results/value-k16-2026-12-05/policy.safetensors --envs 8
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from madp.controllers import make_controller
from madp.datagen.plan import scenario_seed
from madp.eval.suites import LAUNCHES
from madp.policies import SamplingSettings
from madp.policies.checkpoint import load_map_prior
from madp.policies.madp import noise_generator
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.rollout import Hook, run
from madp.training.map_prior import explore_mean, window_examples

RANGES = ((0, 20), (20, 60), (60, None))


class _Windows(Hook):
    def __init__(self, every: int):
        self.every, self.parts = every, []  # (step, inputs, targets, weights)

    def start(self, envs):
        self.stepped(0, envs)

    def stepped(self, t, envs):
        if t % self.every == 0:
            self.parts += [(t, *window_examples(env)) for env in envs]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policy", required=True, help="a policy file that carries a map prior (madp value train)")
    ap.add_argument("--envs", type=int, default=8, help="rollouts per layout")
    ap.add_argument("--steps", type=int, default=200, help="steps per rollout")
    ap.add_argument("--layouts", default="uniform,square,line", help="launch layouts, comma-separated")
    ap.add_argument("--seed", type=int, default=7, help="dataset seed of the scenarios")
    args = ap.parse_args()
    prior = load_map_prior(args.policy)
    if prior is None:
        raise SystemExit(f"{args.policy}: carries no map prior; make one with madp value train")
    params = SimParams()
    ctrl = make_controller("madp", None, sampling=SamplingSettings.of())
    print("| layout | steps | prior: squared error | prior: signed error | explore: squared error "
          "| explore: signed error | true mean |\n|---|---|--:|--:|--:|--:|--:|")
    for layout in args.layouts.split(","):
        envs = [CoverageEnv(Scenario.random(scenario_seed(args.seed, "train", 0, i), params, LAUNCHES[layout]))
                for i in range(args.envs)]
        gens = [noise_generator(e.scenario.seed) for e in envs]
        hook = _Windows(20)
        run(envs, lambda es: ctrl.act_batch(es, gens), [hook], steps=args.steps)
        for lo, hi in RANGES:
            parts = [p for p in hook.parts if p[0] >= lo and (hi is None or p[0] < hi)]
            if not parts:
                continue
            x, y, w = (torch.from_numpy(np.concatenate([p[k] for p in parts]).astype(np.float32)) for k in (1, 2, 3))
            with torch.no_grad():
                pred = torch.cat([prior(c) for c in x.split(4096)])
            mean = explore_mean(x)

            def err(a, power):
                return float(((a - y) ** power * w).sum() / w.sum())

            print(f"| {layout} | {lo}–{hi if hi is not None else args.steps} | {err(pred, 2):.4f} | {err(pred, 1):+.4f} "
                  f"| {err(mean, 2):.4f} | {err(mean, 1):+.4f} | {float((y * w).sum() / w.sum()):.4f} |", flush=True)


if __name__ == "__main__":
    main()
