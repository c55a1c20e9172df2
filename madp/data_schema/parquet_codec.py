"""Parquet encoding of samples: one row per sample, zstd, small row groups for streaming.

Columns (all non-nullable):

=================  ===========================================  ====================================
column             Arrow type                                   content
=================  ===========================================  ====================================
``episode_id``     int64
``step``           int64                                        simulation step
``scenario_seed``  int64
``actions``        fixed_size_list<float32>[2N]                 U0 [N, 2] row-major, m/s
``positions``      fixed_size_list<float32>[2N]                 X [N, 2] row-major, m
``observations``   fixed_size_binary[N·4·32·32·2]               O [N, 4, 32, 32] float16 little-endian
                                                                bytes, C order
=================  ===========================================  ====================================

Schema metadata (key ``madp``, JSON) carries ``schema_version``, ``num_robots`` and each column's
per-sample ``shape`` and ``dtype``; after the last row group the writer adds ``madp.num_samples``
and ``madp.num_episodes`` to the footer. Row groups hold :data:`ROW_GROUP_SAMPLES` samples (the
last one fewer) whatever the batching of the input, and the writer uses no timestamps, so identical
input gives identical bytes. Data pages carry CRC checksums, which the reader verifies; the footer
(Thrift metadata) has none in the Parquet format, and the reader only checks that it parses and
declares the expected schema — the manifest's SHA-256 is the end-to-end guard.

The files are plain Parquet: pyarrow, pandas and DuckDB read them (DuckDB sees ``actions`` as
``FLOAT[]`` and ``observations`` as ``BLOB``).
"""

from __future__ import annotations

import json
import os
from typing import Iterable, Iterator, Optional, Union

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .schema import (
    ACTIONS_DTYPE,
    INDEX_DTYPE,
    OBS_CHANNELS,
    OBS_SHAPE,
    OBSERVATIONS_DTYPE,
    POSITIONS_DTYPE,
    SCHEMA_VERSION,
    DataError,
    Episode,
    SampleBatch,
    sample_shapes,
)

PathLike = Union[str, os.PathLike]

#: Samples per row group (≈ 64 MiB of float16 observations for N = 32 before compression).
ROW_GROUP_SAMPLES = 256
#: zstd level for every column.
ZSTD_LEVEL = 3
#: Schema-metadata key holding the JSON description.
METADATA_KEY = b"madp"
#: Default number of samples per batch yielded by the reader.
DEFAULT_BATCH_SIZE = 256

_INDEX_COLUMNS = ("episode_id", "step", "scenario_seed")


def arrow_schema(num_robots: int) -> pa.Schema:
    """The Arrow schema of a shard with ``num_robots`` robots, including its ``madp`` metadata."""
    shapes = sample_shapes(num_robots)
    obs_bytes = int(np.prod(shapes["observations"])) * OBSERVATIONS_DTYPE.itemsize
    meta = {
        "schema_version": SCHEMA_VERSION,
        "num_robots": num_robots,
        "columns": {
            "actions": {"dtype": "float32", "shape": list(shapes["actions"]), "unit": "m/s"},
            "positions": {"dtype": "float32", "shape": list(shapes["positions"]), "unit": "m"},
            "observations": {
                "dtype": "float16",
                "shape": list(shapes["observations"]),
                "encoding": "little-endian C-order bytes",
                "channels": list(OBS_CHANNELS),
            },
        },
    }
    return pa.schema(
        [
            pa.field("episode_id", pa.int64(), nullable=False),
            pa.field("step", pa.int64(), nullable=False),
            pa.field("scenario_seed", pa.int64(), nullable=False),
            pa.field("actions", pa.list_(pa.field("item", pa.float32(), nullable=False), 2 * num_robots), nullable=False),
            pa.field("positions", pa.list_(pa.field("item", pa.float32(), nullable=False), 2 * num_robots), nullable=False),
            pa.field("observations", pa.binary(obs_bytes), nullable=False),
        ],
        metadata={METADATA_KEY: json.dumps(meta, sort_keys=True).encode()},
    )


