"""Readers refuse other schema versions, truncated and corrupted files with a one-line DataError."""

from __future__ import annotations

import numpy as np
import pytest

from madp.data_schema import DataError, count_samples, iter_shard, mcap_codec, parquet_codec, write_shard

from .conftest import random_episodes


def _read_all(path) -> None:
    for _ in iter_shard(path):
        pass


def _assert_refused(path, match: str = "") -> str:
    with pytest.raises(DataError) as exc:
        _read_all(path)
    msg = str(exc.value)
    assert str(path) in msg, msg
    assert "\n" not in msg
    assert match in msg, msg
    return msg


@pytest.fixture
def shard(tmp_path, fmt, real_episodes):
    path = tmp_path / f"s.{fmt}"
    write_shard(path, real_episodes)
    return path


def test_wrong_schema_version_refused(tmp_path, fmt, monkeypatch):
    module = mcap_codec if fmt == "mcap" else parquet_codec
    monkeypatch.setattr(module, "SCHEMA_VERSION", 2)
    path = tmp_path / f"future.{fmt}"
    write_shard(path, random_episodes(lengths=(2,)))
    monkeypatch.undo()
    _assert_refused(path, "schema_version is 2, expected 1")
    with pytest.raises(DataError, match="expected 1"):
        count_samples(path)


def test_mcap_per_message_schema_version_checked(tmp_path, monkeypatch):
    """A message claiming another version is refused even if the file metadata says 1."""
    real_sample = mcap_codec.sample_proto.Sample

    def future_sample(**kw):
        kw["schema_version"] = 9
        return real_sample(**kw)

    monkeypatch.setattr(mcap_codec.sample_proto, "Sample", future_sample)
    path = tmp_path / "m.mcap"
    write_shard(path, random_episodes(lengths=(2,)))
    monkeypatch.undo()
    _assert_refused(path, "sample 0 has schema_version 9, expected 1")


def test_truncated_half_refused(shard):
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    _assert_refused(shard, "truncated")
    with pytest.raises(DataError):
        count_samples(shard)


def test_corrupted_bytes_in_the_middle_refused(shard):
    data = bytearray(shard.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = bytes(64)
    shard.write_bytes(bytes(data))
    _assert_refused(shard, "corrupt")


def test_every_single_byte_flip_detected_in_mcap(tmp_path):
    """Chunk, data-section and summary CRCs together cover every byte of an MCAP shard."""
    path = tmp_path / "s.mcap"
    write_shard(path, random_episodes(num_robots=2, lengths=(3, 2)))
    data = path.read_bytes()
    bad = tmp_path / "bad.mcap"
    for offset in np.linspace(0, len(data) - 1, 60).astype(int):
        flipped = bytearray(data)
        flipped[offset] ^= 0x41
        bad.write_bytes(bytes(flipped))
        with pytest.raises(DataError):
            _read_all(bad)


def test_not_a_shard(tmp_path, fmt):
    path = tmp_path / f"junk.{fmt}"
    path.write_bytes(b"hello world" * 10)
    _assert_refused(path)
    empty = tmp_path / f"empty.{fmt}"
    empty.write_bytes(b"")
    _assert_refused(empty)
    _assert_refused(tmp_path / f"missing.{fmt}")


def test_foreign_parquet_refused(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = tmp_path / "other.parquet"
    pq.write_table(pa.table({"x": [1, 2, 3]}), path)
    _assert_refused(path, "no 'madp' schema metadata")
