"""The dataset manifest: ``manifest.json`` beside the shards, describing what they hold.

Layout (keys sorted, 2-space indent, trailing newline — the bytes are a pure function of the
content)::

    {
      "action_stats": {"count": 2240000, "mean": [mx, my], "std": [sx, sy]},   # or null
      "code_version": "0.1.0",
      "created_by": "madp datagen --n 100000 ...",
      "format": "mcap",                       # or "parquet"
      "num_robots": 32,
      "params": {...},                        # free dict of generation parameters
      "schema_version": 1,
      "splits": {
        "train": {"num_episodes": 170, "num_samples": 70000,
                  "shards": [{"bytes": ..., "file": "train/shard-00000.mcap",
                              "num_episodes": ..., "num_samples": ..., "sha256": "..."}]},
        "val": {...}, "test": {...}
      }
    }

``file`` is relative to the manifest's directory with ``/`` separators. ``action_stats`` are the
per-axis mean and (population) standard deviation of U0 in m/s over every robot of every sample of
the train split; they normalise actions for training and travel inside every checkpoint.
:class:`~madp.data_schema.action_stats.ActionStatsAccumulator` computes them exactly.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import numpy as np

from madp.io.atomic import write_text_atomic
from madp.io.checksum import sha256_file

from .action_stats import ActionStats
from .schema import SCHEMA_VERSION, DataError

#: File name of the manifest inside a dataset directory.
MANIFEST_FILENAME = "manifest.json"
#: Shard encodings a manifest may declare.
FORMATS = ("mcap", "parquet")
#: The dataset splits, split by episode (SPEC §3).
SPLITS = ("train", "val", "test")

PathLike = Union[str, os.PathLike]


def _code_version() -> str:
    from madp import __version__

    return __version__


def _jsonable(value: Any) -> Any:
    """Convert numpy scalars/arrays and tuples inside ``value`` to plain JSON types."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def dumps_canonical(obj: Any) -> str:
    """Deterministic JSON text: sorted keys, 2-space indent, no NaN/inf, trailing newline."""
    return json.dumps(_jsonable(obj), indent=2, sort_keys=True, allow_nan=False) + "\n"


# --------------------------------------------------------------------------------------------
# manifest


def _req(d: Mapping, key: str, kind: Union[type, tuple], where: str) -> Any:
    if key not in d:
        raise DataError.at(where, f"missing key '{key}'")
    v = d[key]
    if not isinstance(v, kind) or (isinstance(v, bool) and kind is not bool):
        name = kind.__name__ if isinstance(kind, type) else "/".join(k.__name__ for k in kind)
        raise DataError.at(f"{where}.{key}", f"expected {name}, got {type(v).__name__}")
    return v


@dataclass
class ShardInfo:
    """One shard file: where it is and what it holds.

    Attributes:
        file: path relative to the manifest's directory, ``/``-separated.
        num_samples: samples in the shard.
        num_episodes: whole episodes in the shard.
        sha256: hex SHA-256 of the file's bytes.
        bytes: file size in bytes.
    """

    file: str
    num_samples: int
    num_episodes: int
    sha256: str
    bytes: int

    def to_dict(self) -> dict:
        return {
            "bytes": self.bytes,
            "file": self.file,
            "num_episodes": self.num_episodes,
            "num_samples": self.num_samples,
            "sha256": self.sha256,
        }

    @staticmethod
    def from_dict(d: Any, where: str) -> "ShardInfo":
        if not isinstance(d, Mapping):
            raise DataError.at(where, "expected an object")
        extra = set(d) - {"bytes", "file", "num_episodes", "num_samples", "sha256"}
        if extra:
            raise DataError.at(where, f"unexpected keys {sorted(extra)}")
        info = ShardInfo(
            file=_req(d, "file", str, where),
            num_samples=_req(d, "num_samples", int, where),
            num_episodes=_req(d, "num_episodes", int, where),
            sha256=_req(d, "sha256", str, where),
            bytes=_req(d, "bytes", int, where),
        )
        if min(info.num_samples, info.num_episodes, info.bytes) < 0:
            raise DataError.at(where, "expected non-negative counts and size")
        if len(info.sha256) != 64 or any(c not in "0123456789abcdef" for c in info.sha256):
            raise DataError.at(f"{where}.sha256", "expected 64 lowercase hex digits")
        if not info.file or info.file.startswith("/") or "\\" in info.file or ".." in info.file.split("/"):
            raise DataError.at(f"{where}.file", f"expected a relative '/'-separated path inside the dataset, got {info.file!r}")
        return info


