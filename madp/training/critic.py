"""The critic of MADP's joint copies (:mod:`madp.robot.critic`, :mod:`madp.models.critic`): its labels.

:func:`collect` (``madp critic collect``): the deployed policy (MADP at the evaluation default, K = 4:
the ``critic`` rule on a policy file carrying a critic, else ``explore``; the file records which)
drives swarms on dataset scenarios (seeds below 2⁶², never an evaluation suite's; uniform and packed launches in turn, as ``madp value collect``). Every ``every`` steps, from
step 0, each environment's state gets ``copies`` K extra joint copies, drawn by the same policy with
noise of their own (the rollout's noise is left alone), and the file keeps, per state:

* the label: the true J after the step of each copy (:func:`madp.policies.select.oracle_costs`) and J
  before it;
* per robot, what it knows: the critic's window input (:func:`madp.robot.critic.critic_inputs`, from
  its own map and the neighbours it holds), its position, whose positions it holds (from which
  :func:`stored_neighbours` gives the critic's neighbour input), and each copy's action of it;
* per robot, the true mass and centroid of its Voronoi cell now (the quantities the critic predicts);
* per robot, the ``explore`` rule's local cell cost of each copy (and the ``value`` rule's, when a
  map prior is given), the baselines the critic is judged against;
* the motion rule's start and offset, so the true J of any mix of the copies can be computed again
  from the scenario (:func:`world_prefix`).

One ``.npz``, written under a temporary name and renamed, with the settings that made it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from madp.errors import InputError, SettingError
from madp.io.atomic import atomic_path
from madp.io.npz import load_npz
from madp.policies.select import oracle_costs, predictor_of
from madp.robot.prior import value_view
from madp.robot.choice import explore_prior, local_cell_costs, local_views
from madp.robot.critic import critic_inputs, critic_view
from madp.sim import CoverageEnv, SimParams
from madp.sim.rollout import Hook, run
from madp.sim.rules import clip_speed
from madp.sim.voronoi import ColumnPrefix, voronoi_sums
from madp.training.map_prior import _scenario

__all__ = ["CopiesHook", "FORMAT", "collect", "draw_copies", "load_labels", "load_many", "split_envs", "state_record",
           "stored_neighbours", "world_prefix"]

#: Format version of the labels file.
FORMAT = 1
#: The arrays of one state, and the dtype each is stored in.
FIELDS = {"x": np.float16, "actions_mps": np.float64, "j_before": np.float64, "j_after": np.float64,
          "position_m": np.float64, "start_m": np.float64, "offset_m": np.float64, "neighbours": np.bool_,
          "mass": np.float64, "centroid_m": np.float64, "explore_costs": np.float64, "value_costs": np.float64}


def draw_copies(policy, envs: list[CoverageEnv], copies: int, generators: list[torch.Generator]) -> np.ndarray:
    """``[B, K, N, 2]`` (m/s): K = ``copies`` joint samples of each environment's state from MADP's
    ``policy`` (:class:`madp.policies.madp.MADPPolicy`), in one batched call, before any rule keeps
    one; environment b's noise from ``generators[b]``, so the rollout's own noise is untouched."""
    from madp.policies.swarm import swarm_tensors

    with torch.inference_mode():
        obs, pos = swarm_tensors(envs, policy.device)
        shape = (copies, pos.shape[1], policy.model.config.action_dim)
        noise = [policy._noise(g, shape, False) for g in generators]
        first = torch.cat([n[0] for n in noise])
        steps = torch.cat([n[1] for n in noise], dim=1) if policy.stochastic else None
        u = policy._sample(obs, pos, first, steps, envs, copies).numpy()
    u = np.stack([clip_speed(x, envs[0].params.max_speed_mps) for x in u])
    return u.reshape(len(envs), copies, *u.shape[1:])


def state_record(env: CoverageEnv, copies_mps: np.ndarray, map_prior=None) -> dict:
    """One state's arrays (module docstring) for the joint copies ``copies_mps [K, N, 2]``."""
    views = local_views(env)
    per_robot = copies_mps.transpose(1, 0, 2)
    sums = voronoi_sums(env.prefix, env.positions_m, with_cost=False)
    explore = local_cell_costs(explore_prior(env, views), per_robot, env.params)
    value = (local_cell_costs(value_view(env.maps, views, predictor_of(map_prior)), per_robot, env.params) if map_prior is not None
             else np.full_like(explore, np.nan))
    windows, _ = critic_inputs(critic_view(env.maps, views), env.params)  # the neighbours' part: stored_neighbours
    return {"x": windows, "actions_mps": copies_mps, "j_before": env.cost(),
            "j_after": oracle_costs(env, copies_mps), "position_m": env.positions_m.copy(),
            "start_m": env.start_m.copy(), "offset_m": env.offset_m.copy(), "neighbours": env.neighbour_view()[0],
            "mass": sums.mass, "centroid_m": sums.centroid_m, "explore_costs": explore, "value_costs": value}


