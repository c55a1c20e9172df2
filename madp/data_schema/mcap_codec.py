"""MCAP encoding of samples: one shard = one MCAP file holding whole episodes.

Layout of a shard:

* topic ``/madp/sample`` — one ``madp.Sample`` protobuf message per sample (schema embedded as a
  ``FileDescriptorSet``, see ``sample_proto.py``); channel metadata ``schema_version``.
* visualisation topics ``/world/map``, ``/robots``, ``/expert/goals``, ``/expert/actions`` with
  Foxglove's well-known schemas (see ``foxglove_viz.py``), unless ``visualize=False``.
* a metadata record ``madp`` with ``schema_version``, ``num_robots``, ``num_samples``,
  ``num_episodes``, ``step_seconds``, ``sample_topic`` and ``code_version``.

Message ``log_time`` is simulated time, never wall clock: episode ``k`` starts at
``start_k`` ns and its record of step ``s`` is logged at ``start_k + s * step_seconds``;
``start_0 = 0`` and ``start_{k+1} = start_k + (last_step_k + 1) * step_seconds + 1 s``. Together with
fixed chunking (zstd, :data:`CHUNK_BYTES`) this makes the file bytes a pure function of the input.

The reader validates the footer and summary first (a truncated file fails before any sample is
returned; the summary CRC is checked), then streams the file once, checking chunk CRCs and the
data-section CRC — so every byte of the file is covered — decoding only ``/madp/sample`` messages
into preallocated numpy batches with ``np.frombuffer``. Any failure of
the mcap/protobuf/zstd layers becomes a one-line :class:`DataError` naming the file.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass
from typing import Iterable, Iterator, Optional, Union

import numpy as np
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, IndexType, Writer

from . import sample_proto
from .schema import (
    ACTIONS_DTYPE,
    OBSERVATIONS_DTYPE,
    POSITIONS_DTYPE,
    SCHEMA_VERSION,
    DataError,
    Episode,
    SampleBatch,
    sample_shapes,
)

PathLike = Union[str, os.PathLike]

#: Topic of the sample messages.
SAMPLE_TOPIC = "/madp/sample"
#: Name of the shard's metadata record.
METADATA_NAME = "madp"
#: Simulation step, s (SPEC §2); default spacing of log times.
STEP_SECONDS = 0.2
#: Gap between consecutive episodes on the shard's timeline, ns.
EPISODE_GAP_NS = 1_000_000_000
#: Uncompressed chunk size target, bytes (≈ 15 samples of 32 robots per chunk).
CHUNK_BYTES = 4 << 20
#: Default number of samples per batch yielded by the reader.
DEFAULT_BATCH_SIZE = 256


def _library_id() -> str:
    from mcap.writer import __version__ as mcap_version

    from madp import __version__

    return f"madp {__version__}; mcap-python {mcap_version}"


def start_writer(f, chunk_bytes: int) -> Writer:
    """A started MCAP writer with the project's settings: zstd chunks, full indexes and summary,
    CRCs everywhere, and no wall-clock field, so identical messages give identical bytes."""
    writer = Writer(
        f,
        chunk_size=chunk_bytes,
        compression=CompressionType.ZSTD,
        index_types=IndexType.ALL,
        repeat_channels=True,
        repeat_schemas=True,
        use_chunking=True,
        use_statistics=True,
        use_summary_offsets=True,
        enable_crcs=True,
        enable_data_crcs=True,
    )
    writer.start(profile="", library=_library_id())
    return writer


@dataclass(frozen=True)
class McapShardInfo:
    """What a shard's summary and metadata say about it (read without decoding samples)."""

    schema_version: int
    num_robots: int
    num_samples: int
    num_episodes: int
    step_seconds: float


# --------------------------------------------------------------------------------------------
# writing