@dataclass
class SplitInfo:
    """The shards of one split; counts are derived from them."""

    shards: list[ShardInfo] = field(default_factory=list)

    @property
    def num_samples(self) -> int:
        return sum(s.num_samples for s in self.shards)

    @property
    def num_episodes(self) -> int:
        return sum(s.num_episodes for s in self.shards)

    def to_dict(self) -> dict:
        return {
            "num_episodes": self.num_episodes,
            "num_samples": self.num_samples,
            "shards": [s.to_dict() for s in self.shards],
        }

    @staticmethod
    def from_dict(d: Any, where: str) -> "SplitInfo":
        if not isinstance(d, Mapping):
            raise DataError.at(where, "expected an object")
        extra = set(d) - {"num_episodes", "num_samples", "shards"}
        if extra:
            raise DataError.at(where, f"unexpected keys {sorted(extra)}")
        shards = _req(d, "shards", list, where)
        split = SplitInfo([ShardInfo.from_dict(s, f"{where}.shards[{i}]") for i, s in enumerate(shards)])
        for key in ("num_samples", "num_episodes"):
            stated = _req(d, key, int, where)
            if stated != getattr(split, key):
                raise DataError.at(f"{where}.{key}", f"is {stated}, expected {getattr(split, key)} (sum over its shards)")
        return split


