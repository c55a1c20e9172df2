"""How long `madp eval --suite all` takes on this machine, from a sample of each group.

For every group of every suite of `all` and every controller, this runs the first task `madp eval`
would run for it (a batch of --batch environments in lockstep for a learned controller, as
`madp eval` batches them; one environment for a classical one) for the full --steps, in this process
on one torch thread as an evaluation worker runs, and times it in process CPU time (so other jobs
on the machine do not inflate it). A group's CPU time is that per-environment cost times the
group's number of environments; the wall time on W workers is the total over W (the pool keeps
every worker busy until its last few tasks). A sample, not the run: environments of a group differ,
a batch of --batch amortises less than `madp eval`'s batches of 8, and with --steps below the
evaluation's --eval-steps a rollout's time is scaled up by their ratio. With --cities K only the
first K cities are timed, each standing for 40 / K.

    python scripts/suite_time.py --batch 2 --steps 200 --cities 4 --out runs/suite_time.json
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch

from madp.controllers import CLASSICAL, DEFAULT
from madp.eval.runner import EvalConfig, available_controllers, run_task
from madp.eval.suites import SUITES, suite_envs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num-envs", type=int, default=50, help="environments per group of the evaluation timed")
    ap.add_argument("--steps", type=int, default=600, help="control steps timed per rollout")
    ap.add_argument("--eval-steps", type=int, default=600, help="control steps of the evaluation estimated")
    ap.add_argument("--cities", type=int, default=0, help="time only the first K cities (0: all)")
    ap.add_argument("--batch", type=int, default=2, help="environments of a learned controller's timed batch")
    ap.add_argument("--workers", type=int, default=2, help="evaluation workers the wall time is given for")
    ap.add_argument("--suites", default=",".join(SUITES))
    ap.add_argument("--out", type=Path, default=Path("runs/suite_time.json"))
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg, controllers = available_controllers(EvalConfig(suite="all", steps=args.steps), DEFAULT, False)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for suite in args.suites.split(","):
            envs = suite_envs(suite, args.num_envs)
            groups = defaultdict(list)
            for e in envs:
                groups[e.group].append(e)
            timed = list(groups.items())
            if suite == "cities" and args.cities:
                timed = timed[:args.cities]
            stands_for = len(groups) / len(timed)  # groups each timed one stands for
            for group, specs in timed:
                for c in controllers:
                    sample = specs[:1] if c in CLASSICAL else specs[:args.batch]
                    t0 = time.process_time()
                    run_task(cfg, c, sample, Path(tmp) / suite, False)
                    per_env_s = (time.process_time() - t0) / len(sample) * args.eval_steps / args.steps
                    rows.append({"suite": suite, "group": group, "controller": c, "envs": len(specs),
                                 "robots": sample[0].params.num_robots, "cpu_s_per_env": per_env_s,
                                 "cpu_s": per_env_s * len(specs) * stands_for})
                    print(f"{suite:8s} {group:28s} {c:12s} {per_env_s:7.1f} s/env  x {len(specs)}", flush=True)
    total = sum(r["cpu_s"] for r in rows)
    by = defaultdict(float)
    for r in rows:
        by[(r["suite"], r["controller"])] += r["cpu_s"]
    print("\n| suite | " + " | ".join(controllers) + " | all |\n|---|" + "--:|" * (len(controllers) + 1))
    for s in args.suites.split(","):
        cells = [by[(s, c)] / 60 / args.workers for c in controllers]
        print(f"| {s} | " + " | ".join(f"{x:.1f}" for x in cells) + f" | {sum(cells):.1f} |")
    print(f"\nall suites: {total / 3600:.2f} CPU hours, {total / 60 / args.workers:.0f} min wall on {args.workers} workers")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"settings": vars(args) | {"out": str(args.out)}, "rows": rows,
                                    "cpu_s": total, "wall_min": total / 60 / args.workers}, indent=1))


if __name__ == "__main__":
    main()
