"""madp eval: suites, identical environments, learned policies, resume, outputs and errors."""

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from madp.datagen.plan import DATASET_SEED_BITS
from madp.eval.runner import EvalConfig, available_controllers, plan_jobs, run_batch, run_job, run_suite
from madp.eval.suites import EVAL_SEED_BIT, LAUNCHES, suite_envs
from madp.models import MADP, lpac_config, madp_config
from madp.models.lpac import LPAC
from madp.policies import SamplingSettings
from madp.sim import CoverageEnv, DecentralizedCVT
from madp.sim.launch import D4_SIZE, d4_points
from madp.training.checkpoint import save_policy
from tests.eval.conftest import META
from tests.test_reliability_errors import assert_one_line, cli


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


def test_symmetry_suite_images_are_the_same_world():
    """Each ``symmetry`` environment is its layout's environment moved by one of the world's 8
    symmetries, robots on the world's edge included (``line`` spans x = 0 .. 1024): the decentralized
    CVT, a deterministic function of the state, moves every image's robots to the images of the
    layout's positions and leaves every image at the layout's cost. So a difference between images'
    costs is the policy's, not the world's (docs/reports/2026-12-03-packed-starts.md)."""
    envs = {e.key: e for e in suite_envs("symmetry", 1)}
    for layout in ("line", "square"):
        images = [CoverageEnv(envs[f"{layout}_d4-{g}-000"].scenario()) for g in range(D4_SIZE)]
        base, dcvt = images[0], DecentralizedCVT()  # image 0: the layout itself
        for _ in range(6):
            for env in images:
                env.step(dcvt(env))
        for g, env in enumerate(images):
            expect = d4_points(base.positions_m, g, base.params.world_size)
            np.testing.assert_allclose(env.positions_m, expect, atol=1e-6, err_msg=f"{layout} image {g}")
            assert env.normalized_cost() == pytest.approx(base.normalized_cost(), rel=1e-9)


def test_cities_suite_reads_city_files(cities_dir):
    envs = suite_envs("cities", 50, cities_dir)
    assert len(envs) == 40
    sc = envs[[e.group for e in envs].index("portland_oregon")].scenario()
    assert len(sc.features) == 166 and sc.params.num_robots == 32
    shipped = suite_envs("cities", 50)  # the copy inside the package
    assert [e.group for e in shipped] == [e.group for e in envs]


def test_eval_end_to_end_resume_and_identical_envs(tmp_path, checkpoints):
    cfg = EvalConfig(suite="launch", out=str(tmp_path), num_envs=1, steps=12, workers=1, record=1,
                     sampling=SamplingSettings(sampling_steps=3),
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
    # the sampler and S are named in the tables, the summary and the recordings (MADP only)
    madp_rows = results[results.controller.str.startswith("madp")]
    assert (madp_rows.sampler == cfg.sampling.sampler).all() and (madp_rows.sampling_steps == 3).all()
    assert (results[~results.controller.str.startswith("madp")].sampler == "").all()
    summary = json.loads((d / "summary.json").read_text())
    assert summary["sampling"]["madp"] == {"sampler": cfg.sampling.sampler, "sampling_steps": 3, "frame": "d4",
                                           "select": "explore", "candidates": 4}  # the evaluation default
    assert "S = 3" in (d / "summary.md").read_text()
    from mcap.reader import make_reader

    with open(d / "rollouts" / "uniform-000-madp.mcap", "rb") as f:
        md = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["madp.rollout"]
    assert (md["sampler"], md["sampling_steps"]) == (cfg.sampling.sampler, "3")
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


def test_new_checkpoint_reruns_only_its_controllers(tmp_path, checkpoints):
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), num_envs=2, steps=3, workers=1, record=1,
                     sampling=SamplingSettings(sampling_steps=2),
                     controllers=("dcvt", "lpac", "madp_central"),
                     lpac=str(checkpoints / "lpac.safetensors"), madp=str(checkpoints / "madp.safetensors"))
    run_suite(cfg, "uniform", progress=False)
    d = tmp_path / "uniform"
    jobs = d / "jobs"
    stamp = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in jobs.glob("*.npz")}
    torch.manual_seed(1)
    retrained = LPAC(lpac_config("cpu"))
    retrained.set_action_stats(torch.zeros(2), torch.full((2,), 2.0))
    save_policy(tmp_path / "lpac2.safetensors", retrained, "lpac", META)
    cfg2 = EvalConfig(**{**cfg.__dict__, "lpac": str(tmp_path / "lpac2.safetensors")})
    with pytest.raises(ValueError, match="lpac checkpoint"):
        run_suite(cfg2, "uniform", progress=False)
    run_suite(cfg2, "uniform", overwrite=True, progress=False)
    again = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in jobs.glob("*.npz")}
    assert set(again) == set(stamp)
    rerun = sorted(n for n in stamp if again[n] != stamp[n])  # files are written by rename: a new inode
    assert rerun == sorted(n for n in stamp if n.endswith("-lpac.npz")) and len(rerun) == 2
    assert (d / "rollouts" / "uniform-000-lpac.mcap").exists()
    saved = json.loads((d / "config.json").read_text())["checkpoints"]
    assert saved["lpac"]["path"].endswith("lpac2.safetensors") and saved["madp"]["path"].endswith("madp.safetensors")


