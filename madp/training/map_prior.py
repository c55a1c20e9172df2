"""The ``value`` rule's map prior (:mod:`madp.models.map_prior`): its training data and its training.

* :func:`collect` (``madp value collect``): the deployed policy (MADP at the evaluation default, the
  ``critic`` rule on a policy file carrying a critic, else ``explore``; the file records which) drives
  swarms on dataset scenarios (seeds below 2⁶², never an evaluation suite's; uniform and packed
  launches in turn). Every ``every`` steps each robot's window gives one example:
  the prior's input (:func:`madp.robot.prior.prior_inputs`, from the robot's own map) and its
  target, the true importance of the same window (:func:`madp.models.map_prior.prior_targets`). One
  ``.npz`` file, written under a temporary name and renamed, with the settings that made it.
* :func:`train` (``madp value train``): the prior fitted to those examples (the squared error per
  coarse cell, weighted by the part of the cell inside the world the robot has not explored, with
  the world's 8 symmetries as augmentation), the environments' last tenth held out. With an
  ``expectile`` τ above 0.5 the squared error of a prediction below the truth counts τ, above it
  1 − τ (expectile regression): the prior then predicts more than the expected importance where the
  unexplored is uncertain, and about the same where it is not, an optimism that sends robots to look.
  τ = 0.5 is the plain squared error. The explore
  rule's own prior, the explored blocks' mean, is scored on the same held-out cells. The result is a
  copy of the policy file with the prior added (weights under ``map_prior.``, config under the
  metadata key ``map_prior``), so one file carries both.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from madp.io.checksum import sha256_file
from madp.datagen.plan import scenario_seed
from madp.errors import SettingError
from madp.io.atomic import atomic_path
from madp.io.npz import load_npz
from madp.models.map_prior import MapPrior, MapPriorConfig, prior_targets
from madp.models.symmetry import transform_image
from madp.policies.checkpoint import attach
from madp.robot.choice import GRID_M, local_views
from madp.robot.prior import window_inputs
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.launch import TRAINING_LAUNCHES, draw_launch
from madp.sim.rollout import Hook, run

__all__ = ["WindowHook", "collect", "expectile_loss", "explore_mean", "train", "window_examples"]

#: Format version of the examples file.
FORMAT = 1


def window_examples(env: CoverageEnv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every robot's example at the current step: inputs ``[N, 3, 16, 16]``, targets ``[N, 16, 16]``
    and loss weights ``[N, 16, 16]`` (the fraction of each coarse cell inside the world and unexplored)."""
    x, _, inside = window_inputs(env.maps, local_views(env))
    y = prior_targets(local_views(env, true_map=True).weights, inside, GRID_M)
    return x, y, np.clip(x[:, 2] - x[:, 1], 0.0, 1.0)


class WindowHook(Hook):
    """A rollout hook that keeps, every ``every`` steps from step 0, each environment's
    :func:`window_examples` in ``parts`` as ``(step, environment index, (inputs, targets, weights))``."""

    def __init__(self, every: int):
        self.every, self.parts = every, []

    def start(self, envs):
        self.stepped(0, envs)

    def stepped(self, t, envs):
        if t % self.every == 0:
            for b, env in enumerate(envs):
                self.parts.append((t, b, window_examples(env)))


class _StepBar(Hook):
    """Advances a progress bar by each environment's step, so a long rollout shows it moves."""

    def __init__(self, bar, task):
        self.bar, self.task = bar, task

    def stepped(self, t, envs):
        if t > 0:
            self.bar.advance(self.task, len(envs))


#: Bounds of ``madp value collect``: rollouts, and steps of each (its examples are held in memory).
MAX_COLLECT_ENVS, MAX_COLLECT_STEPS = 100_000, 10_000


def _scenario(seed: int, index: int, params: SimParams) -> Scenario:
    s = Scenario.random(scenario_seed(seed, "train", 0, index), params)
    launch = TRAINING_LAUNCHES[index % len(TRAINING_LAUNCHES)]
    if launch == "uniform":
        return s
    rng = np.random.default_rng([s.seed, 0x1A])
    return replace(s, robots_m=draw_launch(rng, launch, params.num_robots, params.world_size))


