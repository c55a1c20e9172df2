"""What limits the local selection rules (README, Choosing among MADP's samples): a diagnostic, not
a controller. It runs ``madp eval``'s ``uniform`` suite for decentralized MADP with ``--select cell``
and K candidates, with the local cost of :mod:`madp.policies.select` replaced by a variant:

* ``--cost window``: the robot's view of J over its whole window with its neighbours fixed,
  ``sum_q w_q min(|q − y|², min_j |q − x_j|²)``, instead of its own cell's cost (the two rank
  candidates differently by what the neighbours would pay for the points the robot takes);
* ``--map true``: each robot's window of the TRUE world map instead of its own sensed map (what
  no robot knows: it tells whether the rule or the robot's information is the limit; with
  ``--cost cell`` this is ``madp eval --select oracle_cell``).

    python scripts/select_probe.py --cost window --map true --out runs/select-probe/window-true
"""

from __future__ import annotations

import argparse

import numpy as np
import pyarrow.parquet as pq
import torch

import madp.policies.select as select
from madp.eval.runner import EvalConfig, available_controllers, run_suite
from madp.policies import SamplingSettings
from madp.sim.env import move


def window_costs(views: select.LocalViews, actions_mps: np.ndarray, params) -> np.ndarray:
    """``[R, K]``: the window's J as robot r sees it after candidate k, neighbours where they are."""
    y, _ = move(views.start_m[:, None], views.offset_m[:, None], actions_mps, params)
    g = views.weights.shape[1]
    q = views.origin_m[:, :, None] + select.GRID_M * np.arange(g) + select.GRID_M / 2
    to_nbr = ((q[:, None, 0, :, None] - views.neighbours_m[..., 0, None, None]) ** 2
              + (q[:, None, 1, None, :] - views.neighbours_m[..., 1, None, None]) ** 2)
    nearest = np.where(views.valid[..., None, None], to_nbr, np.inf).min(1)
    to_y = (q[:, None, 0, :, None] - y[..., 0, None, None]) ** 2 + (q[:, None, 1, None, :] - y[..., 1, None, None]) ** 2
    return (np.minimum(to_y, nearest[:, None]) * views.weights[:, None]).sum((2, 3))


def true_map_views(env) -> select.LocalViews:
    """:func:`madp.policies.select.local_views` with each window read from the world map (the views
    ``--select oracle_cell`` uses)."""
    return select_local_views(env, true_map=True)


select_local_views = select.local_views


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cost", choices=("cell", "window"), default="window")
    p.add_argument("--map", choices=("own", "true"), default="own")
    p.add_argument("--candidates", type=int, default=4)
    p.add_argument("--envs", type=int, default=4)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--out", default="runs/select-probe")
    args = p.parse_args()
    torch.set_num_threads(1)
    if args.cost == "window":
        select.local_cell_costs = window_costs
    if args.map == "true":
        select.local_views = true_map_views
    cfg = EvalConfig(suite="uniform", out=args.out, num_envs=args.envs, steps=args.steps, controllers=("madp",),
                     sampling=SamplingSettings(select="cell", candidates=args.candidates),
                     workers=1)  # one process: the patches hold
    cfg, _ = available_controllers(cfg, ("madp",), True)
    run_suite(cfg, "uniform", progress=False)
    t = pq.read_table(f"{args.out}/uniform/results.parquet").to_pydict()
    print(f"cost {args.cost}, map {args.map}, K = {args.candidates}: J({args.steps})/J(0) per env "
          f"{np.round(t['final_cost'], 3).tolist()}, mean {np.mean(t['final_cost']):.3f}")


if __name__ == "__main__":
    main()
