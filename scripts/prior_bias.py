"""How well a map prior and `explore`'s mean predict the unexplored map, by launch layout and step.

The deployed policy (MADP at the evaluation default, `explore`) drives --envs swarms per layout from
the `launch` suite's rectangles (uniform, square, line) on *dataset* scenario seeds (never an
evaluation suite's), for --steps steps. Every 20 steps each robot's window is an example, as
`madp value collect` takes them. Per layout and step range it prints, over the unexplored part of
the windows inside the world (per m²): the squared error and the mean signed error (positive: the
prediction is above the truth) of `explore`'s mean and of the map prior each --policy carries, on the
same windows, and the true mean importance.

    python scripts/prior_bias.py --envs 8 --policy docs/results/value-k16-2026-12-05/policy.safetensors \
        --policy runs/value/expectile.safetensors
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
from madp.sim.rollout import run
from madp.training.map_prior import WindowHook, explore_mean

RANGES = ((0, 20), (20, 60), (60, None))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policy", required=True, action="append",
                    help="a policy file that carries a map prior (madp value train); repeat for several")
    ap.add_argument("--envs", type=int, default=8, help="rollouts per layout")
    ap.add_argument("--steps", type=int, default=200, help="steps per rollout")
    ap.add_argument("--layouts", default="uniform,square,line", help="launch layouts, comma-separated")
    ap.add_argument("--seed", type=int, default=7, help="dataset seed of the scenarios")
    args = ap.parse_args()
    priors = {}
    for path in args.policy:
        priors[path] = load_map_prior(path)
        if priors[path] is None:
            raise SystemExit(f"{path}: carries no map prior; make one with madp value train")
    params = SimParams()
    ctrl = make_controller("madp", None, sampling=SamplingSettings.of())
    print("| layout | steps | true mean | prediction | squared error | signed error |\n|---|---|--:|---|--:|--:|")
    for layout in args.layouts.split(","):
        envs = [CoverageEnv(Scenario.random(scenario_seed(args.seed, "train", 0, i), params, LAUNCHES[layout]))
                for i in range(args.envs)]
        gens = [noise_generator(e.scenario.seed) for e in envs]
        hook = WindowHook(20)
        run(envs, lambda es: ctrl.act_batch(es, gens), [hook], steps=args.steps)
        for lo, hi in RANGES:
            parts = [p for p in hook.parts if p[0] >= lo and (hi is None or p[0] < hi)]
            if not parts:
                continue
            x, y, w = (torch.from_numpy(np.concatenate([p[2][k] for p in parts]).astype(np.float32)) for k in (0, 1, 2))
            preds = {"explore's mean": explore_mean(x)}
            with torch.no_grad():
                preds.update({path: torch.cat([prior(c) for c in x.split(4096)]) for path, prior in priors.items()})
            head = f"| {layout} | {lo}–{hi if hi is not None else args.steps} | {float((y * w).sum() / w.sum()):.4f}"
            for name, pred in preds.items():
                sq, signed = (float(((pred - y) ** k * w).sum() / w.sum()) for k in (2, 1))
                print(f"{head} | {name} | {sq:.4f} | {signed:+.4f} |", flush=True)


if __name__ == "__main__":
    main()
