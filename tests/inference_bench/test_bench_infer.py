"""madp bench infer: the closed-loop sweep, S*, the plot and the latency rows (structure, not speed)."""

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from madp.errors import SettingError
from madp.inference_bench.bench import bench_infer_all, format_table, parse_grid
from tests.test_reliability_errors import assert_one_line, cli


def test_parse_grid_always_adds_the_ddim50_baseline():
    assert parse_grid("dpm++:10,5;ddim:10") == {"dpm++": (5, 10), "ddim": (10, 50)}
    assert parse_grid("dpm++:3") == {"dpm++": (3,), "ddim": (50,)}
    for bad in ("euler:5", "dpm++:", "dpm++:a", "ddim:0"):
        with pytest.raises(SettingError, match="^grid: "):
            parse_grid(bad)


def test_sweep_s_star_plot_and_latency(tmp_path, checkpoints):
    r = bench_infer_all(str(checkpoints / "madp.safetensors"), tmp_path, {"dpm++": (1, 2)}, envs=3, steps=2,
                        repeats=1, workers=1, presets=("cpu",), progress=False)
    sw = r["sweep"]
    rows = {(x["sampler"], x["steps"]): x for x in sw["rows"]}
    assert set(rows) == {("ddim", 50), ("dpm++", 1), ("dpm++", 2)}
    base = rows[("ddim", 50)]
    assert base["diff_vs_baseline"] == 0 and base["within_one_se"] and base["n"] == 3
    assert sw["baseline"]["se"] > 0 and sw["s_star"]["ddim"] == 50
    # the statistics are those of the suites' own tables
    res = pq.read_table(tmp_path / "dpm++-2" / "uniform" / "results.parquet").to_pandas()
    assert np.isclose(rows[("dpm++", 2)]["mean"], res.final_cost.mean())
    assert set(res.sampler) == {"dpm++"} and set(res.sampling_steps) == {2}
    within = [s for s in (1, 2) if rows[("dpm++", s)]["within_one_se"]]
    assert sw["s_star"]["dpm++"] == (min(within) if within else None)
    # the baseline run also holds the centralized-masked pass
    base_res = pq.read_table(tmp_path / "ddim-50" / "uniform" / "results.parquet").to_pandas()
    assert set(base_res.controller) == {"madp", "madp_central"}
    assert (tmp_path / "cost_vs_steps.png").stat().st_size > 5000
    lat = {(x["mode"], x["sampler"], x["num_steps"]) for x in r["latency"]}
    assert ("decentralized", "ddim", 50) in lat and ("centralized", "ddim", 50) in lat
    assert r["best"]["sampler"] in ("ddim", "dpm++")
    lines = format_table(r)  # what madp bench infer prints: the baseline, one row per setting, the latencies
    assert "DDIM-50" in lines[0] and sum(x.startswith("dpm++") for x in lines) == 2
    assert sum(x.startswith("cpu") for x in lines) == len(r["latency"])
    # a second call only reads the finished suites
    stamp = (tmp_path / "dpm++-2" / "uniform" / "results.parquet").stat().st_mtime_ns
    again = bench_infer_all(str(checkpoints / "madp.safetensors"), tmp_path, {"dpm++": (2,)}, envs=3, steps=2,
                            repeats=1, workers=1, presets=(), progress=False)
    assert again["sweep"]["rows"][0]["mean"] == sw["rows"][0]["mean"]
    assert json.loads((tmp_path / "dpm++-2" / "uniform" / "config.json").read_text())["sampler"] == "dpm++"
    assert stamp <= (tmp_path / "dpm++-2" / "uniform" / "results.parquet").stat().st_mtime_ns


def test_bench_infer_cli_bad_grid_is_one_line(tmp_path):
    assert_one_line(*cli("bench", "infer", "--grid", "euler:3", "--sweep-out", tmp_path), "--grid")


def test_no_sweep_times_every_grid_setting_on_the_device():
    r = bench_infer_all(None, "unused", {"dpm++": (2,)}, repeats=1, presets=("cpu",), sweep=False, device="cpu")
    assert r["sweep"] is None and r["device"] == "cpu"
    assert sorted((x["mode"], x["sampler"], x["num_steps"], x["device"]) for x in r["latency"]) == [
        (m, s, k, "cpu") for m in ("centralized", "decentralized") for s, k in (("ddim", 50), ("dpm++", 2))]


@pytest.mark.parametrize("args,needle", [
    (("bench", "infer", "--presets", "gpu"), "--presets"),
    (("bench", "infer", "--device", "tpu", "--no-sweep"), "--device"),
    (("eval", "--device", "cuda:x"), "--device"),
    (("eval", "--suite", "uniform,moon"), "--suite"),
    (("rollout", "--scenario", "s.json", "--device", "mps"), "--device"),
])
def test_device_presets_and_suite_lists_are_checked_in_one_line(tmp_path, args, needle):
    assert_one_line(*cli(*args, "--out", tmp_path / "o"), needle)


def test_eval_on_a_cuda_device_this_machine_lacks_is_one_line(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    assert_one_line(*cli("eval", "--device", "cuda", "--out", tmp_path), "--device cuda", "no CUDA GPU")


def test_selection_latency_has_a_row_per_candidates_and_rule(tmp_path):
    """``--candidates 1,2,2:2``: K = 1 without selection, then every rule at K = 2 at the default S
    (3) and at S = 2 (structure, not speed)."""
    from madp.inference_bench.bench import bench_select, parse_candidates

    assert parse_candidates("16,1,4") == ((1, None), (4, None), (16, None))
    assert parse_candidates("8,4:3") == ((4, 3), (8, None))
    for bad in ("0,4", "a", "", "4:0", "4:x"):
        with pytest.raises(SettingError, match="^candidates: "):
            parse_candidates(bad)
    assert_one_line(*cli("bench", "infer", "--no-sweep", "--candidates", "1,x", "--presets", "cpu"), "--candidates")
    rows = bench_select(parse_candidates("1,2,2:2"), repeats=1, threads=1, num_robots=8)
    # the shipped policy file carries a critic (no map prior): its rules are timed too
    rules = ["explore", "critic", "critic_hood", "oracle", "oracle_hood", "oracle_cell", "oracle_joint"]
    assert [(r["candidates"], r["num_steps"], r["select"]) for r in rows] == [
        (1, 3, "none"), *[(2, 3, x) for x in rules], *[(2, 2, x) for x in rules]]
    assert all(r["latency_s"] > 0 and r["num_robots"] == 8 for r in rows)
    lines = format_table({"sweep": None, "swept": False, "paper_latency_s": 0.36, "device": "cpu", "latency": [],
                          "selection": rows})
    assert sum(x.strip().startswith("2  2  ") for x in lines) == len(rules) == sum(x.strip().startswith("2  3  ") for x in lines)
    assert any("K" in x and "select" in x for x in lines)
