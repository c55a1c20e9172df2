"""What a sample, an episode and a dataset manifest are, and their MCAP and Parquet encodings.

Public API::

    SCHEMA_VERSION, DataError, Episode, SampleBatch, iter_episodes
    Manifest, ShardInfo, SplitInfo, ActionStats, ActionStatsAccumulator
    write_shard(path, episodes, fmt=None, **options) -> ShardInfo
    check_shard(path, shard_info) — size, sha256 (one streamed read) and counts before use
    iter_shard(path, fmt=None, batch_size=256) -> Iterator[SampleBatch]
    read_shard, count_samples, inspect_shard, iter_shard_episodes, convert_shard
    read_mcap_shard / write_mcap_shard, read_parquet_shard / write_parquet_shard

This layer knows nothing of how samples are made (``sim``/``datagen``) or used (``training``).
The benchmark lives in :mod:`madp.data_schema.bench` (``bench_io``).
"""

from .action_stats import ActionStats, ActionStatsAccumulator
from .manifest import (
    FORMATS,
    MANIFEST_FILENAME,
    SPLITS,
    Manifest,
    ShardInfo,
    SplitInfo,
)
from .mcap_codec import SAMPLE_TOPIC, McapShardInfo, read_mcap_info, read_mcap_shard, write_mcap_shard
from .parquet_codec import read_parquet_info, read_parquet_shard, write_parquet_shard
from .schema import (
    DEFAULT_NUM_ROBOTS,
    OBS_CHANNELS,
    OBS_SHAPE,
    SCHEMA_VERSION,
    DataError,
    Episode,
    SampleBatch,
    iter_episodes,
    sample_shapes,
)
from .shard_io import (
    ShardHeader,
    check_shard,
    convert_shard,
    count_samples,
    inspect_shard,
    iter_shard,
    iter_shard_episodes,
    read_shard,
    shard_format,
    write_shard,
)

__all__ = [
    "ActionStats",
    "ActionStatsAccumulator",
    "DEFAULT_NUM_ROBOTS",
    "DataError",
    "Episode",
    "FORMATS",
    "MANIFEST_FILENAME",
    "Manifest",
    "McapShardInfo",
    "OBS_CHANNELS",
    "OBS_SHAPE",
    "SAMPLE_TOPIC",
    "SCHEMA_VERSION",
    "SPLITS",
    "SampleBatch",
    "ShardHeader",
    "ShardInfo",
    "SplitInfo",
    "check_shard",
    "convert_shard",
    "count_samples",
    "inspect_shard",
    "iter_episodes",
    "iter_shard",
    "iter_shard_episodes",
    "read_mcap_info",
    "read_mcap_shard",
    "read_parquet_info",
    "read_parquet_shard",
    "read_shard",
    "sample_shapes",
    "shard_format",
    "write_mcap_shard",
    "write_parquet_shard",
    "write_shard",
]
