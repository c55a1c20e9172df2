"""The dataset manifest (``madp.data_schema.manifest``): JSON round trip with deterministic bytes,
version refusal and shard verification; and its validation contract, message for message.

Every refusal of the module is a one-line ``"<file or field>: <what was expected>"`` that the CLI
prints as is, so each contract case pins the *whole* message: a mutant that drops or changes the
field name, the expectation, or the condition that raises fails here (written against mutation survivors)."""

from __future__ import annotations

import copy
import json
import locale
import os
import sys

import numpy as np
import pytest

from madp.data_schema import ActionStatsAccumulator, DataError, Manifest, ShardInfo, SplitInfo, iter_shard, write_shard
from madp.data_schema.manifest import _req

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


def test_shard_info_from_write(tmp_path):
    info = write_shard(tmp_path / "a.parquet", random_episodes(lengths=(2,)))
    assert isinstance(info, ShardInfo)
    assert ShardInfo.from_dict(info.to_dict(), "x") == info


# --- the validation contract, message for message --------------------------------------------------

_HEX = "0123456789abcdef" * 4


def _message(fn, *args, **kwargs) -> str:
    with pytest.raises(DataError) as exc:
        fn(*args, **kwargs)
    return str(exc.value)


def _shard(**changes) -> dict:
    d = {"bytes": 10, "file": "train/shard-00000.mcap", "num_episodes": 1, "num_samples": 3, "sha256": _HEX}
    d.update(changes)
    return d


def _manifest_dict() -> dict:
    return {
        "action_stats": {"count": 6, "mean": [0.5, -0.5], "std": [1.0, 2.0]},
        "code_version": "0.1.0",
        "created_by": "madp datagen --n 3",
        "format": "mcap",
        "num_robots": 2,
        "params": {"sigma": [40, 60]},
        "schema_version": 1,
        "splits": {"train": {"num_episodes": 1, "num_samples": 3, "shards": [_shard()]}},
    }


def test_req_messages():
    assert _message(_req, {}, "k", int, "w") == "w: missing key 'k'"
    assert _message(_req, {"k": True}, "k", int, "w") == "w.k: expected int, got bool"
    assert _message(_req, {"k": "x"}, "k", (int, float), "w") == "w.k: expected int/float, got str"
    assert _req({"k": True}, "k", bool, "w") is True


@pytest.mark.parametrize(
    "d, message",
    [
        ("x", "s: expected an object"),
        (_shard(extra=1), "s: unexpected keys ['extra']"),
        (_shard(num_samples=-1), "s: expected non-negative counts and size"),
        (_shard(num_episodes=-1), "s: expected non-negative counts and size"),
        (_shard(bytes=-1), "s: expected non-negative counts and size"),
        (_shard(sha256=_HEX[:-1]), "s.sha256: expected 64 lowercase hex digits"),
        (_shard(sha256=_HEX[:-1] + "g"), "s.sha256: expected 64 lowercase hex digits"),
        (_shard(sha256=_HEX.upper()), "s.sha256: expected 64 lowercase hex digits"),
        (_shard(sha256=_HEX[:-1] + "X"), "s.sha256: expected 64 lowercase hex digits"),
        (_shard(file=""), "s.file: expected a relative '/'-separated path inside the dataset, got ''"),
        (_shard(file="/abs.mcap"), "s.file: expected a relative '/'-separated path inside the dataset, got '/abs.mcap'"),
        (_shard(file="a\\b.mcap"), "s.file: expected a relative '/'-separated path inside the dataset, got 'a\\\\b.mcap'"),
        (_shard(file="a/../b.mcap"), "s.file: expected a relative '/'-separated path inside the dataset, got 'a/../b.mcap'"),
    ],
)
def test_shard_refusals(d, message):
    assert _message(ShardInfo.from_dict, d, "s") == message