def test_eval_cli_errors_are_one_line(tmp_path, checkpoints):
    """In this process (as ``madp`` runs them): exit 2, one line naming the flag or file."""
    def run(*args):
        return cli("eval", "--out", tmp_path, "--num-envs", 1, "--steps", 2, *args)

    assert_one_line(*run("--controllers", "madp", "--madp", tmp_path / "missing.safetensors"), "missing.safetensors")
    assert_one_line(*run("--controllers", "madp", "--madp", checkpoints / "lpac.safetensors"), "expected madp")
    assert_one_line(*run("--suite", "moon"), "--suite")
    assert_one_line(*run("--controllers", "dcvt,foo"), "foo")
    assert_one_line(*run("--controllers", "dcvt", "--sampler", "euler"), "--sampler")
    assert_one_line(*run("--controllers", "dcvt", "--sampler", "dpm++", "--eta", "0.5"), "deterministic")
    assert_one_line(*run("--suite", "scale", "--groups", "N32_F999", "--controllers", "dcvt"), "N32_F999")


def test_groups_run_a_part_of_the_suite_on_the_same_environments(tmp_path):
    """--groups runs the named groups' environments, exactly as the whole suite runs them."""
    whole = EvalConfig(suite="launch", out=str(tmp_path / "whole"), num_envs=2, steps=4, workers=1, controllers=("dcvt",))
    part = EvalConfig(**{**whole.__dict__, "out": str(tmp_path / "part"), "groups": ("line",)})
    run_suite(whole, "launch", progress=False)
    run_suite(part, "launch", progress=False)
    a = pq.read_table(tmp_path / "whole" / "launch" / "results.parquet").to_pandas()
    b = pq.read_table(tmp_path / "part" / "launch" / "results.parquet").to_pandas()
    assert list(b.group) == ["line", "line"]
    line = a[a.group == "line"].reset_index(drop=True)
    assert list(b.scenario_seed) == list(line.scenario_seed) and list(b.final_cost) == list(line.final_cost)
    with pytest.raises(ValueError, match="other settings \\(env_keys"):  # another part: other environments
        run_suite(EvalConfig(**{**part.__dict__, "groups": ("square",)}), "launch", progress=False)


@pytest.mark.parametrize("controller,sampler,eta,fixed", [("lpac", "ddim", 0.0, False), ("madp_central", "ddim", 0.5, False),
                                                          ("madp", "dpm++", 0.0, False), ("madp", "ddim", 0.5, False),
                                                          ("madp", "dpm++", 0.0, True)])
def test_batched_rollouts_match_lone_rollouts(tmp_path, checkpoints, controller, sampler, eta, fixed):
    """Learned controllers run several environments per policy call; each keeps its own noise."""
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), steps=4,
                     sampling=SamplingSettings(sampler=sampler, sampling_steps=3, eta=eta, fixed_noise=fixed),
                     lpac=str(checkpoints / "lpac.safetensors"), madp=str(checkpoints / "madp.safetensors"))
    envs = suite_envs("uniform", 3)
    run_batch(cfg, envs, controller, tmp_path / "batch")
    for e in envs:
        run_job(cfg, e, controller, tmp_path / "lone")
        a = np.load(tmp_path / "batch" / "jobs" / f"{e.key}-{controller}.npz")["cost"]
        b = np.load(tmp_path / "lone" / "jobs" / f"{e.key}-{controller}.npz")["cost"]
        np.testing.assert_allclose(a, b, rtol=1e-5)  # float rounding only, not other noise
    assert len({float(np.load(tmp_path / "batch" / "jobs" / f"{e.key}-{controller}.npz")["cost"][-1])
                for e in envs}) == 3  # three different environments, not one repeated


def test_plan_batches_learned_controllers_of_equal_swarm_size(tmp_path):
    envs = suite_envs("launch", 10)  # 3 groups x 10, all N = 32
    tasks = plan_jobs(envs, ("dcvt", "lpac"), tmp_path, record=1, batch=4)
    dcvt = [t for t in tasks if t[0] == "dcvt"]
    assert len(dcvt) == 30 and all(len(es) == 1 for _, es, _ in dcvt)
    lpac = [[e.key for e in es] for c, es, _ in tasks if c == "lpac"]
    assert lpac[0] == ["uniform-000"] and [t for c, _, t in tasks if c == "lpac"][0]  # recorded alone
    assert lpac[1] == [f"uniform-00{i}" for i in range(1, 5)] and lpac[3] == ["uniform-009", "square-000", "square-001", "square-002"]
    assert sorted(k for ks in lpac for k in ks) == sorted(e.key for e in envs)
    scale = plan_jobs(suite_envs("scale", 3), ("lpac",), tmp_path, record=0, batch=8)
    assert all(len({e.params.num_robots for e in es}) == 1 for _, es, _ in scale)  # a batch never mixes N
    (tmp_path / "jobs").mkdir()
    (tmp_path / "jobs" / "uniform-002-lpac.npz").touch()
    again = [[e.key for e in es] for c, es, _ in plan_jobs(envs, ("lpac",), tmp_path, record=1, batch=4)]
    assert again[1] == ["uniform-001", "uniform-003", "uniform-004"]  # same chunk, minus the finished one


def test_fixed_noise_makes_the_policy_a_function_of_the_state(checkpoints):
    """--fixed-noise: the same state gives the same action at every step of an episode (a fresh
    draw per step would not); a new episode (reset) draws new noise."""
    from madp.policies import MADPPolicy, SamplingSettings, load
    from madp.sim import CoverageEnv

    model, _ = load(checkpoints / "madp.safetensors", "madp")
    env = CoverageEnv(suite_envs("uniform", 1)[0].scenario())
    fixed = MADPPolicy(model, "decentralized", SamplingSettings("dpm++", 3, fixed_noise=True), seed=7)
    fresh = MADPPolicy(model, "decentralized", SamplingSettings("dpm++", 3), seed=7)
    a, b = fixed(env), fixed(env)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fresh(env), a)  # the same first draw from the same seed ...
    assert np.abs(fresh(env) - b).max() > 1e-3     # ... but the next one differs
    fixed.reset(8)
    assert np.abs(fixed(env) - a).max() > 1e-3
