"""madp eval with MADP choosing among K samples per robot (--select, --candidates): the
setting travels into config.json, results.parquet, summary.json, summary.md and the recordings'
metadata, is refused for a suite made with another, and batched rollouts match lone ones."""

import json
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest

from madp.eval.runner import EvalConfig, run_batch, run_job, run_suite
from madp.eval.suites import suite_envs
from madp.policies import SamplingSettings
from tests.recordings.test_record import _read


def test_selection_is_named_in_every_output(tmp_path, checkpoints):
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), num_envs=2, steps=2, controllers=("dcvt", "madp"),
                     madp=str(checkpoints / "madp.safetensors"),
                     sampling=SamplingSettings(select="explore", candidates=2), workers=1, record=1)
    run_suite(cfg, "uniform", progress=False)
    d = tmp_path / "uniform"
    summary = json.loads((d / "summary.json").read_text())
    config = json.loads((d / "config.json").read_text())
    assert config["select"] == "explore" and config["candidates"] == 2
    res = pq.read_table(d / "results.parquet").to_pydict()
    assert {(c, s, k) for c, s, k in zip(res["controller"], res["select"], res["candidates"])} == {
        ("dcvt", "", 0), ("madp", "explore", 2)}
    assert summary["sampling"]["madp"]["select"] == "explore" and summary["sampling"]["madp"]["candidates"] == 2
    assert "2 samples per robot kept by explore: each robot keeps the sample of least cost of its own Voronoi cell" in (d / "summary.md").read_text()
    _, meta, _ = _read(d / "rollouts" / "uniform-000-madp.mcap")
    assert any(m.get("select") == "explore" and m.get("candidates") == "2" for m in meta.values())
    other = replace(cfg, sampling=replace(cfg.sampling, select="oracle_cell"))
    with pytest.raises(ValueError, match="other settings"):
        run_suite(other, "uniform", progress=False)


def test_the_default_runs_its_fallback_on_a_policy_file_without_a_critic(tmp_path, checkpoints):
    """The default rule reads a critic; the shipped file carries one and a fresh one does not: in one
    run each MADP chooses by the rule its file can run, each row and recording names it, the command
    prints a note, and config.json keeps the setting asked for."""
    from typer.testing import CliRunner

    from madp.cli import app
    from madp.selection import DEFAULT_RULE, RULES

    plain = checkpoints / "madp.safetensors"
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), num_envs=1, steps=2, controllers=("madp", "madp:fresh"),
                     named=(("madp:fresh", str(plain)),), workers=1, record=1)
    fallback = RULES[DEFAULT_RULE].fallback
    assert fallback and cfg.sampling.select == DEFAULT_RULE and cfg.sampling_of("madp").select == DEFAULT_RULE
    assert cfg.sampling_of("madp:fresh") == replace(cfg.sampling, select=fallback)
    run_suite(cfg, "uniform", progress=False)
    d = tmp_path / "uniform"
    res = pq.read_table(d / "results.parquet").to_pydict()
    assert dict(zip(res["controller"], res["select"])) == {"madp": DEFAULT_RULE, "madp:fresh": fallback}
    assert json.loads((d / "config.json").read_text())["select"] == DEFAULT_RULE
    _, meta, _ = _read(d / "rollouts" / "uniform-000-madp@fresh.mcap")
    assert any(m.get("select") == fallback for m in meta.values())
    res = CliRunner().invoke(app, ["eval", "--suite", "uniform", "--num-envs", "1", "--steps", "1", "--controllers",
                                   "madp", "--madp", str(plain), "--workers", "1", "--out", str(tmp_path / "cli")])
    assert res.exit_code == 0 and f"carries no critic; it chooses by {fallback}" in res.output


def test_the_oracle_is_labelled_an_upper_bound(tmp_path, checkpoints):
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), num_envs=1, steps=1, controllers=("madp",),
                     madp=str(checkpoints / "madp.safetensors"),
                     sampling=SamplingSettings(select="oracle", candidates=2), workers=1)
    run_suite(cfg, "uniform", progress=False)
    md = (tmp_path / "uniform" / "summary.md").read_text().splitlines()
    line = next(x for x in md if x.startswith("MADP sampling"))
    assert "kept by oracle: the joint sample of least true J after the step (an upper bound, not a controller robots could run)" in line


@pytest.mark.parametrize("select", ["oracle", "oracle_joint"])
def test_batched_rollouts_with_selection_match_lone_rollouts(tmp_path, checkpoints, select):
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), steps=3, madp=str(checkpoints / "madp.safetensors"),
                     sampling=SamplingSettings(select=select, candidates=3))
    envs = suite_envs("uniform", 2)
    run_batch(cfg, envs, "madp", tmp_path / "batch")
    for e in envs:
        run_job(cfg, e, "madp", tmp_path / "lone")
        a = np.load(tmp_path / "batch" / "jobs" / f"{e.key}-madp.npz")["cost"]
        b = np.load(tmp_path / "lone" / "jobs" / f"{e.key}-madp.npz")["cost"]
        np.testing.assert_allclose(a, b, rtol=1e-5)