class CopiesHook(Hook):
    """Every ``every`` steps from step 0, each environment's :func:`state_record` for ``copies`` joint
    copies drawn by ``policy`` with the generators ``generators`` (one per environment), kept in
    ``records`` as ``(step, environment index, record)``."""

    def __init__(self, policy, every: int, copies: int, generators: list[torch.Generator], map_prior=None):
        self.policy, self.every, self.copies, self.generators = policy, every, copies, generators
        self.map_prior, self.records = map_prior, []

    def actions(self, t, envs, actions, act_s):
        if t % self.every == 0:
            drawn = draw_copies(self.policy, envs, self.copies, self.generators)
            for b, env in enumerate(envs):
                self.records.append((t, b, state_record(env, drawn[b], self.map_prior)))


def collect(out: Path, num_envs: int, every: int = 25, steps: int = 600, copies: int = 16, seed: int = 0,
            batch: int = 4, first: int = 0, policy: str | None = None, prior: str | None = None,
            overwrite: bool = False, progress: bool = True) -> dict:
    """Write the labels of ``num_envs`` rollouts (dataset scenarios ``first`` .. ``first + num_envs - 1``
    of ``seed``) to ``out`` (``.npz``); returns its summary. ``prior``: a policy file whose map prior
    gives the ``value`` rule's costs as a baseline (None: they are NaN)."""
    from madp.controllers import make_controller
    from madp.policies import SamplingSettings
    from madp.policies.madp import noise_generator

    out = Path(out)
    if out.suffix != ".npz":
        raise SettingError("out", f"expected a .npz file, got {out}")
    if out.exists() and not overwrite:
        raise SettingError("out", f"{out} exists; pass --overwrite to replace it")
    for name, v, lo in (("num_envs", num_envs, 1), ("every", every, 1), ("steps", steps, 1), ("copies", copies, 2),
                        ("batch", batch, 1), ("first", first, 0)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise SettingError(name, f"expected a whole number >= {lo}, got {v!r}")
    params = SimParams()
    ctrl = make_controller("madp", policy, sampling=SamplingSettings.of())
    map_prior = None
    if prior is not None:
        from madp.policies.checkpoint import load_map_prior

        map_prior = load_map_prior(prior)
        if map_prior is None:
            raise SettingError("prior", f"{prior} carries no map prior (madp value train adds one)")
    parts: dict[str, list] = {k: [] for k in FIELDS}
    env_ids, step_ids = [], []
    t0 = time.perf_counter()
    from rich.progress import Progress

    with Progress(disable=not progress) as bar:
        task = bar.add_task("rollouts", total=num_envs)
        for lo in range(first, first + num_envs, batch):
            idx = list(range(lo, min(first + num_envs, lo + batch)))
            envs = [CoverageEnv(_scenario(seed, i, params)) for i in idx]
            gens = [noise_generator(e.scenario.seed) for e in envs]
            extra = [noise_generator(e.scenario.seed ^ 0xC0FFEE) for e in envs]  # the copies' own noise
            hook = CopiesHook(ctrl, every, copies, extra, map_prior)
            run(envs, lambda es: ctrl.act_batch(es, gens), [hook], steps=steps)
            for t, b, rec in hook.records:
                for k in FIELDS:
                    parts[k].append(np.asarray(rec[k]))
                env_ids.append(idx[b]), step_ids.append(t)
            bar.advance(task, len(idx))
    meta = {"format": FORMAT, "num_envs": num_envs, "first": first, "every": every, "steps": steps, "copies": copies,
            "seed": seed, "policy": str(policy or "shipped"), "prior": prior, "select": ctrl.sampling.select, "candidates": ctrl.sampling.candidates,
            "states": len(env_ids), "seconds": round(time.perf_counter() - t0, 1)}
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".npz") as tmp:
        np.savez(tmp, **{k: np.stack(v).astype(FIELDS[k]) for k, v in parts.items()},
                 env=np.array(env_ids, np.int32), step=np.array(step_ids, np.int32), meta=np.array(json.dumps(meta)))
    return meta


