"""``--overwrite`` removes only what madp wrote; any other file makes it refuse, naming the file, and
nothing is removed ("lost files": it used to delete every file in the directory)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from madp.data_schema import Manifest
from madp.data_schema.dataset import convert_dataset
from madp.datagen import DatagenConfig, run_datagen
from madp.eval.runner import EvalConfig, run_suite
from madp.io.owned import NotOwned, clear_owned
from madp.sim import SimParams

from .test_reliability_errors import assert_one_line, cli

SMALL = ["--num-robots", "4", "--num-features", "4", "--world-size", "256", "--samples-per-shard", "24"]


def tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def small_cfg(n=48, seed=3):
    return DatagenConfig(n, seed=seed, samples_per_shard=24, params=SimParams(world_size=256, num_robots=4, num_features=4))


@pytest.fixture
def dataset(tmp_path):
    root = tmp_path / "d"
    run_datagen(small_cfg(), root, workers=1, progress=False)
    return root


def test_datagen_overwrite_refuses_a_users_file_and_removes_nothing(dataset):
    (dataset / "notes.txt").write_text("mine")
    (dataset / "train" / "extra.mcap").write_bytes(b"my own shard")
    before = tree(dataset)
    line = assert_one_line(*cli("datagen", "--n", "72", "--seed", "3", "--out", dataset, *SMALL, "--overwrite"),
                           "notes.txt", "and 1 more")
    assert "--overwrite" in line and tree(dataset) == before


def test_datagen_overwrite_replaces_only_madps_files(dataset):
    old_plan = (dataset / ".datagen" / "plan.json").read_text()
    code, err = cli("datagen", "--n", "72", "--seed", "3", "--out", dataset, *SMALL, "--overwrite")
    assert code == 0, err
    m = Manifest.load(dataset)
    assert m.num_samples == 72
    files = set(tree(dataset))
    assert files == {"manifest.json", ".datagen/plan.json", *(s.file for sp in m.splits.values() for s in sp.shards),
                     *(f".datagen/shards/{p.name}" for p in (dataset / ".datagen" / "shards").glob("*.json"))}
    assert (dataset / ".datagen" / "plan.json").read_text() != old_plan


def test_datagen_into_a_foreign_directory_names_the_file(tmp_path):
    d = tmp_path / "mine"
    d.mkdir()
    (d / "thesis.tex").write_text("x")
    assert_one_line(*cli("datagen", "--n", "24", "--out", d, *SMALL, "--overwrite"), "thesis.tex")
    assert [p.name for p in d.iterdir()] == ["thesis.tex"]


def test_convert_overwrite(dataset, tmp_path):
    out = tmp_path / "pq"
    convert_dataset(dataset, "parquet", out)
    (out / "README").write_text("mine")
    before = tree(out)
    assert_one_line(*cli("dataset", "convert", dataset, "--to", "mcap", "--out", out, "--overwrite"), "README")
    assert tree(out) == before
    (out / "README").unlink()
    code, err = cli("dataset", "convert", dataset, "--to", "mcap", "--out", out, "--overwrite")
    assert code == 0, err
    assert not list(out.rglob("*.parquet")) and Manifest.load(out).format == "mcap"


def test_an_interrupted_convert_is_redone_without_overwrite(dataset, tmp_path):
    out = tmp_path / "pq"
    m = convert_dataset(dataset, "parquet", out)
    (out / "manifest.json").unlink()  # killed before its manifest
    (out / m.splits["val"].shards[0].file).unlink()
    code, err = cli("dataset", "convert", dataset, "--to", "parquet", "--out", out)
    assert code == 0, err
    assert Manifest.load(out).to_json() == m.to_json()


def test_eval_overwrite_removes_only_the_suites_files(tmp_path):
    cfg = EvalConfig(suite="uniform", out=str(tmp_path / "ev"), num_envs=1, steps=4, controllers=("dcvt",), workers=1)
    run_suite(cfg, "uniform", progress=False)
    suite = tmp_path / "ev" / "uniform"
    (suite / "analysis.ipynb").write_text("{}")
    before = tree(suite)
    other = EvalConfig(**{**cfg.__dict__, "steps": 5})
    with pytest.raises(NotOwned, match="analysis.ipynb"):
        run_suite(other, "uniform", overwrite=True, progress=False)
    assert tree(suite) == before
    (suite / "analysis.ipynb").unlink()
    run_suite(other, "uniform", overwrite=True, progress=False)
    assert '"steps": 5' in (suite / "config.json").read_text()


def test_clear_owned_never_follows_a_link_out_of_the_directory(tmp_path):
    root, outside = tmp_path / "root", tmp_path / "outside"
    root.mkdir()
    outside.mkdir()
    (outside / "precious").write_text("x")
    (root / "manifest.json").write_text("{}")
    os.symlink(outside, root / "train")
    with pytest.raises(NotOwned, match="train"):
        clear_owned(root, ["manifest.json", "train/precious"])
    assert (outside / "precious").exists() and (root / "manifest.json").exists()
    (root / "train").unlink()
    assert clear_owned(root, ["manifest.json", "../outside/precious"]) == 1
    assert (outside / "precious").exists() and not (root / "manifest.json").exists()
