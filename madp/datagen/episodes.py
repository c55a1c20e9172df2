"""Run the clairvoyant expert (with DART noise on what it executes, :func:`dart_driver`, or a learner
it relabels, :mod:`.relabel`) on one scenario and record samples (U0, X, O).

A shard's episodes run one after another, except with a MADP policy to relabel: then
:func:`shard_episodes` runs them in batches of :data:`BATCH_EPISODES` in lockstep
(:func:`record_batch`), the policy called once per step for the whole batch. Each episode is the one
it would be alone, up to the float rounding of the policy's batched actions; the batches are a fixed
function of the shard, so a shard's bytes do not depend on the machine or the number of workers."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Iterator

import numpy as np

from madp.data_schema import Episode
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario
from madp.sim.launch import draw_launch
from madp.sim.rollout import Hook, act_alone, for_each_env, run
from madp.sim.rules import clip_speed

from .plan import DatagenConfig, ShardTask, episode_id, scenario_seed
from .relabel import batches, learner_batch_driver, learner_driver

#: Episodes of a relabelling shard that run in lockstep (:func:`record_batch`), on every machine
#: alike: the rounding of the policy's batched actions, and so the bytes, depend on it.
BATCH_EPISODES = 8
#: The tag of an episode's DART noise stream (:func:`dart_driver`); its launch stream's is 0x1A.
DART_STREAM = 0xDA27


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
    takes over each step with probability beta; or, with ``cfg.dart_sigma_mps``, the swarm executes
    the expert's action plus noise: :func:`dart_driver`); every sample is labelled with the expert's
    noiseless action. A step is recorded when t % record_every == 0, and once more at the end — the
    state where the expert converged (all its actions zero; expert rollouts, DART's included) or the
    last step t = max_steps — unless that step was just recorded. Under DART noise the expert's
    labels are the convergence signal still: the noise keeps pushing robots off their goals, so such
    an episode seldom converges and mostly runs to max_steps, recording states around the expert's
    path up to its end. Recording stops after ``max_samples`` samples. Each sample holds the expert's
    action U0 at X_t, the positions X_t and the observations O_t (float16).
    """
    env = CoverageEnv(scenario)
    expert = ClairvoyantCVT()
    driver = learner_driver(cfg.policy, scenario.seed) if cfg.policy else None
    recorder = EpisodeRecorder(expert, cfg, max_samples, driver is None, on_sample)
    if driver is not None:
        drive = lambda envs, u: [driver(envs[0], u[0])]  # noqa: E731
    elif cfg.dart_sigma_mps:
        drive = dart_driver(cfg.dart_sigma_mps, scenario.seed)
    else:
        drive = None
    run([env], act_alone(expert), [recorder], drive=drive)
    return recorder.episode(ep_id, scenario.seed, env.world_map_f32)


def dart_driver(sigma_mps: float, seed: int) -> Callable[[list[CoverageEnv], np.ndarray], np.ndarray]:
    """What a DART expert rollout executes (the ``drive`` of :func:`madp.sim.rollout.run`):
    ``drive(envs, u [B, N, 2]) -> u + noise``, the noise N(0, sigma_mps²) m/s per robot and axis,
    then every speed clipped to u_max (:func:`madp.sim.rules.clip_speed`). The noise is drawn at every
    step, in one draw, from the episode's own stream ``default_rng([seed, DART_STREAM])`` of its
    scenario seed ``seed``, so it depends on nothing else (not the worker, not a resumed run)."""
    rng = np.random.default_rng([seed, DART_STREAM])

    def drive(envs: list[CoverageEnv], u: np.ndarray) -> np.ndarray:
        noisy_mps = u + sigma_mps * rng.standard_normal(np.shape(u))
        return clip_speed(noisy_mps, envs[0].params.max_speed_mps)

    return drive


def episode_scenario(cfg: DatagenConfig, seed: int) -> Scenario:
    """The scenario of a dataset episode: :meth:`Scenario.random` of its seed, the swarm then moved to
    a start of ``cfg.launch`` drawn from the seed's second stream (uniform: unchanged)."""
    scenario = Scenario.random(seed, cfg.params)
    if cfg.launch == "uniform":
        return scenario
    rng = np.random.default_rng([seed, 0x1A])
    return replace(scenario, robots_m=draw_launch(rng, cfg.launch, cfg.params.num_robots, cfg.params.world_size))


def full_episode_samples(cfg: DatagenConfig) -> int:
    """The samples of an episode that runs all ``max_steps`` steps (every relabelling episode, unless a
    shard's budget cuts it): t = 0, r, 2r, ... and t = max_steps (r = ``record_every``)."""
    return cfg.max_steps // cfg.record_every + 1 + int(cfg.max_steps % cfg.record_every != 0)


