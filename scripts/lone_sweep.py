"""The lone robot's step over the `faults` suite's `no_comm` group, without MADP's sampling: where every
message is lost each robot is alone at every step, so its step (madp.robot.choice.lone_steps) is all
it does. Prints J(600)/J(0) (mean ± SE), the environments above J(0) and the worst, per setting.

    python scripts/lone_sweep.py --radius-m 256 --prior-share 0.1 [--num-envs 50]
    python scripts/lone_sweep.py --radius-m 256 --prior-share 0.1 --explain 38

``--explain K`` runs environment K alone and names the robots whose move raised its cost: what
J(600)/J(0) would lose if that robot alone were back at its start, the others where they ended.
"""

from __future__ import annotations

import argparse

import numpy as np

from madp.eval.suites import suite_envs
from madp.robot.choice import explore_prior, local_views, lone_steps
from madp.sim import CoverageEnv
from madp.sim.voronoi import coverage_cost


def lone_rollout(spec, radius_m: float, prior_share: float, steps: int = 600) -> CoverageEnv:
    """One `no_comm` environment after ``steps`` lone steps with the ``explore`` rule's views."""
    env = CoverageEnv(spec.scenario(), network=spec.network)
    for _ in range(steps):
        env.step(lone_steps(explore_prior(env, local_views(env)), env.params, radius_m, prior_share)[1])
    return env


def final_costs(radius_m: float, prior_share: float, num_envs: int, steps: int = 600) -> np.ndarray:
    """J(steps)/J(0) of the first ``num_envs`` `no_comm` environments, every robot on its lone step."""
    envs = [lone_rollout(s, radius_m, prior_share, steps) for s in suite_envs("faults", num_envs) if s.group == "no_comm"]
    return np.array([coverage_cost(e.prefix, e.positions_m) / e.cost0 for e in envs])


def explain(index: int, radius_m: float, prior_share: float) -> None:
    """Print environment ``index``'s J(600)/J(0) and, per robot whose move changed it by more than
    0.01, how far it moved and what it added (its cost with that robot alone back at its start)."""
    spec = [s for s in suite_envs("faults", index + 1) if s.group == "no_comm"][index]
    env = lone_rollout(spec, radius_m, prior_share)
    end, start = env.positions_m, env.start_m
    final = coverage_cost(env.prefix, end) / env.cost0
    print(f"environment {index}: J(600)/J(0) {final:.3f}")
    for i in range(len(end)):
        back = end.copy()
        back[i] = start[i]
        added = final - coverage_cost(env.prefix, back) / env.cost0
        if abs(added) > 0.01:
            print(f"robot {i:3d} moved {np.linalg.norm(end[i] - start[i]):4.0f} m from {np.round(start[i]).tolist()} "
                  f"to {np.round(end[i]).tolist()}: adds {added:+.3f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius-m", type=float, required=True)
    ap.add_argument("--prior-share", type=float, required=True)
    ap.add_argument("--num-envs", type=int, default=50)
    ap.add_argument("--explain", type=int, default=None, metavar="K", help="name the robots that raised env K's cost")
    a = ap.parse_args()
    if a.explain is not None:
        explain(a.explain, a.radius_m, a.prior_share)
        raise SystemExit(0)
    j = final_costs(a.radius_m, a.prior_share, a.num_envs)
    print(f"radius {a.radius_m:g} m, prior share {a.prior_share:g}: {j.mean():.3f} ± {j.std(ddof=1) / len(j) ** 0.5:.3f}, "
          f"{int((j > 1).sum())}/{len(j)} above J(0), worst {j.max():.3f}")
