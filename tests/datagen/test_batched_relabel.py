"""Relabelling with a MADP policy runs a shard's episodes as a batch in lockstep: the same episodes as
one after another (up to the float rounding of the policy's batched actions), the same bytes every run."""

import numpy as np
import pytest

from madp.data_schema import write_shard
from madp.datagen.episodes import BATCH_EPISODES, full_episode_samples, shard_episodes
from madp.datagen.plan import DatagenConfig, ShardTask, episode_id, scenario_seed
from madp.datagen.relabel import batches, learner_settings
from madp.policies import shipped_checkpoint
from tests.conftest import one_torch_thread
from tests.datagen.test_relabel import PARAMS

MAX_STEPS = 12  # t = 0, 5, 10, 12: 4 samples per episode


def config(beta: float) -> DatagenConfig:
    return DatagenConfig(100, seed=3, samples_per_shard=22, max_steps=MAX_STEPS, params=PARAMS,
                         policy=learner_settings(shipped_checkpoint("madp"), beta))


def test_only_madp_policies_batch():
    assert batches(learner_settings(shipped_checkpoint("madp")))
    assert not batches(learner_settings(shipped_checkpoint("lpac"))) and not batches({})
    assert BATCH_EPISODES > 1


@pytest.mark.parametrize("beta", [0.0, 0.4])
def test_batched_episodes_are_the_lone_episodes(beta):
    """5 episodes in batches of 3 ([0, 1, 2], [3, 4]; episode 4 cut at the 2 samples left) equal the
    episodes run one after another: the coin draws and each episode's noise stream are its own."""
    cfg = config(beta)
    per = full_episode_samples(cfg)
    task = ShardTask("train", 0, 4 * per + 2)
    with one_torch_thread():
        lone = list(shard_episodes(cfg, task, batch=1))
        batched = list(shard_episodes(cfg, task, batch=3))
    assert per == 4 and [e.num_steps for e in lone] == [4, 4, 4, 4, 2] == [e.num_steps for e in batched]
    for k, (a, b) in enumerate(zip(lone, batched)):
        assert (a.episode_id, a.scenario_seed) == (b.episode_id, b.scenario_seed) == (
            episode_id("train", 0, k), scenario_seed(3, "train", 0, k))
        np.testing.assert_array_equal(a.steps, b.steps)
        np.testing.assert_allclose(b.actions, a.actions, atol=1e-4)
        np.testing.assert_allclose(b.positions, a.positions, atol=1e-4)
        np.testing.assert_allclose(b.goals, a.goals, atol=1e-3)
        np.testing.assert_allclose(b.observations.astype(np.float32), a.observations.astype(np.float32), atol=1e-2)
        np.testing.assert_array_equal(b.world_map, a.world_map)
    assert list(batched[0].steps) == [0, 5, 10, 12] and list(batched[-1].steps) == [0, 5]


def test_the_last_episode_stops_at_the_budget_and_the_batch_runs_on():
    """A budget that ends mid-episode: the last episode holds exactly the samples left, and the
    episodes batched with it still run the whole horizon."""
    cfg = config(0.4)
    per = full_episode_samples(cfg)
    with one_torch_thread():
        eps = list(shard_episodes(cfg, ShardTask("val", 1, 2 * per + 3)))  # one batch of 3
    assert [e.num_steps for e in eps] == [per, per, 3] and sum(e.num_steps for e in eps) == 2 * per + 3
    assert [list(e.steps) for e in eps] == [[0, 5, 10, 12], [0, 5, 10, 12], [0, 5, 10]]
    assert [e.episode_id for e in eps] == [episode_id("val", 1, k) for k in range(3)]


def test_batched_shards_are_deterministic(tmp_path):
    cfg = config(0.4)
    task = ShardTask("train", 0, 2 * full_episode_samples(cfg) + 1)
    with one_torch_thread():
        for name in ("a", "b"):
            write_shard(tmp_path / f"{name}.mcap", shard_episodes(cfg, task), "mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