def collect(out: Path, num_envs: int, every: int = 20, steps: int = 600, seed: int = 0, batch: int = 8,
            policy: str | None = None, overwrite: bool = False, progress: bool = True) -> dict:
    """Write the examples of ``num_envs`` rollouts to ``out`` (``.npz``); returns its summary."""
    from madp.controllers import make_controller
    from madp.policies import SamplingSettings
    from madp.policies.madp import noise_generator

    out = Path(out)
    if out.suffix != ".npz":
        raise SettingError("out", f"expected a .npz file, got {out}")
    if out.exists() and not overwrite:
        raise SettingError("out", f"{out} exists; pass --overwrite to replace it")
    for name, v, hi in (("envs", num_envs, MAX_COLLECT_ENVS), ("every", every, MAX_COLLECT_STEPS),
                        ("steps", steps, MAX_COLLECT_STEPS), ("batch", batch, MAX_COLLECT_ENVS)):
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= hi:
            raise SettingError(name, f"expected a whole number from 1 to {hi}, got {v!r}")
    params = SimParams()
    ctrl = make_controller("madp", policy, sampling=SamplingSettings.of())
    xs, ys, ws, env_ids = [], [], [], []
    t0 = time.perf_counter()
    from rich.progress import Progress

    with Progress(disable=not progress) as bar:
        task = bar.add_task("rollout steps", total=num_envs * steps)
        for lo in range(0, num_envs, batch):
            idx = list(range(lo, min(num_envs, lo + batch)))
            envs = [CoverageEnv(_scenario(seed, i, params)) for i in idx]
            gens = [noise_generator(e.scenario.seed) for e in envs]
            hook = WindowHook(every)
            run(envs, lambda es: ctrl.act_batch(es, gens), [hook, _StepBar(bar, task)], steps=steps)
            for _, b, (x, y, w) in hook.parts:
                xs.append(x), ys.append(y), ws.append(w), env_ids.append(np.full(len(x), idx[b], np.int32))
    meta = {"format": FORMAT, "num_envs": num_envs, "every": every, "steps": steps, "seed": seed,
            "policy": str(policy or "shipped"), "select": ctrl.sampling.select, "launches": list(TRAINING_LAUNCHES),
            "examples": int(sum(len(x) for x in xs)), "seconds": round(time.perf_counter() - t0, 1)}
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".npz") as tmp:
        np.savez(tmp, x=np.concatenate(xs), y=np.concatenate(ys), w=np.concatenate(ws).astype(np.float32),
                 env=np.concatenate(env_ids), meta=np.array(json.dumps(meta)))
    return meta


def _load(path: Path) -> tuple[dict, dict]:
    return load_npz(path, ("x", "y", "w", "env"), "a map-prior examples file", "madp value collect", FORMAT,
                    ("x", "y", "w"))


def explore_mean(x: torch.Tensor) -> torch.Tensor:
    """The explore rule's prediction for every cell: the explored part's mean importance per m²
    over the whole window (1 mass unit per block where nothing explored holds any)."""
    known = x[:, 1] * 16.0
    mass = (x[:, 0] * known).sum((1, 2))
    n = known.sum((1, 2)).clamp(min=1.0)
    mean = torch.where(mass > 0, mass / n, torch.full_like(mass, 1.0 / GRID_M ** 2))
    return mean[:, None, None].expand_as(x[:, 0])


def expectile_loss(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor, expectile: float) -> torch.Tensor:
    """The weighted mean of the squared errors, those of predictions below the target counted
    ``2 τ``, those above ``2 (1 − τ)`` (τ = 0.5: the weighted mean squared error itself)."""
    err = pred - target
    side = torch.where(err < 0, 2.0 * expectile, 2.0 * (1.0 - expectile)) if expectile != 0.5 else 1.0
    return (side * err ** 2 * weight).sum() / weight.sum().clamp(min=1e-9)


