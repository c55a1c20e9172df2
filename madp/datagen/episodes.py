"""Run the clairvoyant expert on one scenario and record samples (U0, X, O)."""

from __future__ import annotations

from typing import Callable, Iterator

import numpy as np

from madp.data_schema import Episode
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario

from .plan import DatagenConfig, ShardTask, episode_id, scenario_seed


def record_episode(
    scenario: Scenario,
    cfg: DatagenConfig,
    ep_id: int,
    max_samples: int,
    on_sample: Callable[[], None] | None = None,
) -> Episode:
    """One clairvoyant rollout, recording every ``record_every``-th step.

    A step is recorded when t % record_every == 0, and once more at the end — the state where the
    expert converged (all actions zero) or the last step t = max_steps — unless that step was just
    recorded. Recording stops after ``max_samples`` samples. Each sample holds the expert's action
    U0 at X_t, the positions X_t and the observations O_t (float16).
    """
    env = CoverageEnv(scenario)
    expert = ClairvoyantCVT()
    acts, pos, obs, goals, steps = [], [], [], [], []
    t = 0
    while len(steps) < max_samples:
        u = expert(env)
        last = not u.any() or t >= cfg.max_steps
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
        env.step(u)
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


def shard_episodes(
    cfg: DatagenConfig, task: ShardTask, on_sample: Callable[[], None] | None = None
) -> Iterator[Episode]:
    """The episodes of one shard task, exactly ``task.num_samples`` samples in all."""
    remaining, k = task.num_samples, 0
    while remaining > 0:
        seed = scenario_seed(cfg.seed, task.split, task.index, k)
        ep = record_episode(Scenario.random(seed, cfg.params), cfg, episode_id(task.split, task.index, k),
                            remaining, on_sample)
        remaining -= ep.num_steps
        k += 1
        yield ep