def write_mcap_shard(
    path: PathLike,
    episodes: Iterable[Episode],
    *,
    step_seconds: float = STEP_SECONDS,
    visualize: bool = True,
    chunk_bytes: int = CHUNK_BYTES,
) -> tuple[int, int]:
    """Write ``episodes`` (streamed, in order) as one MCAP shard at ``path``.

    Args:
        path: output file (written in place; :func:`madp.data_schema.write_shard` adds the atomic
            ``.<pid>.tmp`` + rename).
        episodes: whole episodes, all with the same number of robots N.
        step_seconds: simulated seconds per step for log times (0.2 s).
        visualize: also write the Foxglove topics (``/world/map`` when an episode has a
            ``world_map``, ``/expert/goals`` when it has ``goals``, ``/robots`` and
            ``/expert/actions`` always).
        chunk_bytes: uncompressed MCAP chunk size target.

    Returns:
        ``(num_samples, num_episodes)``.
    """
    step_ns = int(round(step_seconds * 1e9))
    if step_ns <= 0:
        raise DataError.at(path, f"step_seconds must be positive, got {step_seconds}")
    with open(path, "wb") as f:
        writer = start_writer(f, chunk_bytes)
        sample_schema = writer.register_schema(
            name=sample_proto.SAMPLE_SCHEMA_NAME, encoding=SchemaEncoding.Protobuf, data=sample_proto.FILE_DESCRIPTOR_SET
        )
        sample_channel = writer.register_channel(
            topic=SAMPLE_TOPIC,
            message_encoding=MessageEncoding.Protobuf,
            schema_id=sample_schema,
            metadata={"schema_version": str(SCHEMA_VERSION)},
        )
        viz_channels: dict[str, int] = {}
        if visualize:
            from . import foxglove_viz as viz

            schema_ids: dict[str, int] = {}
            for topic, (name, encoding, data) in viz.schemas().items():
                if name not in schema_ids:
                    schema_ids[name] = writer.register_schema(name=name, encoding=encoding, data=data)
                viz_channels[topic] = writer.register_channel(
                    topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_ids[name]
                )
        sequences = {ch: 0 for ch in [sample_channel, *viz_channels.values()]}

        def emit(channel: int, log_time: int, data: bytes) -> None:
            writer.add_message(channel_id=channel, log_time=log_time, data=data, publish_time=log_time, sequence=sequences[channel])
            sequences[channel] += 1

        num_robots: Optional[int] = None
        num_samples = num_episodes = 0
        episode_start_ns = 0
        for ep in episodes:
            if not isinstance(ep, Episode):
                raise DataError.at(path, f"expected Episode objects to write, got {type(ep).__name__}")
            if num_robots is None:
                num_robots = ep.num_robots
            elif ep.num_robots != num_robots:
                raise DataError.at(path, f"episode {ep.episode_id} has {ep.num_robots} robots, expected {num_robots} like the shard's first episode")
            times = episode_start_ns + ep.steps * step_ns
            if visualize and ep.world_map is not None:
                emit(viz_channels[viz.TOPIC_MAP], int(times[0]), viz.grid_message(ep.world_map, int(times[0])))
            for t in range(ep.num_steps):
                log_time = int(times[t])
                msg = sample_proto.Sample(
                    schema_version=SCHEMA_VERSION,
                    episode_id=ep.episode_id,
                    step=int(ep.steps[t]),
                    scenario_seed=ep.scenario_seed,
                )
                sample_proto.tensor_from_numpy(msg.actions, ep.actions[t])
                sample_proto.tensor_from_numpy(msg.positions, ep.positions[t])
                sample_proto.tensor_from_numpy(msg.observations, ep.observations[t])
                emit(sample_channel, log_time, msg.SerializeToString())
                if visualize:
                    emit(viz_channels[viz.TOPIC_ROBOTS], log_time, viz.robots_message(ep.positions[t], log_time))
                    emit(viz_channels[viz.TOPIC_ACTIONS], log_time, viz.actions_message(ep.positions[t], ep.actions[t], log_time))
                    if ep.goals is not None:
                        emit(viz_channels[viz.TOPIC_GOALS], log_time, viz.goals_message(ep.positions[t], ep.goals[t], log_time))
            num_samples += ep.num_steps
            num_episodes += 1
            episode_start_ns = int(times[-1]) + step_ns + EPISODE_GAP_NS
        if num_robots is None:
            raise DataError.at(path, "expected at least one episode to write")
        from madp import __version__

        writer.add_metadata(
            METADATA_NAME,
            {
                "code_version": __version__,
                "num_episodes": str(num_episodes),
                "num_robots": str(num_robots),
                "num_samples": str(num_samples),
                "sample_topic": SAMPLE_TOPIC,
                "schema_version": str(SCHEMA_VERSION),
                "step_seconds": repr(float(step_seconds)),
            },
        )
        writer.finish()
    return num_samples, num_episodes


