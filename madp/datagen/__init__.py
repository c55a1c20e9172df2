"""Dataset generation: plans shard tasks, runs the clairvoyant expert (or a learner it relabels) in
``sim``, writes through ``data_schema``."""

from .episodes import record_episode, shard_episodes
from .plan import DatagenConfig, ShardTask, make_plan, scenario_seed, split_sizes
from .relabel import learner_settings
from .runner import merge_parts, parse_shards, run_datagen, run_shard

__all__ = ["DatagenConfig", "ShardTask", "learner_settings", "make_plan", "merge_parts", "parse_shards",
           "record_episode", "run_datagen", "run_shard", "scenario_seed", "shard_episodes", "split_sizes"]
