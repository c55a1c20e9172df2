"""convert, train and merge check every shard against the manifest (size, sha256, counts) before use
("unchecked data": a Parquet shard with one row fewer converted into a dataset that verified)."""

from __future__ import annotations

import json
import shutil

import pyarrow.parquet as pq
import pytest

from madp.data_schema import DataError, Manifest, ShardInfo, check_shard
from madp.io.checksum import sha256_file
from madp.data_schema.dataset import convert_dataset
from madp.datagen import DatagenConfig, make_plan, run_datagen
from madp.sim import SimParams

from ..test_reliability_errors import assert_one_line, cli


def small_cfg(fmt="parquet"):
    return DatagenConfig(96, seed=5, format=fmt, samples_per_shard=24,
                         params=SimParams(world_size=256, num_robots=4, num_features=4))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("pq")
    run_datagen(small_cfg(), root, workers=1, progress=False)
    return root


def drop_last_row(path) -> None:
    """Re-encode a Parquet shard without its last sample: a valid shard, one row short."""
    t = pq.read_table(path)
    pq.write_table(t.slice(0, t.num_rows - 1), path, compression="zstd")


@pytest.fixture
def one_row_short(dataset, tmp_path):
    """A copy of the dataset whose first train shard lost a row (manifest untouched), and that shard."""
    copy = tmp_path / "short"
    shutil.copytree(dataset, copy)
    shard = Manifest.load(copy).shard_paths("train", copy)[0]
    drop_last_row(shard)
    return copy, shard


def restamp(root, shard) -> None:
    """Make the manifest's size and sha256 of ``shard`` match the file, leaving its counts stale."""
    d = json.loads((root / "manifest.json").read_text())
    for s in d["splits"]["train"]["shards"]:
        if root / s["file"] == shard:
            s["sha256"], s["bytes"] = sha256_file(shard), shard.stat().st_size
    (root / "manifest.json").write_text(json.dumps(d))


def test_convert_refuses_a_shard_one_row_short(one_row_short, tmp_path):
    root, shard = one_row_short
    assert_one_line(*cli("dataset", "convert", root, "--to", "mcap", "--out", tmp_path / "out"), str(shard), "(manifest)")
    restamp(root, shard)  # the checksum agrees now; the count does not
    assert_one_line(*cli("dataset", "convert", root, "--to", "mcap", "--out", tmp_path / "out2"), str(shard), "samples")
    assert not (tmp_path / "out" / "manifest.json").exists() and not (tmp_path / "out2" / "manifest.json").exists()


def test_train_refuses_a_shard_one_row_short_before_training(one_row_short, tmp_path):
    root, shard = one_row_short
    out = tmp_path / "run"
    args = ["train", "--data", root, "--out", out, "--epochs", "1", "--batch-size", "4", "--workers", "0",
            "--val-samples", "4", "--max-steps-per-epoch", "1"]
    assert_one_line(*cli(*args), str(shard), "(manifest)")
    restamp(root, shard)
    assert_one_line(*cli(*args), str(shard), "samples")
    assert not out.exists()


def test_merge_checks_each_shard_against_its_record(tmp_path):
    cfg = small_cfg("mcap")
    n = len(make_plan(cfg))
    run_datagen(cfg, tmp_path / "a", workers=1, shards=(0, 2), progress=False)
    run_datagen(cfg, tmp_path / "b", workers=1, shards=(2, n), progress=False)
    rec_file = sorted((tmp_path / "a" / ".datagen" / "shards").glob("*.json"))[0]
    rec = json.loads(rec_file.read_text())
    rec["shard"]["num_samples"] -= 1  # a record whose count disagrees with its (intact) shard
    rec_file.write_text(json.dumps(rec))
    shard = tmp_path / "a" / rec["shard"]["file"]
    assert_one_line(*cli("dataset", "merge", tmp_path / "a", tmp_path / "b", "--out", tmp_path / "m"), str(shard),
                    "samples")
    assert not (tmp_path / "m" / "manifest.json").exists()


def test_check_shard_names_every_disagreement(dataset, tmp_path):
    m = Manifest.load(dataset)
    info = m.splits["val"].shards[0]
    path = dataset / info.file
    check_shard(path, info, num_robots=4)  # intact
    copy = tmp_path / "x.parquet"
    shutil.copyfile(path, copy)
    check_shard(copy, info, copy_to=tmp_path / "y.parquet")
    assert (tmp_path / "y.parquet").read_bytes() == path.read_bytes()  # the checked copy costs no second read
    for bad, needle in ((ShardInfo(info.file, info.num_samples, info.num_episodes, "0" * 64, info.bytes), "sha256"),
                        (ShardInfo(info.file, info.num_samples, info.num_episodes, info.sha256, info.bytes + 1), "size"),
                        (ShardInfo(info.file, info.num_samples + 1, info.num_episodes, info.sha256, info.bytes), "samples")):
        with pytest.raises(DataError, match=needle):
            check_shard(copy, bad)
    with pytest.raises(DataError, match="robots"):
        check_shard(copy, info, num_robots=5)
    with pytest.raises(DataError, match="missing"):
        check_shard(tmp_path / "gone.parquet", info)


def test_an_intact_dataset_still_converts_and_trains(dataset, tmp_path):
    m = convert_dataset(dataset, "mcap", tmp_path / "mc")
    assert m.counts() == Manifest.load(dataset).counts()
