"""madp eval compare: paired numbers equal a direct computation from results.parquet; refusals are one line."""

import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from scipy import stats

from madp.eval.runner import EvalConfig, run_suite
from madp.models import lpac_config
from madp.models.lpac import LPAC
from madp.training.checkpoint import save_policy
from tests.eval.conftest import META
from tests.test_reliability_errors import assert_one_line, cli

STEPS = 12


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two real evaluations of the same 4 uniform environments that differ in the LPAC-K3 checkpoint (small
    untrained networks, one moving faster than the other), and one of 3 environments."""
    d = tmp_path_factory.mktemp("compare")
    for seed, std in ((0, 2.0), (1, 20.0)):
        torch.manual_seed(seed)
        model = LPAC(lpac_config("cpu", cnn_channels=(4, 4, 4), gnn_layers=1, gnn_hidden=8, mlp_hidden=(8,)))
        model.set_action_stats(torch.zeros(2), torch.full((2,), std))
        save_policy(d / f"lpac-{seed}.safetensors", model, "lpac", META)
    for name, lpac, n, controllers in (("a", 0, 4, ("dcvt", "lpac")), ("b", 1, 4, ("dcvt", "lpac")),
                                       ("fewer", 0, 3, ("dcvt",))):
        run_suite(EvalConfig(suite="uniform", out=str(d / name), num_envs=n, steps=STEPS, workers=1,
                             controllers=controllers, lpac=str(d / f"lpac-{lpac}.safetensors")), "uniform", progress=False)
    return d


def _direct(run_dir, base_dir):
    """{controller: (mean of run, mean of base, mean d, SE d, t interval, wins)} from the two results tables."""
    a = pq.read_table(base_dir / "results.parquet").to_pandas()
    b = pq.read_table(run_dir / "results.parquet").to_pandas()
    m = b.merge(a, on=["group", "env", "scenario_seed", "controller"], suffixes=("_run", "_base"), validate="1:1")
    out = {}
    for c, g in m.groupby("controller"):
        d = (g.final_cost_run - g.final_cost_base).to_numpy()
        n = len(d)
        se = d.std(ddof=1) / np.sqrt(n)
        half = stats.t.ppf(0.975, n - 1) * se
        out[c] = dict(n=n, run=g.final_cost_run.mean(), base=g.final_cost_base.mean(), diff=d.mean(), se=se,
                      lo=d.mean() - half, hi=d.mean() + half, wins=int((d < 0).sum()), ties=int((d == 0).sum()))
    return out


def test_compare_matches_results_parquet(runs, tmp_path):
    a, b = runs / "a" / "uniform", runs / "b" / "uniform"
    code, err = cli("eval", "compare", a, b, "--out", tmp_path)
    assert code == 0, err
    doc = json.loads((tmp_path / "compare.json").read_text())
    assert doc["baseline"] == "a" and [r["name"] for r in doc["runs"]] == ["a", "b"]
    assert doc["differing_settings"] == ["lpac checkpoint"] and doc["environments"] == 4 and doc["steps"] == STEPS
    assert sorted(doc["files"]) == ["compare.json", "compare.md", "compare.png"]
    assert (tmp_path / "compare.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    direct = _direct(b, a)
    assert set(doc["by_controller"]) == set(direct) == {"dcvt", "lpac"}
    for c, want in direct.items():
        row = doc["by_controller"][c]["groups"]["uniform"]
        p = row["paired"]["b"]
        assert row["n"] == p["n"] == want["n"] == 4
        np.testing.assert_allclose([row["mean"]["a"], row["mean"]["b"], p["diff"], p["se"], p["ci_lo"], p["ci_hi"]],
                                   [want["base"], want["run"], want["diff"], want["se"], want["lo"], want["hi"]],
                                   rtol=1e-12, atol=1e-15)
        assert (p["wins"], p["ties"]) == (want["wins"], want["ties"])
    assert direct["dcvt"]["ties"] == 4  # DCVT needs no checkpoint: the same rollouts
    assert direct["lpac"]["ties"] == 0 and abs(direct["lpac"]["diff"]) > 1e-3  # another checkpoint, other rollouts
    lp = direct["lpac"]
    md = (tmp_path / "compare.md").read_text()
    assert f"| uniform | 4 | {lp['base']:.3f} | {lp['run']:.3f} | {lp['diff']:+.3f} ± {lp['se']:.3f} " \
           f"[{lp['lo']:+.3f}, {lp['hi']:+.3f}] | {lp['wins']}/4 |" in md
    assert "| 0/4 (4 tied) |" in md and "![paired differences](compare.png)" in md
    # the other run as the baseline, named by its path: every difference changes sign
    code, err = cli("eval", "compare", a, b, "--baseline", b, "--out", tmp_path / "rev")
    assert code == 0, err
    rev = json.loads((tmp_path / "rev" / "compare.json").read_text())
    p = rev["by_controller"]["lpac"]["groups"]["uniform"]["paired"]["a"]
    assert rev["baseline"] == "b"
    np.testing.assert_allclose([p["diff"], p["ci_lo"], p["ci_hi"]], [-lp["diff"], -lp["hi"], -lp["lo"]], rtol=1e-12)


def test_compare_refuses_other_environments_and_missing_runs(runs, tmp_path):
    a = runs / "a" / "uniform"
    out = tmp_path / "out"
    assert_one_line(*cli("eval", "compare", a, runs / "fewer" / "uniform", "--out", out),
                    "runs differ in their environments", "env 3 is in a only")
    assert_one_line(*cli("eval", "compare", a, tmp_path / "missing", "--out", out), "missing: no such run directory")
    assert_one_line(*cli("eval", "compare", a, runs / "b", "--out", out), "holds the suites uniform")
    assert_one_line(*cli("eval", "compare", a, "--out", out), "at least two")
    assert_one_line(*cli("eval", "compare", a, runs / "b" / "uniform", "--baseline", "c", "--out", out), "--baseline")
    # a copy of run a that claims other steps, and one with a NaN cost
    longer, broken = tmp_path / "longer" / "uniform", tmp_path / "broken" / "uniform"
    for d in (longer, broken):
        shutil.copytree(a, d)
    config = json.loads((longer / "config.json").read_text())
    (longer / "config.json").write_text(json.dumps({**config, "steps": STEPS + 1}))
    assert_one_line(*cli("eval", "compare", a, longer, "--out", out), f"runs differ in steps: a ran {STEPS}, longer {STEPS + 1}")
    table = pq.read_table(a / "results.parquet")
    cost = table.column("final_cost").to_numpy().copy()
    cost[5] = np.nan
    pq.write_table(table.set_column(table.column_names.index("final_cost"), "final_cost", pa.array(cost)),
                   broken / "results.parquet")
    assert_one_line(*cli("eval", "compare", a, broken, "--out", out), "results.parquet: final_cost is nan for controller 'lpac', group 'uniform', env 2")
    (broken / "config.json").write_text((a / "config.json").read_text()[:40])  # a truncated config
    assert_one_line(*cli("eval", "compare", a, broken, "--out", out), "config.json: unreadable (JSONDecodeError")
    assert not out.exists()


def test_shared_pairs_a_subset_run_with_a_full_one(runs, tmp_path):
    """--shared pairs run ``fewer`` (the first 3 environments, dcvt only) with run ``a`` on those 3: the
    numbers equal a direct computation on them, and the page says so."""
    a, fewer = runs / "a" / "uniform", runs / "fewer" / "uniform"
    code, err = cli("eval", "compare", a, fewer, "--shared", "--out", tmp_path)
    assert code == 0, err
    doc = json.loads((tmp_path / "compare.json").read_text())
    assert doc["environments"] == 3 and doc["shared_of"] == {"a": 4, "fewer": 3}
    want = _direct(fewer, a)["dcvt"]
    got = doc["by_controller"]["dcvt"]["groups"]["uniform"]
    assert got["n"] == want["n"] == 3
    np.testing.assert_allclose(got["paired"]["fewer"]["diff"], want["diff"], atol=1e-15)
    assert "Paired on the 3 environments every run holds (of a's 4, fewer's 3)" in (tmp_path / "compare.md").read_text()
    # runs that share no environment are refused in one line
    other = tmp_path / "other" / "uniform"
    shutil.copytree(fewer, other)
    table = pq.read_table(other / "results.parquet")
    seeds = table.column("scenario_seed").to_numpy() + 1
    pq.write_table(table.set_column(table.column_names.index("scenario_seed"), "scenario_seed", pa.array(seeds)),
                   other / "results.parquet")
    assert_one_line(*cli("eval", "compare", a, other, "--shared", "--out", tmp_path / "x"), "share no environment")


def test_paired_se_runs_the_environments_the_kept_spread_asks_for(tmp_path):
    """--paired-se S runs ⌈(σ_d / S)²⌉ environments of a suite (σ_d from the kept spread), the first ones,
    capped by --num-envs; S ≤ 0 or NaN is a one-line error."""
    from madp.eval.paired_se import envs_for_se, paired_sd

    sd = paired_sd("uniform")
    assert 0.01 < sd < 0.2
    se = sd / 2  # needs 4 environments
    assert envs_for_se("uniform", se, 1, 50) == 4 and envs_for_se("uniform", se, 1, 3) == 3
    assert envs_for_se("uniform", se, 3, 50) == 2  # 4 spread over 3 groups
    summary_dir = tmp_path / "r"
    run_suite(EvalConfig(suite="uniform", out=str(summary_dir), num_envs=50, steps=2, workers=1, controllers=("dcvt",),
                         paired_se=se), "uniform", progress=False)
    config = json.loads((summary_dir / "uniform" / "config.json").read_text())
    assert config["num_envs"] == 4 and config["env_keys"] == [f"uniform-{i:03d}" for i in range(4)]
    for bad in (0, -1.0, float("nan")):
        assert_one_line(*cli("eval", "--controllers", "dcvt", "--paired-se", str(bad), "--out", tmp_path / "bad"),
                        "--paired-se")