def test_shard_boundaries_accepted():
    """An empty shard (0 samples, 0 episodes, 0 bytes) and a name with dots are valid."""
    info = ShardInfo.from_dict(_shard(num_samples=0, num_episodes=0, bytes=0, file="x/a..b.mcap"), "s")
    assert (info.num_samples, info.num_episodes, info.bytes, info.file) == (0, 0, 0, "x/a..b.mcap")


@pytest.mark.parametrize(
    "d, message",
    [
        ([], "sp: expected an object"),
        ({"shards": [], "num_samples": 0, "num_episodes": 0, "x": 1}, "sp: unexpected keys ['x']"),
        ({"shards": [_shard()], "num_samples": 4, "num_episodes": 1}, "sp.num_samples: is 4, expected 3 (sum over its shards)"),
        ({"shards": [_shard()], "num_samples": 3, "num_episodes": 2}, "sp.num_episodes: is 2, expected 1 (sum over its shards)"),
        ({"shards": [_shard(), "x"], "num_samples": 3, "num_episodes": 1}, "sp.shards[1]: expected an object"),
    ],
)
def test_split_refusals(d, message):
    assert _message(SplitInfo.from_dict, d, "sp") == message


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"format": "hdf5", "num_robots": 2}, "manifest.format: expected one of ['mcap', 'parquet'], got 'hdf5'"),
        ({"format": "mcap", "num_robots": 0}, "manifest.num_robots: expected a positive integer, got 0"),
        ({"format": "mcap", "num_robots": True}, "manifest.num_robots: expected a positive integer, got True"),
        ({"format": "mcap", "num_robots": 2.0}, "manifest.num_robots: expected a positive integer, got 2.0"),
    ],
)
def test_manifest_constructor_refusals(kwargs, message):
    assert _message(Manifest, **kwargs) == message


def test_manifest_one_robot_and_no_stats():
    m = Manifest(format="parquet", num_robots=1)
    d = m.to_dict()
    assert d["num_robots"] == 1 and d["action_stats"] is None and d["format"] == "parquet"
    assert _message(m.shard_paths, "dev", "/r") == "manifest.splits: no split named 'dev' (have ['test', 'train', 'val'])"
    m.params["bad"] = float("nan")
    assert _message(m.to_json) == "manifest.params: expected JSON-serialisable finite values (Out of range float values are not JSON compliant: nan)"


def _edit(fn):
    d = copy.deepcopy(_manifest_dict())
    fn(d)
    return d


@pytest.mark.parametrize(
    "d, message",
    [
        ([], "m.json: expected a JSON object"),
        (_edit(lambda d: d.pop("schema_version")), "m.json: schema_version is None, expected 1"),
        (_edit(lambda d: d.update(junk=0)), "m.json: unexpected keys ['junk']"),
        (_edit(lambda d: d.update(format="hdf5")), "m.json: format: expected one of ['mcap', 'parquet'], got 'hdf5'"),
        (_edit(lambda d: d.update(num_robots=0)), "m.json: num_robots: expected a positive integer, got 0"),
        (_edit(lambda d: d.update(num_robots=True)), "m.json.num_robots: expected int, got bool"),
        (_edit(lambda d: d["params"].update(x=float("inf"))), "m.json: params: expected finite JSON values"),
        (_edit(lambda d: d["splits"]["train"].update(num_samples=2)), "m.json: splits.train.num_samples: is 2, expected 3 (sum over its shards)"),
        (_edit(lambda d: d["action_stats"].update(count=0)), "m.json: action_stats.count: expected a positive integer"),
        (_edit(lambda d: d.pop("created_by")), "m.json: missing key 'created_by'"),
    ],
)
def test_manifest_refusals(d, message):
    assert _message(Manifest.from_dict, d, "m.json") == message


def test_manifest_load_names_the_file(tmp_path):
    path = tmp_path / "manifest.json"
    assert Manifest.load(_write(path, _manifest_dict())).num_robots == 2
    assert Manifest.load(tmp_path).counts() == {"train": 3}  # a directory means its manifest.json
    path.write_bytes(b'{"a": "\xff"}')
    assert _message(Manifest.load, path) == f"{path}: not UTF-8 text (byte 7); expected a JSON manifest"
    missing = tmp_path / "nowhere" / "manifest.json"
    assert _message(Manifest.load, missing) == f"{missing}: cannot read manifest (No such file or directory)"


