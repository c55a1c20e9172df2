"""Fuzz the manifest: any JSON (or bytes) in manifest.json gives a Manifest or a one-line DataError
naming it — never another exception; a manifest that loads never points outside its dataset."""

from __future__ import annotations

import copy
import json
from pathlib import PurePosixPath

import pytest
from hypothesis import strategies as st

from madp.data_schema import ActionStats, DataError, Manifest, ShardInfo, SplitInfo

from ..fuzzing import JSON, load_damaged_file, mutate, twins


def valid_manifest() -> dict:
    shard = lambda f, n: ShardInfo(f, n, 2, "ab" * 32, 1000 + n)  # noqa: E731
    m = Manifest("mcap", 4, params={"seed": 3, "params": {"world_size": 256}},
                 splits={"train": SplitInfo([shard("train/shard-00000.mcap", 24), shard("train/shard-00001.mcap", 10)]),
                         "val": SplitInfo([shard("val/shard-00000.mcap", 10)]), "test": SplitInfo([])},
                 action_stats=ActionStats((0.1, -0.2), (1.0, 2.0), 136), created_by="madp datagen --n 44")
    return json.loads(m.to_json())


VALID = valid_manifest()


def builds_or_refuses(doc) -> None:
    try:
        m = Manifest.from_dict(doc, "fuzz/manifest.json")
    except DataError as e:
        assert "\n" not in str(e) and "fuzz/manifest.json" in str(e)
        return
    for sp in m.splits.values():
        for s in sp.shards:
            p = PurePosixPath(s.file)
            assert not p.is_absolute() and ".." not in p.parts and "\\" not in s.file
    m.to_json()  # what loads, saves


def prop_any_json(doc):
    builds_or_refuses(doc)


def prop_mutated(data):
    builds_or_refuses(mutate(data, VALID, rounds=4))


def prop_damaged_file(tmp_path_factory, data):
    load_damaged_file(tmp_path_factory, data, "fuzz-manifest.json", json.dumps(VALID, indent=2).encode(),
                      Manifest.load, DataError)


test_any_json_manifest, test_any_json_manifest_soak = twins(prop_any_json, 150, 3000, doc=JSON)
test_mutated_manifest, test_mutated_manifest_soak = twins(prop_mutated, 300, 6000, data=st.data())
test_damaged_manifest_file, test_damaged_manifest_file_soak = twins(prop_damaged_file, 150, 3000, data=st.data())


def test_the_valid_manifest_loads():
    assert Manifest.from_dict(VALID).num_samples == 44


def test_cases_the_fuzzers_found():
    """Each raised another exception before it was fixed (the soak found them)."""
    huge_mean = copy.deepcopy(VALID)
    huge_mean["action_stats"]["mean"][0] = 10**400  # OverflowError
    inf_params = copy.deepcopy(VALID)
    inf_params["params"]["seed"] = float("inf")  # loaded, then failed on save
    for doc in (huge_mean, inf_params):
        with pytest.raises(DataError):
            Manifest.from_dict(doc, "fuzz/manifest.json")


def test_non_utf8_manifest_is_named(tmp_path):  # found by the quick pass: UnicodeDecodeError
    (tmp_path / "manifest.json").write_bytes(b"\x80{}")
    with pytest.raises(DataError, match="manifest.json"):
        Manifest.load(tmp_path)