class LockstepRecorder(Hook):
    """The rollout hook of :func:`record_batch`: one :class:`EpisodeRecorder` per environment, each
    shown its own environment's steps until it ends its episode (``live``: the episodes not ended,
    in order); ends the rollout when every episode has ended."""

    def __init__(self, recorders: list[EpisodeRecorder]):
        self.recorders = recorders
        self.live = list(range(len(recorders)))

    def actions(self, t, envs, actions, act_s):
        self.live = [b for b in self.live if not self.recorders[b].actions(t, [envs[b]], actions[b:b + 1], act_s)]
        return not self.live


def _expert_action(env: CoverageEnv, expert: ClairvoyantCVT) -> np.ndarray:
    return expert(env)


def record_batch(
    scenarios: list[Scenario],
    cfg: DatagenConfig,
    ep_ids: list[int],
    max_samples: list[int],
    on_sample: Callable[[], None] | None = None,
) -> list[Episode]:
    """:func:`record_episode` of B relabelling episodes (``cfg.policy`` a MADP policy:
    :func:`madp.datagen.relabel.batches`) run in lockstep: episode b of ``scenarios[b]``, id
    ``ep_ids[b]``, at most ``max_samples[b]`` samples. At every step the expert labels each episode
    still running and :func:`madp.datagen.relabel.learner_batch_driver` moves them (the policy
    called once for the episodes whose draw chose it); an episode that reaches its ``max_samples``
    stops recording (its swarm is no longer driven by the learner) while the others run on, and the
    rollout ends when every episode has ended. Each episode is the one :func:`record_episode` would
    record, up to the float rounding of the policy's batched actions."""
    envs = [CoverageEnv(s) for s in scenarios]
    experts = [ClairvoyantCVT() for _ in scenarios]
    lockstep = LockstepRecorder([EpisodeRecorder(e, cfg, m, False, on_sample) for e, m in zip(experts, max_samples)])
    driver = learner_batch_driver(cfg.policy, [s.seed for s in scenarios])

    def act(envs: list[CoverageEnv]) -> np.ndarray:
        u = np.zeros((len(envs), envs[0].num_robots, 2))
        live = lockstep.live
        u[live] = for_each_env(_expert_action, [envs[b] for b in live], [experts[b] for b in live])
        return u

    run(envs, act, [lockstep], drive=lambda envs, u: driver(envs, u, lockstep.live))
    return [rec.episode(i, s.seed, env.world_map_f32)
            for rec, i, s, env in zip(lockstep.recorders, ep_ids, scenarios, envs)]


def shard_episodes(
    cfg: DatagenConfig, task: ShardTask, on_sample: Callable[[], None] | None = None, batch: int = BATCH_EPISODES
) -> Iterator[Episode]:
    """The episodes of one shard task, exactly ``task.num_samples`` samples in all: episode k of
    scenario seed :func:`scenario_seed` (..., k) and id :func:`episode_id` (..., k), k = 0, 1, ...,
    each cut where the shard is full. With a MADP policy to relabel they run in batches of ``batch``
    (:func:`record_batch`: every episode runs all ``max_steps`` steps, the last one cut at the
    samples left); otherwise, or with ``batch`` 1, one after another (:func:`record_episode`)."""
    if cfg.policy and batches(cfg.policy) and batch > 1:
        yield from _batched_shard_episodes(cfg, task, on_sample, batch)
        return
    remaining, k = task.num_samples, 0
    while remaining > 0:
        seed = scenario_seed(cfg.seed, task.split, task.index, k)
        ep = record_episode(episode_scenario(cfg, seed), cfg, episode_id(task.split, task.index, k),
                            remaining, on_sample)
        remaining -= ep.num_steps
        k += 1
        yield ep


def _batched_shard_episodes(cfg: DatagenConfig, task: ShardTask, on_sample: Callable[[], None] | None,
                            batch: int) -> Iterator[Episode]:
    full, rest = divmod(task.num_samples, full_episode_samples(cfg))
    budgets = [full_episode_samples(cfg)] * full + ([rest] if rest else [])
    for first in range(0, len(budgets), batch):
        ks = range(first, min(first + batch, len(budgets)))
        scenarios = [episode_scenario(cfg, scenario_seed(cfg.seed, task.split, task.index, k)) for k in ks]
        yield from record_batch(scenarios, cfg, [episode_id(task.split, task.index, k) for k in ks],
                                [budgets[k] for k in ks], on_sample)
