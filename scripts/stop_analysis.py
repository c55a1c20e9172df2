"""Where robots stop from packed starts, and what the expert would do there (README, Exploration).

Along MADP's (decentralized, the evaluation default sampler) and LPAC-K3's rollouts of the ``launch``
suite's ``line`` and ``square`` environments (600 steps), at every control step and per robot:

* ``speed``: the speed it executes (m/s, after clipping to u_max); ``stopped``: speed < 0.1 m/s;
* ``distance``: the distance it has travelled since t = 0 (m);
* ``unsensed``: whether its Voronoi cell (over the whole world, among all robots) still holds
  importance that no robot has sensed: more than ``1e-3`` of the world's total importance on cells no
  robot's sensor has covered yet (every 4th cell per axis, i.e. on a 4 m grid);
* the clairvoyant expert's action in the same state: its speed, and its cosine with the policy's
  action (over robots where both move faster than 0.01 m/s).

Written: a JSON summary (per controller and layout: curves every 10 steps, and per-robot stop times:
the first step from which a robot stays below 0.1 m/s until the end) and a PNG of the curves over time.

    python scripts/stop_analysis.py [--envs 10] [--out docs/results/stop_analysis]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from madp.controllers import make_controller
from madp.eval.suites import suite_envs
from madp.policies import noise_generator
from madp.sim import ClairvoyantCVT, CoverageEnv
from madp.sim.rollout import Hook, run

STOP_MPS = 0.1
GRID_M = 4
UNSENSED_FRACTION = 1e-3


class StopProbe(Hook):
    """Per step t = 0..T-1 and robot: executed speed, expert speed, cosine, unsensed-cell flag."""

    def __init__(self, steps: int):
        self.steps = steps
        self.expert = ClairvoyantCVT()

    def start(self, envs):
        b, n = len(envs), envs[0].num_robots
        p = envs[0].params
        self.speed = np.empty((b, self.steps, n))
        self.expert_speed = np.empty((b, self.steps, n))
        self.cosine = np.full((b, self.steps, n), np.nan)
        self.unsensed = np.zeros((b, self.steps, n), dtype=bool)
        w = p.world_size
        self.grid_m = np.stack(np.meshgrid(np.arange(0, w, GRID_M) + 0.5, np.arange(0, w, GRID_M) + 0.5,
                                           indexing="ij"), -1).reshape(-1, 2)  # [G, 2] (x, y) cell centres
        self.importance = [e.world_map[::GRID_M, ::GRID_M].reshape(-1) for e in envs]  # world_map[x, y]
        self.sensed = [np.zeros((w, w), dtype=bool) for _ in envs]
        self.half = p.sensor_size // 2
        for i, e in enumerate(envs):
            self._sense(i, e)

    def _sense(self, i: int, env: CoverageEnv) -> None:
        w = env.params.world_size
        for cx, cy in env.cells():  # N slices, one per robot
            self.sensed[i][max(cx - self.half, 0):min(cx + self.half, w), max(cy - self.half, 0):min(cy + self.half, w)] = True

    def actions(self, t, envs, actions, act_s):
        for i, e in enumerate(envs):
            u = actions[i]
            u_star = self.expert(e)
            s, s_star = np.linalg.norm(u, axis=1), np.linalg.norm(u_star, axis=1)
            self.speed[i, t] = np.minimum(s, e.params.max_speed_mps)
            self.expert_speed[i, t] = np.minimum(s_star, e.params.max_speed_mps)
            both = (s > 0.01) & (s_star > 0.01)
            self.cosine[i, t, both] = (u[both] * u_star[both]).sum(1) / (s[both] * s_star[both])
            d2 = ((self.grid_m[:, None] - e.positions_m[None]) ** 2).sum(-1)  # [G, N]
            owner = d2.argmin(1)
            left = self.importance[i] * ~self.sensed[i][::GRID_M, ::GRID_M].reshape(-1)
            per_cell = np.bincount(owner, weights=left, minlength=e.num_robots)
            self.unsensed[i, t] = per_cell > UNSENSED_FRACTION * self.importance[i].sum()

    def stepped(self, t, envs):
        for i, e in enumerate(envs):
            self._sense(i, e)


def stop_times(speed: np.ndarray) -> np.ndarray:
    """``speed [..., T]`` → the first step from which it stays below STOP_MPS to the end (T: never)."""
    moving = speed >= STOP_MPS
    t_len = speed.shape[-1]
    last_moving = np.where(moving.any(-1), t_len - 1 - np.argmax(moving[..., ::-1], -1), -1)
    return last_moving + 1


def analyse(controller: str, layout: str, num_envs: int, steps: int) -> dict:
    specs = [s for s in suite_envs("launch", num_envs) if s.group == layout]
    envs = [CoverageEnv(s.scenario()) for s in specs]
    ctrl = make_controller(controller, seed=specs[0].seed)
    gens = [noise_generator(s.seed) for s in specs]
    probe = StopProbe(steps)
    costs: list[list[float]] = [[1.0] for _ in envs]

    class Cost(Hook):
        def stepped(self, t, es):
            for c, e in zip(costs, es):
                c.append(e.normalized_cost())

    run(envs, lambda es: ctrl.act_batch(es, gens), [probe, Cost()], steps)
    stopped = probe.speed < STOP_MPS  # [B, T, N]
    distance = np.cumsum(probe.speed * envs[0].params.dt_s, axis=1)
    every = np.arange(0, steps, 10)
    with np.errstate(invalid="ignore"):
        frac_unsensed = (stopped & probe.unsensed).sum((0, 2)) / np.maximum(stopped.sum((0, 2)), 1)
    cos_stopped = np.where(stopped, probe.cosine, np.nan)
    t_stop = stop_times(probe.speed.transpose(0, 2, 1))  # [B, N]
    return {
        "controller": controller, "layout": layout, "envs": len(envs), "steps": steps,
        "t": every.tolist(),
        "cost": np.mean(costs, 0)[every].tolist(),
        "speed_mps": probe.speed.mean((0, 2))[every].tolist(),
        "expert_speed_mps": probe.expert_speed.mean((0, 2))[every].tolist(),
        "stopped_fraction": stopped.mean((0, 2))[every].tolist(),
        "stopped_unsensed_fraction": frac_unsensed[every].tolist(),
        "expert_speed_when_stopped_mps": [float(np.nanmean(np.where(stopped[:, t], probe.expert_speed[:, t], np.nan)))
                                          if stopped[:, t].any() else None for t in every],
        "cosine": np.nanmean(probe.cosine, (0, 2))[every].tolist(),
        "cosine_when_stopped": [float(np.nanmean(cos_stopped[:, t])) if np.isfinite(cos_stopped[:, t]).any() else None
                                for t in every],
        "distance_m_mean": distance.mean((0, 2))[every].tolist(),
        "distance_m_final_quartiles": np.percentile(distance[:, -1], [25, 50, 75]).tolist(),
        "stop_step_quartiles": np.percentile(t_stop, [25, 50, 75]).tolist(),
        "never_stop_fraction": float((t_stop == steps).mean()),
        "final_cost": float(np.mean([c[-1] for c in costs])),
    }


def plot(rows: list[dict], out_png: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = [("cost", "J(t)/J(0)"), ("speed_mps", "mean speed (m/s); dotted: expert in the same state"),
              ("stopped_fraction", "robots stopped (< 0.1 m/s)"),
              ("stopped_unsensed_fraction", "stopped robots whose cell holds unsensed importance"),
              ("cosine", "cos(policy, expert), all robots"), ("distance_m_mean", "mean distance travelled (m)")]
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    colors = {"madp": "tab:red", "lpac": "tab:blue"}
    for ax, (key, title) in zip(axes.flat, panels):
        for r in rows:
            style = "-" if r["layout"] == "line" else "--"
            label = f"{'MADP' if r['controller'] == 'madp' else 'LPAC-K3'} {r['layout']}"
            ax.plot(r["t"], [np.nan if v is None else v for v in r[key]], style, color=colors[r["controller"]], label=label)
            if key == "speed_mps":
                ax.plot(r["t"], r["expert_speed_mps"], ":", color=colors[r["controller"]], alpha=0.7)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("control step")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Packed starts: where robots stop ({rows[0]['envs']} launch-suite environments per layout)")
    fig.tight_layout()
    tmp = out_png.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    tmp.replace(out_png)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=10, help="environments per layout (the launch suite's first)")
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--controllers", default="madp,lpac")
    p.add_argument("--out", type=Path, default=Path("docs/results/stop_analysis"), help="writes OUT.json and OUT.png")
    args = p.parse_args()
    torch.set_num_threads(1)
    rows = [analyse(c, layout, args.envs, args.steps) for c in args.controllers.split(",") for layout in ("line", "square")]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(rows, indent=1))
    tmp.replace(args.out.with_suffix(".json"))
    plot(rows, args.out.with_suffix(".png"))
    for r in rows:
        k = min(30, len(r["t"]) - 1)  # step 300 of the full horizon
        print(f"{r['controller']:5s} {r['layout']:6s} J(600)/J(0) {r['final_cost']:.3f}  stopped@{r['t'][k]} "
              f"{r['stopped_fraction'][k]:.2f}  of them unsensed {r['stopped_unsensed_fraction'][k]:.2f}  "
              f"expert speed there {r['expert_speed_when_stopped_mps'][k]}  stop step q25/50/75 {r['stop_step_quartiles']}  "
              f"distance q25/50/75 {r['distance_m_final_quartiles']}")


if __name__ == "__main__":
    main()