# --------------------------------------------------------------------------------------------
# reading


def _corrupt(path: PathLike, err: BaseException) -> DataError:
    return DataError.corrupt(path, "MCAP", err)


# Footer record (opcode, length, summary_start, summary_offset_start, summary_crc) + magic.
_FOOTER = struct.Struct("<BQQQI")
_MAGIC_SIZE = 8


def _check_summary_crc(f, path: PathLike) -> None:
    """Verify the footer's summary CRC (all bytes from the summary start through the footer's
    summary_offset_start field). The mcap library does not check it; together with the chunk and
    data-section CRCs it makes every byte of the file checked."""
    size = f.seek(0, os.SEEK_END)
    if size < _MAGIC_SIZE * 2 + _FOOTER.size:
        raise DataError.at(path, f"corrupt or truncated MCAP shard (only {size} bytes)")
    f.seek(size - _MAGIC_SIZE - _FOOTER.size)
    opcode, length, summary_start, _, summary_crc = _FOOTER.unpack(f.read(_FOOTER.size))
    if opcode != Opcode.FOOTER or length != _FOOTER.size - 9 or summary_start > size:
        raise DataError.at(path, "corrupt or truncated MCAP shard (no valid footer at the end)")
    if summary_crc == 0 or summary_start == 0:
        return
    f.seek(summary_start)
    covered = f.read(size - _MAGIC_SIZE - 4 - summary_start)
    if zlib.crc32(covered) != summary_crc:
        raise DataError.at(path, "corrupt MCAP shard (summary section CRC mismatch)")


def _open_summary(f, path: PathLike, verify_crc: bool = True) -> tuple[McapShardInfo, int]:
    """Validate footer, summary, metadata and sample channel; return (info, sample channel id)."""
    try:
        if verify_crc:
            _check_summary_crc(f, path)
        f.seek(0)
        reader = SeekingReader(f, validate_crcs=verify_crc)
        summary = reader.get_summary()
        meta = None
        if summary is not None:
            for record in reader.iter_metadata():
                if record.name == METADATA_NAME:
                    meta = dict(record.metadata)
    except DataError:
        raise
    except Exception as e:  # mcap raises McapError, struct.error, EndOfFile, ValueError, ...
        raise _corrupt(path, e) from None
    if summary is None or summary.statistics is None:
        raise DataError.at(path, "MCAP shard has no summary section, expected one written by madp")
    if meta is None:
        raise DataError.at(path, f"no '{METADATA_NAME}' metadata record, expected a madp sample shard")
    try:
        version = int(meta.get("schema_version", "-1"))
        num_robots = int(meta["num_robots"])
        num_samples = int(meta["num_samples"])
        num_episodes = int(meta["num_episodes"])
        step_seconds = float(meta["step_seconds"])
    except (KeyError, ValueError) as e:
        raise DataError.at(path, f"'{METADATA_NAME}' metadata is incomplete ({type(e).__name__}: {e})") from None
    if version != SCHEMA_VERSION:
        raise DataError.at(path, f"schema_version is {version}, expected {SCHEMA_VERSION}")
    if num_robots <= 0 or num_samples < 0 or num_episodes < 0:
        raise DataError.at(path, f"'{METADATA_NAME}' metadata has impossible counts (N={num_robots}, samples={num_samples})")
    channels = [c for c in summary.channels.values() if c.topic == SAMPLE_TOPIC]
    if len(channels) != 1:
        raise DataError.at(path, f"expected exactly one {SAMPLE_TOPIC} channel, found {len(channels)}")
    channel = channels[0]
    schema = summary.schemas.get(channel.schema_id)
    if schema is None or schema.name != sample_proto.SAMPLE_SCHEMA_NAME or channel.message_encoding != MessageEncoding.Protobuf:
        got = schema.name if schema is not None else "none"
        raise DataError.at(path, f"{SAMPLE_TOPIC} has schema {got!r}, expected protobuf {sample_proto.SAMPLE_SCHEMA_NAME!r}")
    counted = summary.statistics.channel_message_counts.get(channel.id, 0)
    if counted != num_samples:
        raise DataError.at(path, f"statistics count {counted} samples but metadata says {num_samples}")
    info = McapShardInfo(version, num_robots, num_samples, num_episodes, step_seconds)
    return info, channel.id


