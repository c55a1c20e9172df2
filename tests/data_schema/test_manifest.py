"""Manifest JSON round trip, version refusal, shard verification and exact action statistics."""

from __future__ import annotations

import json

import numpy as np
import pytest

from madp.data_schema import (
    ActionStatsAccumulator,
    DataError,
    Manifest,
    ShardInfo,
    SplitInfo,
    iter_shard,
    write_shard,
)

from .conftest import random_episodes


def _manifest(tmp_path) -> Manifest:
    eps = random_episodes(lengths=(3, 2, 4), with_extras=False)
    splits = {}
    acc = ActionStatsAccumulator()
    for name, part in (("train", eps[:2]), ("val", eps[2:]), ("test", [])):
        split = SplitInfo()
        if part:
            info = write_shard(tmp_path / name / "shard-00000.mcap", part)
            info.file = f"{name}/{info.file}"
            split.shards.append(info)
        splits[name] = split
    for batch in iter_shard(tmp_path / "train" / "shard-00000.mcap"):
        acc.add_batch(batch)
    return Manifest(
        format="mcap",
        num_robots=6,
        params={"sigma": [40, 60], "n": np.int64(9), "u_max": 5.0},
        splits=splits,
        action_stats=acc.result(),
        created_by="madp datagen --n 9",
    )


def test_round_trip_and_deterministic_bytes(tmp_path):
    m = _manifest(tmp_path)
    path = m.save(tmp_path)
    text = path.read_text()
    assert path.name == "manifest.json" and text.endswith("}\n")
    assert json.loads(text)["splits"]["train"]["num_samples"] == 5
    loaded = Manifest.load(tmp_path)
    assert loaded.to_json() == text  # stable key order, identical bytes
    assert loaded.counts() == {"train": 5, "val": 4, "test": 0}
    assert loaded.splits["val"].num_episodes == 1
    assert loaded.params["n"] == 9
    assert loaded.action_stats == m.action_stats
    assert loaded.code_version == "0.1.0" and loaded.schema_version == 1
    assert [p.name for p in loaded.shard_paths("train", tmp_path)] == ["shard-00000.mcap"]
    loaded.verify_shards(tmp_path)


def test_wrong_schema_version_refused(tmp_path):
    m = _manifest(tmp_path)
    d = m.to_dict()
    d["schema_version"] = 2
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(d))
    with pytest.raises(DataError) as exc:
        Manifest.load(path)
    assert str(exc.value) == f"{path}: schema_version is 2, expected 1"


@pytest.mark.parametrize(
    "edit, fragment",
    [
        (lambda d: d.pop("format"), "missing key 'format'"),
        (lambda d: d.update(format="hdf5"), "expected one of ['mcap', 'parquet']"),
        (lambda d: d["splits"]["train"].update(num_samples=99), "splits.train.num_samples: is 99, expected 5"),
        (lambda d: d["splits"]["train"]["shards"][0].update(sha256="xyz"), "expected 64 lowercase hex digits"),
        (lambda d: d["splits"]["train"]["shards"][0].update(file="../x.mcap"), "expected a relative"),
        (lambda d: d.update(extra=1), "unexpected keys ['extra']"),
        (lambda d: d["action_stats"].update(std=[1.0]), "action_stats.std: expected a list of 2 finite numbers"),
    ],
)
def test_invalid_manifest_refused(tmp_path, edit, fragment):
    d = _manifest(tmp_path).to_dict()
    edit(d)
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(d))
    with pytest.raises(DataError) as exc:
        Manifest.load(path)
    assert fragment in str(exc.value) and str(path) in str(exc.value)


def test_invalid_json_and_missing_file(tmp_path):
    (tmp_path / "manifest.json").write_text("{ nope")
    with pytest.raises(DataError, match="invalid JSON at line 1"):
        Manifest.load(tmp_path)
    with pytest.raises(DataError, match="cannot read manifest"):
        Manifest.load(tmp_path / "missing.json")


def test_verify_shards_detects_tampering(tmp_path):
    m = _manifest(tmp_path)
    shard = tmp_path / "val" / "shard-00000.mcap"
    data = bytearray(shard.read_bytes())
    data[100] ^= 1
    shard.write_bytes(bytes(data))
    with pytest.raises(DataError, match="sha256 is .* expected"):
        m.verify_shards(tmp_path)
    shard.write_bytes(bytes(data[:-1]))
    with pytest.raises(DataError, match="size is"):
        m.verify_shards(tmp_path, check_sha256=False)
    shard.unlink()
    with pytest.raises(DataError, match="missing"):
        m.verify_shards(tmp_path)


def test_action_stats_match_float64_reference():
    rng = np.random.default_rng(0)
    u = rng.uniform(-5, 5, (500, 32, 2)).astype(np.float32)
    stats = ActionStatsAccumulator().add(u).result()
    ref = u.reshape(-1, 2).astype(np.float64)
    np.testing.assert_allclose(stats.mean, ref.mean(axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(stats.std, ref.std(axis=0), rtol=1e-12)
    assert stats.count == 500 * 32


def test_action_stats_exact_and_order_independent():
    rng = np.random.default_rng(1)
    # wide dynamic range, subnormals and exact cancellation: float64 sums would depend on order
    u = np.concatenate(
        [
            rng.uniform(-5, 5, (300, 2)),
            np.array([[1e30, -1e30], [-1e30, 1e30], [1e-45, -1e-45], [3.0, 4.0]]),
        ]
    ).astype(np.float32)
    whole = ActionStatsAccumulator().add(u).result()
    perm = u[rng.permutation(len(u))]
    parts = [ActionStatsAccumulator().add(perm[i : i + 37]) for i in range(0, len(perm), 37)]
    merged = ActionStatsAccumulator()
    for p in reversed(parts):
        merged.merge(ActionStatsAccumulator.from_state(json.loads(json.dumps(p.state()))))
    assert merged.result() == whole  # bit-identical floats
    # exact mean of a set whose float64 running sum loses the small values
    tiny = np.array([[1e30, 1.0], [1.0, 1.0], [-1e30, 1.0]], np.float32)
    assert ActionStatsAccumulator().add(tiny).result().mean[0] == pytest.approx(1.0 / 3.0, rel=1e-15)


def test_action_stats_refuses_bad_input():
    with pytest.raises(DataError, match="expected a float32 array"):
        ActionStatsAccumulator().add(np.zeros((3, 2)))
    with pytest.raises(DataError, match="finite"):
        ActionStatsAccumulator().add(np.full((3, 2), np.nan, np.float32))
    with pytest.raises(DataError, match="no actions"):
        ActionStatsAccumulator().result()


def test_shard_info_from_write(tmp_path):
    info = write_shard(tmp_path / "a.parquet", random_episodes(lengths=(2,)))
    assert isinstance(info, ShardInfo)
    assert ShardInfo.from_dict(info.to_dict(), "x") == info
