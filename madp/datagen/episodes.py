"""Run the clairvoyant expert on one scenario and record samples (U0, X, O)."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Iterator

import numpy as np

from madp.data_schema import Episode
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario
from madp.sim.launch import draw_launch

from .plan import DatagenConfig, ShardTask, episode_id, scenario_seed

_POLICIES: dict = {}  # (path, sha256) -> loaded policy, once per process


def learner_driver(policy: dict, seed: int) -> Callable[[CoverageEnv, np.ndarray], np.ndarray]:
    """What moves the swarm in a relabelling rollout: ``driver(env, expert_u) -> u`` executes the
    expert's action with probability beta (one draw per step) and the learned policy's otherwise.

    The policy's noise and the draws are seeded by the scenario seed, and torch runs on one thread
    here, so a shard's bytes do not depend on which process makes it or how many there are."""
    import torch

    from madp.data_schema.manifest import sha256_file
    from madp.policies import LPACPolicy, MADPPolicy, load

    key = (policy["path"], policy["sha256"])
    if key not in _POLICIES:
        if sha256_file(policy["path"]) != policy["sha256"]:
            raise ValueError(f"{policy['path']}: changed since this dataset's plan was made (sha256 differs)")
        model, _ = load(policy["path"], policy["kind"])
        _POLICIES[key] = MADPPolicy(model) if policy["kind"] == "madp" else LPACPolicy(model)
    learner = _POLICIES[key]
    if hasattr(learner, "reset"):
        learner.reset(seed)
    coin = np.random.default_rng([seed & 0xFFFFFFFF, seed >> 32, 0xDA66E])
    beta = float(policy["beta"])

    def drive(env: CoverageEnv, expert_u: np.ndarray) -> np.ndarray:
        if coin.random() < beta:
            return expert_u
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return learner(env)
        finally:
            torch.set_num_threads(threads)

    return drive


def record_episode(
    scenario: Scenario,
    cfg: DatagenConfig,
    ep_id: int,
    max_samples: int,
    on_sample: Callable[[], None] | None = None,
) -> Episode:
    """One rollout, recording every ``record_every``-th step.

    The clairvoyant expert drives (or, with ``cfg.policy``, the learned policy drives and the expert
    takes over each step with probability beta); every sample is labelled with the expert's action.
    A step is recorded when t % record_every == 0, and once more at the end — the state where the
    expert converged (all actions zero; expert rollouts only) or the last step t = max_steps —
    unless that step was just recorded. Recording stops after ``max_samples`` samples. Each sample
    holds the expert's action U0 at X_t, the positions X_t and the observations O_t (float16).
    """
    env = CoverageEnv(scenario)
    expert = ClairvoyantCVT()
    driver = learner_driver(cfg.policy, scenario.seed) if cfg.policy else None
    acts, pos, obs, goals, steps = [], [], [], [], []
    t = 0
    while len(steps) < max_samples:
        u = expert(env)
        last = (driver is None and not u.any()) or t >= cfg.max_steps
        if t % cfg.record_every == 0 or last:
            acts.append(u.astype(np.float32))
            pos.append(env.positions_m.astype(np.float32))
            obs.append(env.observations().astype(np.float16))
            goals.append(expert.goals_m.astype(np.float32))
            steps.append(t)
            if on_sample is not None:
                on_sample()
        if last:
            break
        env.step(u if driver is None else driver(env, u))
        t += 1
    return Episode(
        episode_id=ep_id,
        scenario_seed=int(scenario.seed),
        actions=np.stack(acts),
        positions=np.stack(pos),
        observations=np.stack(obs),
        steps=np.asarray(steps, dtype=np.int64),
        world_map=env.world_map_f32,
        goals=np.stack(goals),
    )


def episode_scenario(cfg: DatagenConfig, seed: int) -> Scenario:
    """The scenario of a dataset episode: :meth:`Scenario.random` of its seed, the swarm then moved to
    a start of ``cfg.launch`` drawn from the seed's second stream (uniform: unchanged)."""
    scenario = Scenario.random(seed, cfg.params)
    if cfg.launch == "uniform":
        return scenario
    rng = np.random.default_rng([seed, 0x1A])
    return replace(scenario, robots_m=draw_launch(rng, cfg.launch, cfg.params.num_robots, cfg.params.world_size))


def shard_episodes(
    cfg: DatagenConfig, task: ShardTask, on_sample: Callable[[], None] | None = None
) -> Iterator[Episode]:
    """The episodes of one shard task, exactly ``task.num_samples`` samples in all."""
    remaining, k = task.num_samples, 0
    while remaining > 0:
        seed = scenario_seed(cfg.seed, task.split, task.index, k)
        ep = record_episode(episode_scenario(cfg, seed), cfg, episode_id(task.split, task.index, k),
                            remaining, on_sample)
        remaining -= ep.num_steps
        k += 1
        yield ep
