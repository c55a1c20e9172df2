"""``madp bench infer`` (its robot-runtime rows): the time of one robot's control step through the
exported files (:class:`madp.robot.RobotRuntime`, onnxruntime on one thread), beside the PyTorch
policy's control step of the whole swarm on one thread, per robot.

The swarm: N robots of a random uniform-launch scenario at its first step, the evaluation default's
sampling (:class:`madp.policies.SamplingSettings`' defaults). A robot's step is what it runs
per control step once it has sensed: its token (perception graph, neighbourhood offset) and its act
(inbox checks, encoder once, denoiser S times on K samples, the choice); its observation and map
views are computed before timing (as the simulator gives them), except that under a ``value`` rule the
map prior's graph runs on the robot's own window inside the timing (a ``critic`` rule's graph runs in its
choice, timed), and under a ``_joint`` rule the
sum of its neighbours' costs (their cost messages from an untimed pass) too. A policy distilled into
one sampler step samples at S = 1. The PyTorch figure is
:meth:`madp.policies.MADPPolicy.act_batch` on the whole swarm (observations and the choice included)
divided by N. Medians of ``repeats`` passes over all robots, one untimed pass first.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["bench_robot_runtime", "format_robot_runtime"]


def bench_robot_runtime(checkpoint: str | None = None, num_robots: int = 32, candidates: int | None = None, repeats: int = 5,
                        seed: int = 0, select: str | None = None) -> dict:
    """Latency per robot per control step of the runtime (one thread) and of PyTorch (one thread), at the
    evaluation default's sampling (``candidates``: another K; ``select``: another rule, those that read a
    learned network with the one the checkpoint carries)."""
    import torch

    from madp.models.bench import torch_threads
    from madp.policies import MADPPolicy, SamplingSettings, load, noise_generator, shipped_checkpoint
    from madp.policies.checkpoint import load_learned
    from madp.robot.choice import local_views
    from madp.robot import RobotRuntime
    from madp.robot.prior import window_inputs
    from madp.selection import RULES
    from madp.sim import CoverageEnv, Scenario, SimParams

    from .onnx import export_policy

    path = checkpoint or str(shipped_checkpoint("madp"))
    model = load(path, "madp")[0]
    one_step = model.config.prediction == "sample"  # distilled into one sampler step
    sampling = SamplingSettings.of(select=select, candidates=candidates, sampling_steps=1 if one_step else None)
    env = CoverageEnv(Scenario.random(seed, SimParams(num_robots=num_robots, num_features=32)))
    with tempfile.TemporaryDirectory() as tmp:
        export_policy(path, Path(tmp), sampling)
        rt = RobotRuntime(tmp, threads=1)
        obs, pos, nbr = env.observations(), env.positions_m, env.neighbours()
        base = local_views(env)
        views = rt.view(env.maps, base)
        rows = [views.row(i) for i in range(num_robots)]
        # the map prior's input per robot (value rules): its graph runs inside the timing
        windows = window_inputs(env.maps, base)[0] if rt.record.prior else None
        sent = [rt.message(i, 0, obs[i], pos[i], pos[nbr[i]], seed) for i in range(num_robots)]
        inboxes = [[sent[j] for j in np.flatnonzero(nbr[i])] for i in range(num_robots)]
        costs = [rt.cost_message(rt.step(i, 0, obs[i], pos[i], inboxes[i], seed, view=rows[i], own=sent[i]))
                 for i in range(num_robots)] if rt.joint else None

        def one_pass() -> float:
            t0 = time.perf_counter()
            for i in range(num_robots):
                own = rt.message(i, 0, obs[i], pos[i], pos[nbr[i]], seed)
                if windows is not None:
                    rt.predict_prior(windows[i:i + 1])
                res = rt.step(i, 0, obs[i], pos[i], inboxes[i], seed, view=rows[i], own=own)
                if costs is not None:
                    ids = np.flatnonzero(nbr[i])
                    rt.choose_joint(res, [costs[j] for j in ids], ids)
            return (time.perf_counter() - t0) / num_robots

        one_pass()
        robot = [one_pass() for _ in range(repeats)]
    needs = RULES[sampling.select].needs
    policy = MADPPolicy(model, "decentralized", sampling, network=load_learned(path, needs) if needs else None)
    gen = noise_generator(seed)
    with torch_threads(1):
        policy.act_batch([env], [gen])
        swarm = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            policy.act_batch([env], [gen])
            swarm.append(time.perf_counter() - t0)
    return {"checkpoint": path, "num_robots": num_robots, "candidates": sampling.candidates, "sampler": sampling.sampler,
            "num_steps": sampling.sampling_steps, "select": sampling.select, "frame": sampling.frame, "threads": 1,
            "mean_neighbourhood": float(nbr.sum(1).mean() + 1), "onnxruntime_per_robot_s": float(np.median(robot)),
            "torch_swarm_s": float(np.median(swarm)), "torch_per_robot_s": float(np.median(swarm)) / num_robots,
            "torch_threads": torch.get_num_threads()}


def format_robot_runtime(r: dict) -> list[str]:
    """The lines ``madp bench infer`` prints for :func:`bench_robot_runtime`."""
    return [f"robot runtime (madp export, onnxruntime, 1 thread): {1e3 * r['onnxruntime_per_robot_s']:.2f} ms per robot "
            f"per control step; PyTorch (1 thread, the whole swarm's step / N): {1e3 * r['torch_per_robot_s']:.2f} ms per "
            f"robot ({1e3 * r['torch_swarm_s']:.1f} ms per swarm step)   ({r['sampler']} S = {r['num_steps']}, "
            f"{r['select']} among K = {r['candidates']}, frame {r['frame']}, N = {r['num_robots']}, "
            f"{r['mean_neighbourhood']:.1f} robots per neighbourhood; paper: 0.36 s per control step on an RTX 3090)"]
