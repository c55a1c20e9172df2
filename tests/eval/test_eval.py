"""madp eval: suites, identical environments, learned policies, resume, outputs and errors."""

import json
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from madp.datagen.plan import DATASET_SEED_BITS
from madp.eval.runner import EvalConfig, available_controllers, run_suite
from madp.eval.suites import EVAL_SEED_BIT, LAUNCHES, suite_envs
from madp.models import LPAC, MADP, lpac_config, madp_config
from madp.training.checkpoint import save_policy
from tests.conftest import CITIES

META = {"action_stats": {"count": 1, "mean": [0.0, 0.0], "std": [2.0, 2.0]}}


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """Untrained but well-formed policy files (the plumbing, not the skill, is under test here)."""
    d = tmp_path_factory.mktemp("ckpt")
    torch.manual_seed(0)
    for kind, model in (("madp", MADP(madp_config("cpu"))), ("lpac", LPAC(lpac_config("cpu")))):
        model.set_action_stats(torch.zeros(2), torch.full((2,), 2.0))
        save_policy(d / f"{kind}.safetensors", model, kind, META)
    return d


def test_suites_are_seeded_apart_from_datasets():
    for suite in ("uniform", "sigma", "launch", "scale"):
        envs = suite_envs(suite, 2)
        seeds = [e.seed for e in envs]
        assert len(set(seeds)) == len(seeds)
        assert all(s & EVAL_SEED_BIT and s < 2 * EVAL_SEED_BIT for s in seeds)
        assert all(s >= 1 << DATASET_SEED_BITS for s in seeds)  # dataset seeds are < 2^62
    assert [e.group for e in suite_envs("sigma", 1)] == ["sigma_30-40", "sigma_20-30", "sigma_10-20", "sigma_5-10"]
    assert len(suite_envs("scale", 1)) == 16
    square = [e for e in suite_envs("launch", 3) if e.launch == "square"][0].scenario()
    x0, y0, x1, y1 = LAUNCHES["square"]
    assert ((square.robots_m >= [x0, y0]) & (square.robots_m <= [x1, y1])).all()
    s = suite_envs("sigma", 1)[-1].scenario()
    assert (s.features[:, 2] >= 5).all() and (s.features[:, 2] <= 10).all()


def test_cities_suite_reads_city_files():
    if not CITIES.is_dir():
        pytest.skip("../shared/cities not present")
    envs = suite_envs("cities", 50, CITIES)
    assert len(envs) == 40
    sc = envs[[e.group for e in envs].index("portland_oregon")].scenario()
    assert len(sc.features) == 166 and sc.params.num_robots == 32
    shipped = suite_envs("cities", 50)  # the copy inside the package
    assert [e.group for e in shipped] == [e.group for e in envs]


def test_eval_end_to_end_resume_and_identical_envs(tmp_path, checkpoints):
    cfg = EvalConfig(suite="launch", out=str(tmp_path), num_envs=1, steps=12, workers=1, record=1, ddim_steps=3,
                     lpac=str(checkpoints / "lpac.safetensors"), madp=str(checkpoints / "madp.safetensors"))
    cfg, used = available_controllers(cfg, ("clairvoyant", "dcvt", "lpac", "madp", "madp_central"), explicit=True)
    run_suite(cfg, "launch", progress=False)
    d = tmp_path / "launch"
    curves = pq.read_table(d / "curves.parquet").to_pandas()
    results = pq.read_table(d / "results.parquet").to_pandas()
    assert set(results.controller) == set(used) and len(results) == 3 * 5
    assert (curves[curves.step == 0].cost == 1.0).all()
    # every controller saw the same environments (same seeds per group)
    assert results.groupby("group").scenario_seed.nunique().eq(1).all()
    for f in ("summary.md", "summary.json"):
        assert (d / f).stat().st_size > 100
    assert list(d.glob("*.png"))
    rollouts = sorted(p.name for p in (d / "rollouts").glob("*.mcap"))
    assert rollouts == sorted(f"uniform-000-{c}.mcap" for c in used)  # first environment only
    # resume: drop one finished job, run again, tables identical
    before = (d / "results.parquet").read_bytes()
    (d / "jobs" / "line-000-dcvt.npz").unlink()
    run_suite(cfg, "launch", progress=False)
    after = pq.read_table(d / "results.parquet").to_pandas()
    np.testing.assert_allclose(after.final_cost, results.final_cost)
    # other settings are refused; a controller may be added later
    with pytest.raises(ValueError, match="--overwrite"):
        run_suite(EvalConfig(**{**cfg.__dict__, "steps": 13}), "launch", progress=False)
    fewer = EvalConfig(**{**cfg.__dict__, "controllers": ("clairvoyant", "dcvt")})
    run_suite(fewer, "launch", progress=False)
    assert set(pq.read_table(d / "results.parquet").column("controller").to_pylist()) == {"clairvoyant", "dcvt"}


def test_eval_cli_errors_are_one_line(tmp_path, checkpoints):
    def run(*args):
        return subprocess.run([sys.executable, "-m", "madp.cli", "eval", "--out", str(tmp_path), "--num-envs", "1",
                               "--steps", "2", *args], capture_output=True, text=True)

    r = run("--controllers", "madp", "--madp", str(tmp_path / "missing.safetensors"))
    assert r.returncode == 2 and "missing.safetensors" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = run("--controllers", "madp", "--madp", str(checkpoints / "lpac.safetensors"))
    assert r.returncode == 2 and "expected madp" in r.stderr
    r = run("--suite", "moon")
    assert r.returncode == 2 and "--suite" in r.stderr
    r = run("--controllers", "dcvt,foo")
    assert r.returncode == 2 and "foo" in r.stderr