def read_mcap_info(path: PathLike) -> McapShardInfo:
    """Schema version, N and counts of a shard, from its summary and metadata only (fast)."""
    try:
        f = open(path, "rb")
    except OSError as e:
        raise DataError.at(path, f"cannot open shard ({e.strerror or e})") from None
    with f:
        return _open_summary(f, path)[0]


def read_mcap_shard(path: PathLike, batch_size: int = DEFAULT_BATCH_SIZE, verify_crc: bool = True) -> Iterator[SampleBatch]:
    """Stream the samples of an MCAP shard as :class:`SampleBatch` es of up to ``batch_size``.

    Only ``/madp/sample`` messages are decoded. Every yielded batch owns fresh, writable,
    C-contiguous arrays. Raises :class:`DataError` naming the file for another schema version, a
    truncated or corrupt file (CRC, compression or protobuf failure) or a malformed sample.
    ``verify_crc=False`` skips the chunk and data-section CRC checks (≈ 2 GB/s of CRC32 over the
    decompressed data); leave it on unless the shard's SHA-256 was just verified.
    """
    if batch_size <= 0:
        raise DataError.at(path, f"batch_size must be positive, got {batch_size}")
    try:
        f = open(path, "rb")
    except OSError as e:
        raise DataError.at(path, f"cannot open shard ({e.strerror or e})") from None
    with f:
        info, channel_id = _open_summary(f, path, verify_crc)
        n = info.num_robots
        shapes = sample_shapes(n)
        where = f"{path}: {SAMPLE_TOPIC}"
        Sample = sample_proto.Sample
        spec_actions = sample_proto.TensorSpec(f"{where}.actions", ACTIONS_DTYPE, shapes["actions"])
        spec_positions = sample_proto.TensorSpec(f"{where}.positions", POSITIONS_DTYPE, shapes["positions"])
        spec_obs = sample_proto.TensorSpec(f"{where}.observations", OBSERVATIONS_DTYPE, shapes["observations"])
        batch = SampleBatch.empty(min(batch_size, max(info.num_samples, 1)), n)
        fill = 0
        seen = 0
        try:
            f.seek(0)
            for record in StreamReader(f, validate_crcs=verify_crc).records:
                if type(record) is not Message or record.channel_id != channel_id:
                    continue
                msg = Sample.FromString(record.data)
                if msg.schema_version != SCHEMA_VERSION:
                    raise DataError.at(path, f"sample {seen} has schema_version {msg.schema_version}, expected {SCHEMA_VERSION}")
                batch.episode_id[fill] = msg.episode_id
                batch.step[fill] = msg.step
                batch.scenario_seed[fill] = msg.scenario_seed
                batch.actions[fill] = spec_actions.decode(msg.actions)
                batch.positions[fill] = spec_positions.decode(msg.positions)
                batch.observations[fill] = spec_obs.decode(msg.observations)
                fill += 1
                seen += 1
                if fill == len(batch):
                    yield batch
                    batch = SampleBatch.empty(min(batch_size, max(info.num_samples - seen, 1)), n)
                    fill = 0
        except DataError:
            raise
        except Exception as e:  # McapError, CRCValidationError, zstd.ZstdError, DecodeError, ...
            raise _corrupt(path, e) from None
        if seen != info.num_samples:
            raise DataError.at(path, f"found {seen} samples, expected {info.num_samples} (metadata)")
        if fill:
            yield batch.slice(0, fill)


__all__ = [
    "CHUNK_BYTES",
    "DEFAULT_BATCH_SIZE",
    "EPISODE_GAP_NS",
    "METADATA_NAME",
    "McapShardInfo",
    "SAMPLE_TOPIC",
    "STEP_SECONDS",
    "read_mcap_info",
    "read_mcap_shard",
    "write_mcap_shard",
]
