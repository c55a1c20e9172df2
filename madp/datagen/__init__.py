"""Dataset generation: plans shard tasks, runs the clairvoyant expert in ``sim``, writes through
``data_schema``."""

from .episodes import record_episode, shard_episodes
from .plan import DatagenConfig, ShardTask, make_plan, scenario_seed, split_sizes
from .runner import merge_parts, run_datagen, run_shard

__all__ = ["DatagenConfig", "ShardTask", "make_plan", "merge_parts", "record_episode", "run_datagen",
           "run_shard", "scenario_seed", "shard_episodes", "split_sizes"]