def _batch_to_table(batch: SampleBatch, schema: pa.Schema) -> pa.Table:
    """Arrow table of ``batch`` (zero-copy over the numpy buffers)."""
    b, n = len(batch), batch.num_robots
    obs = np.ascontiguousarray(batch.observations, dtype=OBSERVATIONS_DTYPE)
    obs_width = schema.field("observations").type.byte_width
    columns = [
        pa.array(batch.episode_id, pa.int64()),
        pa.array(batch.step, pa.int64()),
        pa.array(batch.scenario_seed, pa.int64()),
        pa.FixedSizeListArray.from_arrays(
            pa.array(np.ascontiguousarray(batch.actions, ACTIONS_DTYPE).reshape(-1)), type=schema.field("actions").type
        ),
        pa.FixedSizeListArray.from_arrays(
            pa.array(np.ascontiguousarray(batch.positions, POSITIONS_DTYPE).reshape(-1)), type=schema.field("positions").type
        ),
        pa.Array.from_buffers(pa.binary(obs_width), b, [None, pa.py_buffer(obs.reshape(-1).view(np.uint8))]),
    ]
    return pa.Table.from_arrays(columns, schema=schema)


def write_parquet_shard(
    path: PathLike,
    episodes: Iterable[Episode],
    *,
    row_group_samples: int = ROW_GROUP_SAMPLES,
) -> tuple[int, int]:
    """Write ``episodes`` (streamed, in order) as one Parquet shard at ``path``.

    Samples are buffered until a full row group of ``row_group_samples`` is available, so the
    layout does not depend on episode lengths. The extras ``world_map``/``goals`` are not stored.

    Returns:
        ``(num_samples, num_episodes)``.
    """
    if row_group_samples <= 0:
        raise DataError.at(path, f"row_group_samples must be positive, got {row_group_samples}")
    writer: Optional[pq.ParquetWriter] = None
    schema: Optional[pa.Schema] = None
    pending: list[SampleBatch] = []
    pending_len = 0
    num_robots = 0
    num_samples = num_episodes = 0

    def write_rows(final: bool) -> None:
        nonlocal pending, pending_len
        while pending_len >= row_group_samples or (final and pending_len):
            merged = pending[0] if len(pending) == 1 else SampleBatch.concat(pending)
            take = min(row_group_samples, len(merged))
            writer.write_table(_batch_to_table(merged.slice(0, take), schema), row_group_size=row_group_samples)
            rest = merged.slice(take, len(merged))
            pending = [rest] if len(rest) else []
            pending_len = len(rest)

    try:
        for ep in episodes:
            if not isinstance(ep, Episode):
                raise DataError.at(path, f"expected Episode objects to write, got {type(ep).__name__}")
            if schema is None:
                schema = arrow_schema(ep.num_robots)
                writer = pq.ParquetWriter(
                    path,
                    schema,
                    compression="zstd",
                    compression_level=ZSTD_LEVEL,
                    use_dictionary=False,
                    write_statistics=list(_INDEX_COLUMNS),
                    write_page_checksum=True,
                    store_schema=True,
                    version="2.6",
                )
                num_robots = ep.num_robots
            elif ep.num_robots != num_robots:
                raise DataError.at(path, f"episode {ep.episode_id} has {ep.num_robots} robots, expected {num_robots} like the shard's first episode")
            pending.append(ep.to_batch())
            pending_len += ep.num_steps
            num_samples += ep.num_steps
            num_episodes += 1
            write_rows(final=False)
        if writer is None:
            raise DataError.at(path, "expected at least one episode to write")
        write_rows(final=True)
        writer.add_key_value_metadata({"madp.num_samples": str(num_samples), "madp.num_episodes": str(num_episodes)})
    finally:
        if writer is not None:
            writer.close()
    return num_samples, num_episodes


# --------------------------------------------------------------------------------------------
# reading


def _corrupt(path: PathLike, err: BaseException) -> DataError:
    return DataError.corrupt(path, "Parquet", err)


