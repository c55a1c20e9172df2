"""One facade over both shard encodings: write atomically, stream batches, count, inspect, convert.

The format is inferred from the suffix (``.mcap`` or ``.parquet``); an explicit ``fmt`` must agree
with it, so a shard can always be read back by name alone.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Optional, Union

from madp.io.atomic import named, temp_path
from madp.io.checksum import sha256_file

from . import mcap_codec, parquet_codec
from .manifest import FORMATS, ShardInfo
from .schema import SCHEMA_VERSION, DataError, Episode, SampleBatch, iter_episodes

PathLike = Union[str, os.PathLike]

#: File suffix → format name.
SUFFIXES = {".mcap": "mcap", ".parquet": "parquet"}
#: Default number of samples per yielded batch.
DEFAULT_BATCH_SIZE = 256


@dataclass(frozen=True)
class ShardHeader:
    """What a shard declares about itself, read from its footer/summary without decoding samples."""

    format: str
    schema_version: int
    num_robots: int
    num_samples: int
    num_episodes: int


def shard_format(path: PathLike, fmt: Optional[str] = None) -> str:
    """The format of ``path`` from its suffix; ``fmt``, if given, must match it."""
    suffix = Path(path).suffix.lower()
    inferred = SUFFIXES.get(suffix)
    if inferred is None:
        raise DataError.at(path, f"unknown shard suffix {suffix!r}, expected one of {sorted(SUFFIXES)}")
    if fmt is not None and fmt != inferred:
        if fmt not in FORMATS:
            raise DataError.at(path, f"unknown format {fmt!r}, expected one of {list(FORMATS)}")
        raise DataError.at(path, f"format {fmt!r} does not match the file suffix {suffix!r}")
    return inferred


def write_shard(path: PathLike, episodes: Iterable[Episode], fmt: Optional[str] = None, **options) -> ShardInfo:
    """Write whole ``episodes`` as one shard, atomically (``path.<pid>.tmp``, fsync, ``os.replace``).

    Args:
        path: destination; its suffix (``.mcap``/``.parquet``) selects the encoding.
        episodes: the episodes, in order (an iterator is consumed once, streaming).
        fmt: optional explicit format, must agree with the suffix.
        **options: passed to the codec (``visualize``, ``step_seconds``, ``chunk_bytes`` for MCAP;
            ``row_group_samples`` for Parquet).

    Returns:
        A :class:`ShardInfo` (``file`` is the file name; make it relative to the dataset root
        before adding it to a manifest) with ``num_samples``, ``num_episodes``, ``sha256``, ``bytes``.
    """
    fmt = shard_format(path, fmt)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(path)
    writer = mcap_codec.write_mcap_shard if fmt == "mcap" else parquet_codec.write_parquet_shard
    try:
        num_samples, num_episodes = writer(tmp, episodes, **options)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(e, OSError):  # a full disk: say which shard
            raise named(e, path) from None
        raise
    return ShardInfo(
        file=path.name,
        num_samples=num_samples,
        num_episodes=num_episodes,
        sha256=sha256_file(path),
        bytes=path.stat().st_size,
    )


def check_shard(path: PathLike, expected: ShardInfo, fmt: Optional[str] = None, num_robots: Optional[int] = None,
                copy_to: Optional[PathLike] = None, chunk_bytes: int = 8 << 20) -> None:
    """Check a shard against its manifest entry (or shard record) before it is used.

    Size and SHA-256 are computed in one streamed read (which also copies the bytes to ``copy_to``,
    if given, so a checked copy costs no second read); then the sample and episode counts (and N,
    if ``num_robots`` is given) that the shard's footer declares must match. Raises
    :class:`DataError` naming the file.
    """
    fmt = shard_format(path, fmt)
    h, size = hashlib.sha256(), 0
    try:
        with open(path, "rb") as f, (open(copy_to, "wb") if copy_to is not None else _NoSink()) as out:
            while block := f.read(chunk_bytes):
                h.update(block)
                out.write(block)
                size += len(block)
            if copy_to is not None:
                out.flush()
                os.fsync(out.fileno())
    except FileNotFoundError:
        raise DataError.at(path, "shard is missing (listed in the manifest)") from None
    except IsADirectoryError:
        raise DataError.at(path, "is a directory, expected a shard file") from None
    if size != expected.bytes:
        raise DataError.at(path, f"size is {size} bytes, expected {expected.bytes} (manifest)")
    if h.hexdigest() != expected.sha256:
        raise DataError.at(path, f"sha256 is {h.hexdigest()}, expected {expected.sha256} (manifest)")
    head = inspect_shard(path, fmt)
    if (head.num_samples, head.num_episodes) != (expected.num_samples, expected.num_episodes):
        raise DataError.at(path, f"holds {head.num_samples} samples in {head.num_episodes} episodes, manifest says "
                                 f"{expected.num_samples} in {expected.num_episodes}")
    if num_robots is not None and head.num_robots != num_robots:
        raise DataError.at(path, f"holds {head.num_robots} robots per sample, manifest says {num_robots}")


class _NoSink:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def write(self, block: bytes) -> None:
        pass


def iter_shard(
    path: PathLike, fmt: Optional[str] = None, batch_size: int = DEFAULT_BATCH_SIZE, verify_crc: bool = True
) -> Iterator[SampleBatch]:
    """Stream a shard's samples as :class:`SampleBatch` es of up to ``batch_size`` samples.

    Batches follow the file order (episodes whole and in order, steps increasing) and own their
    arrays. Raises :class:`DataError` naming the file on any schema/version/corruption problem.
    ``verify_crc`` checks the encodings' CRCs (MCAP chunks, Parquet pages) while reading.
    """
    fmt = shard_format(path, fmt)
    if fmt == "mcap":
        return mcap_codec.read_mcap_shard(path, batch_size=batch_size, verify_crc=verify_crc)
    return parquet_codec.read_parquet_shard(path, batch_size=batch_size, verify_crc=verify_crc)


def read_shard(path: PathLike, fmt: Optional[str] = None) -> SampleBatch:
    """All samples of a shard in one batch (loads the whole shard into memory)."""
    batches = list(iter_shard(path, fmt))
    if not batches:
        raise DataError.at(path, "shard holds no samples")
    return batches[0] if len(batches) == 1 else SampleBatch.concat(batches)


def inspect_shard(path: PathLike, fmt: Optional[str] = None) -> ShardHeader:
    """Schema version, N and counts of a shard from its metadata only (fast, no sample decoding)."""
    fmt = shard_format(path, fmt)
    if fmt == "mcap":
        info = mcap_codec.read_mcap_info(path)
        return ShardHeader("mcap", info.schema_version, info.num_robots, info.num_samples, info.num_episodes)
    num_robots, num_samples, num_episodes = parquet_codec.read_parquet_info(path)
    return ShardHeader("parquet", SCHEMA_VERSION, num_robots, num_samples, num_episodes)


def count_samples(path: PathLike, fmt: Optional[str] = None) -> int:
    """Number of samples in a shard, from its metadata (fast)."""
    return inspect_shard(path, fmt).num_samples


def iter_shard_episodes(path: PathLike, fmt: Optional[str] = None) -> Iterator[Episode]:
    """A shard's samples regrouped into :class:`Episode` objects (no visualisation extras)."""
    return iter_episodes(iter_shard(path, fmt), where=str(path))


def convert_shard(src: PathLike, dst: PathLike, **options) -> ShardInfo:
    """Re-encode shard ``src`` as ``dst`` (formats from the suffixes), streaming episode by episode.

    Samples are preserved bit for bit; MCAP visualisation extras that are not part of a sample
    (world map, goals) are not carried over.
    """
    return write_shard(dst, iter_shard_episodes(src), **options)


__all__ = [
    "DEFAULT_BATCH_SIZE",
    "SUFFIXES",
    "ShardHeader",
    "check_shard",
    "convert_shard",
    "count_samples",
    "inspect_shard",
    "iter_shard",
    "iter_shard_episodes",
    "read_shard",
    "shard_format",
    "write_shard",
]
