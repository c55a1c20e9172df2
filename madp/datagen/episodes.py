"""Run the clairvoyant expert (or a learner it relabels, :mod:`.relabel`) on one scenario and record
samples (U0, X, O)."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Iterator

import numpy as np

from madp.data_schema import Episode
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario
from madp.sim.launch import draw_launch
from madp.sim.rollout import Hook, act_alone, run

from .plan import DatagenConfig, ShardTask, episode_id, scenario_seed
from .relabel import learner_driver

class EpisodeRecorder(Hook):
    """The rollout hook (:mod:`madp.sim.rollout`) of :func:`record_episode`: records a sample at every
    ``record_every``-th step and at the last one, and ends the rollout there (see :func:`record_episode`)."""

    def __init__(self, expert: ClairvoyantCVT, cfg: DatagenConfig, max_samples: int, stops_when_converged: bool,
                 on_sample: Callable[[], None] | None = None):
        self.expert, self.cfg, self.max_samples, self.on_sample = expert, cfg, max_samples, on_sample
        self.stops_when_converged = stops_when_converged
        self.acts, self.pos, self.obs, self.goals, self.steps = [], [], [], [], []

    def actions(self, t, envs, actions, act_s):
        env, u = envs[0], actions[0]
        last = (self.stops_when_converged and not u.any()) or t >= self.cfg.max_steps
        if t % self.cfg.record_every == 0 or last:
            self.acts.append(u.astype(np.float32))
            self.pos.append(env.positions_m.astype(np.float32))
            self.obs.append(env.observations().astype(np.float16))
            self.goals.append(self.expert.goals_m.astype(np.float32))
            self.steps.append(t)
            if self.on_sample is not None:
                self.on_sample()
        return last or len(self.steps) >= self.max_samples

    def episode(self, episode_id: int, scenario_seed: int, world_map: np.ndarray) -> Episode:
        """What was recorded, as the :class:`madp.data_schema.Episode` ``episode_id``."""
        return Episode(
            episode_id=episode_id,
            scenario_seed=int(scenario_seed),
            actions=np.stack(self.acts),
            positions=np.stack(self.pos),
            observations=np.stack(self.obs),
            steps=np.asarray(self.steps, dtype=np.int64),
            world_map=world_map,
            goals=np.stack(self.goals),
        )


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
    recorder = EpisodeRecorder(expert, cfg, max_samples, driver is None, on_sample)
    drive = None if driver is None else (lambda envs, u: [driver(envs[0], u[0])])
    run([env], act_alone(expert), [recorder], drive=drive)
    return recorder.episode(ep_id, scenario.seed, env.world_map_f32)


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
