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
:class:`ActionStatsAccumulator` computes them exactly (integer arithmetic), so the result does not
depend on batch sizes, shard order or how parallel workers' partial sums are merged.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import numpy as np

from madp.io.atomic import write_text_atomic

from .schema import ACTIONS_DTYPE, SCHEMA_VERSION, DataError, SampleBatch

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


def sha256_file(path: PathLike, chunk_bytes: int = 8 << 20) -> str:
    """Hex SHA-256 of a file's bytes, read in ``chunk_bytes`` pieces."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while True:
                block = f.read(chunk_bytes)
                if not block:
                    break
                h.update(block)
    except OSError as e:
        raise DataError.at(path, f"cannot read file ({e.strerror or e})") from None
    return h.hexdigest()


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
# action statistics

# A float32 x equals M * 2**E with an integer |M| < 2**24 and E >= -172 (frexp's significand of
# the smallest subnormal 2**-149 is 2**23 * 2**-172). Scaling by 2**_SHIFT makes every value an
# integer, and squares integers after scaling by 2**(2 * _SHIFT).
_SHIFT = 172
# int64 group sums of squares (each < 2**48) are exact for up to 2**15 terms.
_BLOCK = 1 << 15


def _exact_scaled_sums(x: np.ndarray) -> tuple[int, int]:
    """Exact ``(sum(x) * 2**_SHIFT, sum(x**2) * 2**(2*_SHIFT))`` of float32 values as Python ints.

    Values are split into integer significands and exponents with ``np.frexp``, significands are
    summed per exponent in int64 (vectorised), and the per-exponent sums are shifted into Python
    integers. Nothing is rounded, so the result is independent of the order of the values.
    """
    total, total_sq = 0, 0
    x = np.ascontiguousarray(x, dtype=np.float32).ravel()
    for start in range(0, x.size, _BLOCK):
        m, e = np.frexp(x[start : start + _BLOCK].astype(np.float64))
        sig = (m * (1 << 24)).astype(np.int64)  # exact: float32 has a 24-bit significand
        exp = e.astype(np.int64) - 24
        order = np.argsort(exp, kind="stable")
        exp, sig = exp[order], sig[order]
        starts = np.concatenate(([0], np.flatnonzero(np.diff(exp)) + 1))
        sums = np.add.reduceat(sig, starts)
        sums_sq = np.add.reduceat(sig * sig, starts)
        for s, s2, ex in zip(sums.tolist(), sums_sq.tolist(), exp[starts].tolist()):
            total += s << (ex + _SHIFT)
            total_sq += s2 << (2 * (ex + _SHIFT))
    return total, total_sq


def _finite_number(a: Any) -> bool:
    """A JSON number that is finite as a float (an integer beyond float range is not)."""
    if isinstance(a, bool) or not isinstance(a, (int, float)):
        return False
    try:
        return math.isfinite(a)
    except OverflowError:
        return False


@dataclass(frozen=True)
class ActionStats:
    """Per-axis statistics of expert actions U0 (m/s), for normalisation.

    Attributes:
        mean: ``[2]`` mean of (u_x, u_y) in m/s.
        std: ``[2]`` population standard deviation in m/s (may be 0 for degenerate data;
            consumers dividing by it must guard).
        count: number of action vectors (samples × robots) the statistics cover.
    """

    mean: tuple[float, float]
    std: tuple[float, float]
    count: int

    def to_dict(self) -> dict:
        return {"count": self.count, "mean": list(self.mean), "std": list(self.std)}

    @staticmethod
    def from_dict(d: Any, where: str = "action_stats") -> "ActionStats":
        if not isinstance(d, Mapping) or set(d) != {"count", "mean", "std"}:
            raise DataError.at(where, "expected an object with keys count, mean, std")
        vecs = []
        for key in ("mean", "std"):
            v = d[key]
            if (
                not isinstance(v, list)
                or len(v) != 2
                or not all(_finite_number(a) for a in v)
            ):
                raise DataError.at(f"{where}.{key}", "expected a list of 2 finite numbers")
            vecs.append(tuple(float(a) for a in v))
        if any(s < 0 for s in vecs[1]):
            raise DataError.at(f"{where}.std", "expected non-negative values")
        count = d["count"]
        if not isinstance(count, int) or isinstance(count, bool) or count <= 0:
            raise DataError.at(f"{where}.count", "expected a positive integer")
        return ActionStats(mean=vecs[0], std=vecs[1], count=count)  # type: ignore[arg-type]


class ActionStatsAccumulator:
    """Exact, order-independent accumulation of per-axis action mean and std.

    Feed it actions ``[..., 2]`` float32 (e.g. ``batch.actions`` of every train batch) with
    :meth:`add` / :meth:`add_batch`, merge partial accumulators from parallel workers with
    :meth:`merge` (or ship them as JSON with :meth:`state` / :meth:`from_state`), and read the
    result with :meth:`result`. Sums are kept as exact integers, so identical sets of samples give
    bit-identical statistics whatever the order or batching.
    """

    NUM_AXES = 2

    def __init__(self) -> None:
        self.count = 0
        self._sum = [0] * self.NUM_AXES  # sum(u) * 2**_SHIFT per axis
        self._sum_sq = [0] * self.NUM_AXES  # sum(u**2) * 2**(2*_SHIFT) per axis

    def add(self, actions: np.ndarray) -> "ActionStatsAccumulator":
        """Accumulate an array of actions ``[..., 2]`` float32 (finite). Returns ``self``."""
        if not isinstance(actions, np.ndarray) or actions.dtype != ACTIONS_DTYPE or actions.shape[-1:] != (2,):
            got = f"{actions.dtype.name} {list(actions.shape)}" if isinstance(actions, np.ndarray) else type(actions).__name__
            raise DataError.at("actions", f"expected a float32 array [..., 2], got {got}")
        flat = actions.reshape(-1, self.NUM_AXES)
        if not np.isfinite(flat).all():
            raise DataError.at("actions", "expected finite values, found NaN/inf")
        for axis in range(self.NUM_AXES):
            s, s2 = _exact_scaled_sums(flat[:, axis])
            self._sum[axis] += s
            self._sum_sq[axis] += s2
        self.count += flat.shape[0]
        return self

    def add_batch(self, batch: SampleBatch) -> "ActionStatsAccumulator":
        """Accumulate the actions of every robot of every sample of ``batch``."""
        return self.add(batch.actions)

    def merge(self, other: "ActionStatsAccumulator") -> "ActionStatsAccumulator":
        """Add another accumulator's sums into this one (exact). Returns ``self``."""
        self.count += other.count
        for axis in range(self.NUM_AXES):
            self._sum[axis] += other._sum[axis]
            self._sum_sq[axis] += other._sum_sq[axis]
        return self

    def state(self) -> dict:
        """JSON-able exact state (big integers as decimal strings)."""
        return {"count": self.count, "sum": [str(v) for v in self._sum], "sum_sq": [str(v) for v in self._sum_sq]}

    @classmethod
    def from_state(cls, state: Mapping) -> "ActionStatsAccumulator":
        """Inverse of :meth:`state`."""
        acc = cls()
        try:
            acc.count = int(state["count"])
            acc._sum = [int(v) for v in state["sum"]]
            acc._sum_sq = [int(v) for v in state["sum_sq"]]
        except (KeyError, TypeError, ValueError) as e:
            raise DataError.at("action stats state", f"expected count, sum, sum_sq ({e})") from None
        if len(acc._sum) != cls.NUM_AXES or len(acc._sum_sq) != cls.NUM_AXES or acc.count < 0:
            raise DataError.at("action stats state", "expected 2 axes and a non-negative count")
        return acc

    def result(self) -> ActionStats:
        """Mean and population std per axis, each correctly rounded from the exact sums."""
        if self.count == 0:
            raise DataError.at("action_stats", "no actions accumulated (is the train split empty?)")
        n = self.count
        scale = 1 << _SHIFT
        means, stds = [], []
        for axis in range(self.NUM_AXES):
            s, q = self._sum[axis], self._sum_sq[axis]
            means.append(float(Fraction(s, n * scale)))
            var = Fraction(n * q - s * s, n * n * scale * scale)  # exact, >= 0
            stds.append(math.sqrt(float(var)))
        return ActionStats(mean=(means[0], means[1]), std=(stds[0], stds[1]), count=n)


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
    "ActionStats",
    "ActionStatsAccumulator",
    "FORMATS",
    "MANIFEST_FILENAME",
    "Manifest",
    "SPLITS",
    "ShardInfo",
    "SplitInfo",
    "dumps_canonical",
    "sha256_file",
]