def _open(path: PathLike, verify_crc: bool = True) -> tuple[pq.ParquetFile, int]:
    """Open a shard, check its madp metadata and columns; return (file, num_robots)."""
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
        pf = pq.ParquetFile(path, page_checksum_verification=verify_crc)
    except FileNotFoundError:
        raise DataError.at(path, "shard not found") from None
    except Exception as e:  # ArrowInvalid, OSError, ...
        raise _corrupt(path, e) from None
    if magic != b"PAR1":
        pf.close()
        raise DataError.at(path, "corrupt Parquet shard (bad leading magic bytes)")
    meta = pf.schema_arrow.metadata or {}
    if METADATA_KEY not in meta:
        raise DataError.at(path, "no 'madp' schema metadata, expected a madp sample shard")
    try:
        info = json.loads(meta[METADATA_KEY])
        version = info.get("schema_version")
        num_robots = int(info["num_robots"])
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise DataError.at(path, f"unreadable 'madp' schema metadata ({type(e).__name__}: {e})") from None
    if version != SCHEMA_VERSION:
        raise DataError.at(path, f"schema_version is {version}, expected {SCHEMA_VERSION}")
    expected = arrow_schema(num_robots)
    if not pf.schema_arrow.remove_metadata().equals(expected.remove_metadata()):
        raise DataError.at(path, f"columns are {pf.schema_arrow.remove_metadata()}, expected {expected.remove_metadata()}")
    return pf, num_robots


def _record_batch_to_samples(rb: pa.RecordBatch, num_robots: int) -> SampleBatch:
    """Decode a record batch into a :class:`SampleBatch` of owned, writable numpy arrays."""
    b = rb.num_rows
    shapes = sample_shapes(num_robots)
    cols = {name: rb.column(name) for name in rb.schema.names}
    for name, col in cols.items():
        if col.null_count:
            raise DataError.at(name, f"expected no nulls, found {col.null_count}")
    out = {name: cols[name].to_numpy().astype(INDEX_DTYPE, copy=True) for name in _INDEX_COLUMNS}
    for name, dtype in (("actions", ACTIONS_DTYPE), ("positions", POSITIONS_DTYPE)):
        flat = cols[name].flatten().to_numpy(zero_copy_only=True)
        out[name] = np.array(flat, dtype=dtype, copy=True).reshape(b, *shapes[name])
    obs_col = cols["observations"]
    width = obs_col.type.byte_width
    data = obs_col.buffers()[1]
    raw = np.frombuffer(data, dtype=np.uint8, count=b * width, offset=obs_col.offset * width)
    out["observations"] = raw.view(OBSERVATIONS_DTYPE).reshape(b, num_robots, *OBS_SHAPE).copy()
    return SampleBatch(**out)


def read_parquet_shard(path: PathLike, batch_size: int = DEFAULT_BATCH_SIZE, verify_crc: bool = True) -> Iterator[SampleBatch]:
    """Stream the samples of a Parquet shard as :class:`SampleBatch` es of up to ``batch_size``.

    Reads one row group at a time (page CRCs verified unless ``verify_crc=False``). Every yielded
    batch owns fresh, writable arrays. Raises :class:`DataError` naming the file for another
    schema version, other columns, or a truncated/corrupt file.
    """
    if batch_size <= 0:
        raise DataError.at(path, f"batch_size must be positive, got {batch_size}")
    pf, num_robots = _open(path, verify_crc)
    try:
        for rb in pf.iter_batches(batch_size=batch_size, use_threads=False):
            try:
                yield _record_batch_to_samples(rb, num_robots)
            except DataError as e:
                raise DataError.at(path, str(e)) from None
    except DataError:
        raise
    except Exception as e:  # ArrowInvalid, OSError (checksum/zstd), ...
        raise _corrupt(path, e) from None
    finally:
        pf.close()


def read_parquet_info(path: PathLike) -> tuple[int, int, int]:
    """``(num_robots, num_samples, num_episodes)`` of a shard from its footer (no data decoded)."""
    pf, num_robots = _open(path)
    try:
        kv = pf.metadata.metadata or {}
        num_samples = pf.metadata.num_rows
        if b"madp.num_episodes" in kv:
            num_episodes = int(kv[b"madp.num_episodes"])
        else:
            ids = pf.read(columns=["episode_id"]).column(0).to_numpy()
            num_episodes = int(np.count_nonzero(np.diff(ids)) + 1) if ids.size else 0
        return num_robots, num_samples, num_episodes
    finally:
        pf.close()


__all__ = [
    "METADATA_KEY",
    "ROW_GROUP_SAMPLES",
    "ZSTD_LEVEL",
    "arrow_schema",
    "read_parquet_info",
    "read_parquet_shard",
    "write_parquet_shard",
]