def load_labels(path: Path) -> tuple[dict, dict]:
    """The arrays and settings of a labels file from :func:`collect`; one-line errors for a missing,
    foreign or damaged one."""
    return load_npz(path, (*FIELDS, "env", "step"), "a critic labels file", "madp critic collect", FORMAT,
                    ("x", "actions_mps", "j_after", "mass", "centroid_m"))


def stored_neighbours(data: dict, comm_radius_m: float | None = None) -> np.ndarray:
    """``[S, N, MAX_NEIGHBOURS, 3]`` float32: the critic's neighbour input of every robot of every stored
    state (:func:`madp.robot.critic.neighbour_features`), from the positions and whose each robot holds
    (the simulator without a network: a held position is the true one)."""
    from madp.robot.critic import neighbour_features

    r_c = SimParams().comm_radius_m if comm_radius_m is None else comm_radius_m
    pos, near = data["position_m"], data["neighbours"].copy()
    s, n = near.shape[:2]
    near[:, np.arange(n), np.arange(n)] = False
    offsets = pos[:, None, :, :] - pos[:, :, None, :]  # [S, N, N, 2]: robot j minus robot i
    return neighbour_features(offsets.reshape(s * n, n, 2), near.reshape(s * n, n), r_c).reshape(s, n, -1, 3)


def world_prefix(seed: int, index: int, params: SimParams | None = None) -> ColumnPrefix:
    """The world map's prefix table of dataset scenario ``index`` of ``seed`` (what :func:`collect`
    rolled out), for the true J of any positions (:func:`madp.sim.voronoi.coverage_cost`)."""
    return CoverageEnv(_scenario(seed, index, params or SimParams())).prefix


def load_many(paths) -> tuple[dict, dict]:
    """The labels files ``paths`` (:func:`load_labels`) as one: their states concatenated, the settings
    they share (one-line errors unless they were collected alike, on different environments).

    The files may come from different drivers (one round's states where its own rule drove, the next
    round's where the critic learned from them drove): a label is the true J after a copy's actions,
    whatever policy reached the state. ``policies`` lists each file's driver, in order."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise SettingError("data", "expected at least one labels file")
    loaded = [load_labels(p) for p in paths]
    meta = loaded[0][1]
    same = ("every", "steps", "copies", "seed")
    for p, (_, m) in zip(paths[1:], loaded[1:]):
        if any(m.get(k) != meta.get(k) for k in same):
            raise InputError(f"{p}: collected with other settings than {paths[0]} ({', '.join(same)} must agree)")
    envs = [np.unique(d["env"]) for d, _ in loaded]
    if len(np.unique(np.concatenate(envs))) != sum(len(e) for e in envs):
        raise InputError("the labels files share environments; expected each rollout once")
    data = {k: np.concatenate([d[k] for d, _ in loaded]) for k in loaded[0][0]}
    driver = ("policy", "select", "candidates")
    drivers = [{k: m.get(k) for k in driver} for _, m in loaded]
    shared = {k: v for k, v in meta.items() if k not in driver}
    return data, {**shared, "files": [str(p) for p in paths], "policies": drivers, "states": int(len(data["env"])),
                  "num_envs": int(sum(len(e) for e in envs))}


def split_envs(env: np.ndarray, held_out: float) -> tuple[np.ndarray, np.ndarray]:
    """The environments of ``env`` (one index per state) split into (training, held out): the last
    ``held_out`` share of them, in index order, held out (at least one of each unless ``held_out`` is 0:
    then all train, and other files' environments are the held-out ones)."""
    if isinstance(held_out, bool) or not isinstance(held_out, (int, float)) or not 0.0 <= held_out < 1.0:
        raise SettingError("held_out", f"expected a share in [0, 1), got {held_out!r}")
    envs = np.unique(env)
    if held_out == 0:
        return envs, envs[:0]
    if len(envs) < 2:
        raise SettingError("held_out", f"expected labels of at least 2 environments to hold some out, got {len(envs)}")
    n_held = min(len(envs) - 1, max(1, int(round(len(envs) * held_out))))
    return envs[:-n_held], envs[-n_held:]
