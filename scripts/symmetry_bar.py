"""How often an exactly symmetric policy meets issue 25's symmetry bar (every image's mean within its
own SE of the layout's mean over the 8 images), given a finished ``symmetry`` run (README, Exploration).

Per layout it estimates, from the run's final costs ``cost[env, image]``, the environments' spread (sd
of the per-environment means over images) and the rollout noise (sd across images within an
environment), then simulates symmetric policies with those two: for n environments per image, each
draw resamples n environments' means and adds independent rollout noise per image, and counts the draws
where all 8 images lie within one SE. Prints both spreads and the pass rate for each n.

    python scripts/symmetry_bar.py runs/eval-r8/symmetry [--n 15,50] [--draws 4000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from madp.eval.stats import SYMMETRY_GROUP


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("suite_dir", type=Path)
    ap.add_argument("--controller", default="madp")
    ap.add_argument("--n", default="15,50")
    ap.add_argument("--draws", type=int, default=4000)
    args = ap.parse_args()
    t = pq.read_table(args.suite_dir / "results.parquet").to_pydict()
    cubes: dict[str, dict[tuple[int, int], float]] = {}
    for group, env, ctrl, cost in zip(t["group"], t["env"], t["controller"], t["final_cost"]):
        m = SYMMETRY_GROUP.match(group)
        if m and ctrl == args.controller:
            cubes.setdefault(m["layout"], {})[(int(env), int(m["g"]))] = cost
    rng = np.random.default_rng(0)
    for layout, cells in sorted(cubes.items()):
        envs, images = sorted({e for e, _ in cells}), sorted({g for _, g in cells})
        cube = np.array([[cells.get((e, g), np.nan) for g in images] for e in envs])
        cube = cube[np.isfinite(cube).all(1)]  # [env, image]
        k = cube.shape[1]
        env_means = cube.mean(1, keepdims=True)
        noise = float(np.sqrt(((cube - env_means) ** 2).sum() / (len(cube) * (k - 1))))
        print(f"{layout}: {len(cube)} environments x {k} images; environments' sd {env_means.std(ddof=1):.4f}, "
              f"rollout noise sd {noise:.4f}")
        for n in (int(x) for x in args.n.split(",")):
            sims = env_means[rng.integers(0, len(cube), (args.draws, n))] + rng.normal(0, noise, (args.draws, n, k))
            se = sims.std(1, ddof=1) / np.sqrt(n)
            dev = sims.mean(1) - sims.mean((1, 2))[:, None]
            print(f"  n = {n}: all {k} images within one SE in {np.mean((np.abs(dev) <= se).all(1)):.2f} of draws")


if __name__ == "__main__":
    main()
