"""Training: streams shards (``data_schema``) into the models (``models``); checkpoints, resume, DDP."""

from .checkpoint import load_policy, save_checkpoint
from .config import PRESET_DEFAULTS, TrainConfig, resolve
from .stream import ShardStream, StreamPosition, stream_plan
from .trainer import Trainer, train

__all__ = ["PRESET_DEFAULTS", "ShardStream", "StreamPosition", "TrainConfig", "Trainer", "load_policy", "resolve",
           "save_checkpoint", "stream_plan", "train"]