def test_manifest_is_read_as_utf8_whatever_the_locale(tmp_path):
    """A manifest is UTF-8 JSON, also in a C (ASCII) locale (guards ``read_text(encoding=None)``; in
    Python's UTF-8 mode both read UTF-8 and the test cannot tell them apart)."""
    d = _manifest_dict()
    d["created_by"] = "madp datagen --out Zürich"
    path = tmp_path / "manifest.json"
    path.write_bytes(json.dumps(d, ensure_ascii=False).encode("utf-8"))
    before = locale.setlocale(locale.LC_CTYPE)
    try:
        locale.setlocale(locale.LC_CTYPE, "C")
        if not sys.flags.utf8_mode:
            assert locale.getpreferredencoding(False) != "UTF-8"
        m = Manifest.load(path)
    finally:
        locale.setlocale(locale.LC_CTYPE, before)
    assert m.created_by == "madp datagen --out Zürich"


def _write(path, d) -> str:
    path.write_text(json.dumps(d))
    return os.fspath(path)


def test_verify_shards_messages(tmp_path):
    """Each shard problem names the shard's path (mutants: ``DataError.at(None, …)``)."""
    body = b"0123456789"
    import hashlib

    d = _manifest_dict()
    d["splits"]["train"]["shards"][0]["sha256"] = hashlib.sha256(body).hexdigest()
    m = Manifest.from_dict(d)
    shard = tmp_path / "train" / "shard-00000.mcap"
    assert _message(m.verify_shards, tmp_path) == f"{shard}: shard of split 'train' is missing"
    shard.parent.mkdir()
    shard.write_bytes(body[:-1])
    assert _message(m.verify_shards, tmp_path) == f"{shard}: size is 9 bytes, expected 10 (manifest)"
    shard.write_bytes(body[::-1])
    assert _message(m.verify_shards, tmp_path) == (
        f"{shard}: sha256 is {hashlib.sha256(body[::-1]).hexdigest()}, expected {hashlib.sha256(body).hexdigest()} (manifest)"
    )
    m.verify_shards(tmp_path, check_sha256=False)
    shard.write_bytes(body)
    m.verify_shards(tmp_path)


def test_dumps_canonical_text_is_pinned(tmp_path):
    """Guards the manifest's exact bytes (its sha256 is recorded in checkpoints' provenance): sorted
    keys, 2-space indent, numpy arrays and scalars as plain JSON, paths as strings, NaN refused
    (mutants: ``indent=3``/``None``/dropped, ``sort_keys=False``/``None``/dropped, ``allow_nan=None``,
    ``_jsonable(None)`` for arrays, ``os.fspath(None)``)."""
    from pathlib import Path

    from madp.data_schema.manifest import dumps_canonical

    text = dumps_canonical({"b": np.array([1, 2], dtype=np.int64), "a": {"d": np.float32(0.5), "c": Path("x/y")}})
    assert text == '{\n  "a": {\n    "c": "x/y",\n    "d": 0.5\n  },\n  "b": [\n    1,\n    2\n  ]\n}\n'
    with pytest.raises(ValueError):
        dumps_canonical({"x": float("nan")})


def test_from_dict_keeps_what_the_file_says():
    """Guards ``Manifest.from_dict``: one robot is a valid dataset (mutant ``num_robots <= 1``), a
    manifest whose action statistics are still ``null`` loads (mutant ``(stats_d is None) and
    False``), and the writer's ``code_version`` is the file's, not this install's (mutant dropping
    ``code_version=``); the dict round-trips exactly."""
    d = _manifest_dict()
    d.update(num_robots=1, action_stats=None, code_version="0.0.1-writer")
    m = Manifest.from_dict(copy.deepcopy(d))
    assert m.num_robots == 1 and m.action_stats is None and m.code_version == "0.0.1-writer"
    assert m.to_dict() == d