@dataclass
class Manifest:
    """A dataset's manifest (see the module docstring for the JSON layout).

    Attributes:
        format: ``"mcap"`` or ``"parquet"``.
        num_robots: N, fixed within the dataset.
        params: free dict of generation parameters (JSON-able; numpy scalars are converted).
        splits: split name → :class:`SplitInfo`; ``train``, ``val`` and ``test`` by default.
        action_stats: normalisation statistics over the train split, or ``None`` until computed.
        created_by: the command line that created the dataset.
        schema_version: sample schema version (must equal :data:`SCHEMA_VERSION` to load).
        code_version: ``madp.__version__`` of the writer.
    """

    format: str
    num_robots: int
    params: dict = field(default_factory=dict)
    splits: dict[str, SplitInfo] = field(default_factory=lambda: {s: SplitInfo() for s in SPLITS})
    action_stats: Optional[ActionStats] = None
    created_by: str = ""
    schema_version: int = SCHEMA_VERSION
    code_version: str = field(default_factory=_code_version)

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise DataError.at("manifest.format", f"expected one of {list(FORMATS)}, got {self.format!r}")
        if not isinstance(self.num_robots, int) or isinstance(self.num_robots, bool) or self.num_robots <= 0:
            raise DataError.at("manifest.num_robots", f"expected a positive integer, got {self.num_robots!r}")

    # ---- derived
    @property
    def num_samples(self) -> int:
        """Samples over all splits."""
        return sum(s.num_samples for s in self.splits.values())

    def counts(self) -> dict[str, int]:
        """Samples per split."""
        return {name: split.num_samples for name, split in self.splits.items()}

    def shard_paths(self, split: str, root: PathLike) -> list[Path]:
        """Absolute paths of ``split``'s shards, given the dataset directory ``root``."""
        if split not in self.splits:
            raise DataError.at("manifest.splits", f"no split named {split!r} (have {sorted(self.splits)})")
        return [Path(root) / s.file for s in self.splits[split].shards]

    # ---- serialisation
    def to_dict(self) -> dict:
        return {
            "action_stats": None if self.action_stats is None else self.action_stats.to_dict(),
            "code_version": self.code_version,
            "created_by": self.created_by,
            "format": self.format,
            "num_robots": self.num_robots,
            "params": _jsonable(self.params),
            "schema_version": self.schema_version,
            "splits": {name: split.to_dict() for name, split in self.splits.items()},
        }

    def to_json(self) -> str:
        """Canonical JSON text (deterministic bytes for identical content)."""
        try:
            return dumps_canonical(self.to_dict())
        except (TypeError, ValueError) as e:
            raise DataError.at("manifest.params", f"expected JSON-serialisable finite values ({e})") from None

    @staticmethod
    def from_dict(d: Any, source: str = MANIFEST_FILENAME) -> "Manifest":
        """Validate and build a manifest from parsed JSON; errors name ``source``."""
        if not isinstance(d, Mapping):
            raise DataError.at(source, "expected a JSON object")
        version = d.get("schema_version")
        if version != SCHEMA_VERSION:
            raise DataError.at(source, f"schema_version is {version!r}, expected {SCHEMA_VERSION}")
        known = {"action_stats", "code_version", "created_by", "format", "num_robots", "params", "schema_version", "splits"}
        extra = set(d) - known
        if extra:
            raise DataError.at(source, f"unexpected keys {sorted(extra)}")
        fmt = _req(d, "format", str, source)
        if fmt not in FORMATS:
            raise DataError.at(f"{source}: format", f"expected one of {list(FORMATS)}, got {fmt!r}")
        splits_d = _req(d, "splits", dict, source)
        splits = {name: SplitInfo.from_dict(v, f"{source}: splits.{name}") for name, v in splits_d.items()}
        stats_d = d.get("action_stats")
        stats = None if stats_d is None else ActionStats.from_dict(stats_d, f"{source}: action_stats")
        num_robots = _req(d, "num_robots", int, source)
        if num_robots <= 0:
            raise DataError.at(f"{source}: num_robots", f"expected a positive integer, got {num_robots}")
        params = dict(_req(d, "params", dict, source))
        try:
            dumps_canonical(params)
        except (TypeError, ValueError):  # NaN or Infinity, which json.loads accepts
            raise DataError.at(f"{source}: params", "expected finite JSON values") from None
        return Manifest(
            format=fmt,
            num_robots=num_robots,
            params=params,
            splits=splits,
            action_stats=stats,
            created_by=_req(d, "created_by", str, source),
            schema_version=version,
            code_version=_req(d, "code_version", str, source),
        )

    def save(self, path: PathLike) -> Path:
        """Write the canonical JSON atomically (``manifest.json.<pid>.tmp``, fsync, rename). ``path`` may be the
        dataset directory, in which case ``manifest.json`` inside it is written."""
        p = Path(path)
        if p.is_dir():
            p = p / MANIFEST_FILENAME
        return write_text_atomic(p, self.to_json())

    @staticmethod
    def load(path: PathLike) -> "Manifest":
        """Read and validate a manifest (``path`` may be the dataset directory)."""
        p = Path(path)
        if p.is_dir():
            p = p / MANIFEST_FILENAME
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as e:
            raise DataError.at(p, f"cannot read manifest ({e.strerror or e})") from None
        except UnicodeDecodeError as e:
            raise DataError.at(p, f"not UTF-8 text (byte {e.start}); expected a JSON manifest") from None
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise DataError.at(p, f"invalid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
        return Manifest.from_dict(d, source=str(p))

    def verify_shards(self, root: PathLike, check_sha256: bool = True) -> None:
        """Check every shard exists with the recorded size (and SHA-256); raise :class:`DataError`."""
        for name, split in self.splits.items():
            for shard in split.shards:
                p = Path(root) / shard.file
                try:
                    size = p.stat().st_size
                except OSError:
                    raise DataError.at(p, f"shard of split '{name}' is missing") from None
                if size != shard.bytes:
                    raise DataError.at(p, f"size is {size} bytes, expected {shard.bytes} (manifest)")
                if check_sha256:
                    digest = sha256_file(p)
                    if digest != shard.sha256:
                        raise DataError.at(p, f"sha256 is {digest}, expected {shard.sha256} (manifest)")


__all__ = [
    "FORMATS",
    "MANIFEST_FILENAME",
    "Manifest",
    "SPLITS",
    "ShardInfo",
    "SplitInfo",
    "dumps_canonical",
]
