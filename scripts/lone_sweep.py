"""The lone robot's step over the `faults` suite's `no_comm` group, without MADP's sampling: where every
message is lost each robot is alone at every step, so its step (madp.robot.choice.lone_steps) is all
it does. Prints J(600)/J(0) (mean ± SE), the environments above J(0) and the worst, per setting.

    python scripts/lone_sweep.py --radius-m 256 --prior-share 0.1 [--num-envs 50]
"""

from __future__ import annotations

import argparse

import numpy as np

from madp.eval.suites import suite_envs
from madp.robot.choice import explore_prior, local_views, lone_steps
from madp.sim import CoverageEnv
from madp.sim.voronoi import coverage_cost


def final_costs(radius_m: float, prior_share: float, num_envs: int, steps: int = 600) -> np.ndarray:
    """J(steps)/J(0) of the first ``num_envs`` `no_comm` environments, every robot on its lone step
    with the ``explore`` rule's views."""
    out = []
    for spec in [s for s in suite_envs("faults", num_envs) if s.group == "no_comm"]:
        env = CoverageEnv(spec.scenario(), network=spec.network)
        for _ in range(steps):
            env.step(lone_steps(explore_prior(env, local_views(env)), env.params, radius_m, prior_share)[1])
        out.append(coverage_cost(env.prefix, env.positions_m) / env.cost0)
    return np.array(out)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius-m", type=float, required=True)
    ap.add_argument("--prior-share", type=float, required=True)
    ap.add_argument("--num-envs", type=int, default=50)
    a = ap.parse_args()
    j = final_costs(a.radius_m, a.prior_share, a.num_envs)
    print(f"radius {a.radius_m:g} m, prior share {a.prior_share:g}: {j.mean():.3f} ± {j.std(ddof=1) / len(j) ** 0.5:.3f}, "
          f"{int((j > 1).sum())}/{len(j)} above J(0), worst {j.max():.3f}")