def train(data: Path, policy: Path, out: Path, epochs: int = 8, batch: int = 256, lr: float = 2e-3, seed: int = 0,
          config: MapPriorConfig | None = None, expectile: float = 0.5, overwrite: bool = False,
          progress: bool = True) -> dict:
    """Fit the map prior to the examples in ``data``, and write ``policy`` with it added to ``out``.
    Returns the held-out scores (squared error and mean signed error per m² of unexplored window)."""
    out = Path(out)
    if isinstance(expectile, bool) or not isinstance(expectile, (int, float)) or not 0.0 < expectile < 1.0:
        raise SettingError("expectile", f"expected a number strictly between 0 and 1, got {expectile!r}")
    if out.exists() and not overwrite:
        raise SettingError("out", f"{out} exists; pass --overwrite to replace it")
    if out.resolve() == Path(policy).resolve():
        raise SettingError("out", f"{out} is the policy file itself; expected a new file")
    arrays, meta = _load(Path(data))
    from madp.policies.checkpoint import load_policy

    load_policy(policy)  # a one-line error unless it is a policy file
    torch.manual_seed(seed)
    envs = np.unique(arrays["env"])
    held = np.isin(arrays["env"], envs[int(len(envs) * 0.9):]) if len(envs) > 1 else np.zeros(len(arrays["env"]), bool)
    x, y, w = (torch.from_numpy(arrays[k]) for k in ("x", "y", "w"))
    tr, va = torch.from_numpy(~held), torch.from_numpy(held)
    net = MapPrior(config)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    n_tr = int(tr.sum())
    steps = epochs * max(1, n_tr // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, lr, total_steps=steps)
    g = torch.Generator().manual_seed(seed)
    xt, yt, wt = x[tr], y[tr], w[tr]

    def score(pred, yy, ww):
        return float(expectile_loss(pred, yy, ww, 0.5))

    def bias(pred, yy, ww):
        return float(((pred - yy) * ww).sum() / ww.sum().clamp(min=1e-9))

    from rich.progress import Progress

    history = []
    with Progress(disable=not progress) as bar:
        task = bar.add_task("map prior", total=steps)
        for epoch in range(epochs):
            net.train()
            perm = torch.randperm(n_tr, generator=g)
            total = 0.0
            for i in range(max(1, n_tr // batch)):
                j = perm[i * batch:(i + 1) * batch]
                k = int(torch.randint(8, (1,), generator=g))
                xb, yb, wb = transform_image(xt[j], k), transform_image(yt[j], k), transform_image(wt[j], k)
                loss = expectile_loss(net(xb), yb, wb, expectile)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                sched.step()
                total += loss.item()
                bar.advance(task)
            history.append(total / max(1, n_tr // batch))
    net.eval()
    with torch.no_grad():
        xv, yv, wv = (x[va], y[va], w[va]) if bool(va.any()) else (xt, yt, wt)
        pred, mean = torch.cat([net(c) for c in xv.split(4096)]), explore_mean(xv)
        scores = {"held_out_examples": int(len(xv)), "train_loss": history,
                  "held_out_mse": score(pred, yv, wv), "held_out_bias": bias(pred, yv, wv),
                  "explore_mean_mse": score(mean, yv, wv), "explore_mean_bias": bias(mean, yv, wv),
                  "zero_mse": score(torch.zeros_like(yv), yv, wv)}
    record = {"data": str(data), "data_sha256": sha256_file(data), "collect": meta, "epochs": epochs, "seed": seed,
              "expectile": expectile, **{k: v for k, v in scores.items() if k != "train_loss"}}
    add_prior(Path(policy), out, net, record)
    return scores


def add_prior(policy: Path, out: Path, net: MapPrior, record: dict) -> None:
    """``policy``'s tensors and metadata with ``net`` added, written to ``out`` under a temporary name."""
    attach(Path(policy), out, "map prior", net, net.config.to_dict(), record)
