"""madp datagen: exact counts, determinism across workers, crash-resume, refusals, dataset tools."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from madp.data_schema import Manifest, iter_shard
from madp.data_schema.dataset import convert_dataset, verify_dataset
from madp.datagen import DatagenConfig, make_plan, run_datagen, split_sizes
from madp.sim import SimParams

SMALL = ["--num-robots", "4", "--num-features", "4", "--world-size", "256", "--samples-per-shard", "24"]


def small_cfg(n=120, fmt="mcap", seed=3):
    return DatagenConfig(n, seed=seed, format=fmt, samples_per_shard=24,
                         params=SimParams(world_size=256, num_robots=4, num_features=4))


def madp(*args, **kw):
    return subprocess.run([sys.executable, "-m", "madp.cli", *args], capture_output=True, text=True, **kw)


def tree_bytes(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("ref")
    m = run_datagen(small_cfg(), root, workers=1, progress=False)
    return root, m


def test_plan_counts_are_exact():
    assert split_sizes(100000) == {"train": 70000, "val": 20000, "test": 10000}
    for n in (1, 7, 99, 1001):
        cfg = DatagenConfig(n, samples_per_shard=10)
        assert sum(t.num_samples for t in make_plan(cfg)) == n


def test_exact_samples_split_by_episode(reference):
    root, m = reference
    assert m.num_samples == 120 and m.counts() == {"train": 84, "val": 24, "test": 12}
    seen = {}
    for split in ("train", "val", "test"):
        for p in m.shard_paths(split, root):
            for b in iter_shard(p):
                for e in np.unique(b.episode_id):
                    assert seen.setdefault(int(e), split) == split  # an episode never crosses splits
    steps_ok = all((np.diff(b.step) != 0).any() or len(b.step) == 1 for b in iter_shard(m.shard_paths("train", root)[0]))
    assert steps_ok
    assert m.action_stats is not None and m.action_stats.count == 84 * 4
    assert verify_dataset(root) == 120


def test_samples_are_the_expert_on_the_scenario(reference):
    """A recorded sample's action is the clairvoyant action at its positions (every 5th step)."""
    from madp.datagen.plan import scenario_seed
    from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario

    root, m = reference
    b = next(iter_shard(m.shard_paths("train", root)[0]))
    cfg = small_cfg()
    assert b.scenario_seed[0] == scenario_seed(cfg.seed, "train", 0, 0)
    env = CoverageEnv(Scenario.random(int(b.scenario_seed[0]), cfg.params))
    expert = ClairvoyantCVT()
    assert list(b.step[:3]) == [0, 5, 10]
    for t in range(11):
        u = expert(env)
        if t in (0, 5, 10):
            k = [0, 5, 10].index(t)
            np.testing.assert_array_equal(b.actions[k], u.astype(np.float32))
            np.testing.assert_array_equal(b.positions[k], env.positions_m.astype(np.float32))
            np.testing.assert_array_equal(b.observations[k], env.observations().astype(np.float16))
        env.step(u)


def test_workers_do_not_change_bytes(reference, tmp_path):
    root, _ = reference
    run_datagen(small_cfg(), tmp_path / "w2", workers=2, progress=False)
    assert tree_bytes(tmp_path / "w2") == tree_bytes(root)


def test_parts_merge_to_the_whole(reference, tmp_path):
    root, _ = reference
    n = len(make_plan(small_cfg()))
    assert run_datagen(small_cfg(), tmp_path / "a", workers=1, shards=(0, 2), progress=False) is None
    run_datagen(small_cfg(), tmp_path / "b", workers=1, shards=(2, n), progress=False)
    r = madp("dataset", "merge", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "m"))
    assert r.returncode == 0, r.stderr
    assert tree_bytes(tmp_path / "m") == tree_bytes(root)


def test_kill_9_then_resume_gives_identical_bytes(reference, tmp_path):
    root, _ = reference
    out = tmp_path / "killed"
    args = [sys.executable, "-m", "madp.cli", "datagen", "--n", "120", "--seed", "3", "--out", str(out),
            "--workers", "1", *SMALL]
    for wait_records in (1, 3):
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 120
        while time.time() < deadline:
            recs = list((out / ".datagen" / "shards").glob("*.json")) if out.exists() else []
            if len(recs) >= wait_records:
                time.sleep(0.15)  # land somewhere inside the next shard
                break
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    r = subprocess.run(args, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert tree_bytes(out) == tree_bytes(root)
    assert not list(out.rglob("*.tmp"))


def test_refuses_other_parameters_and_bad_flags(reference, tmp_path):
    root, _ = reference
    from tests.test_reliability_errors import assert_one_line, cli  # in this process: the same error path

    assert_one_line(*cli("datagen", "--n", "121", "--seed", "3", "--out", str(root), *SMALL), "--overwrite")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x.txt").write_text("mine")
    assert_one_line(*cli("datagen", "--n", "10", "--out", str(tmp_path / "junk"), *SMALL), "not empty")
    assert_one_line(*cli("datagen", "--n", "10", "--format", "csv", "--out", str(tmp_path / "x"), *SMALL), "--format")


def test_verify_names_a_corrupt_or_missing_shard(reference, tmp_path):
    root, m = reference
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    shard = m.shard_paths("val", copy)[0]
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0xFF
    shard.write_bytes(bytes(data))
    r = madp("dataset", "verify", str(copy))
    assert r.returncode == 2 and str(shard) in r.stderr
    shard.unlink()
    r = madp("dataset", "verify", str(copy))
    assert r.returncode == 2 and "missing" in r.stderr


def test_convert_keeps_samples_and_manifest_content(reference, tmp_path):
    root, m = reference
    pq = convert_dataset(root, "parquet", tmp_path / "pq")
    back = convert_dataset(tmp_path / "pq", "mcap", tmp_path / "back")
    assert pq.format == "parquet" and pq.counts() == m.counts() and pq.action_stats == m.action_stats
    assert pq.params == m.params and back.counts() == m.counts()
    for split in ("train", "val", "test"):
        for a, b in zip(m.shard_paths(split, root), pq.shard_paths(split, tmp_path / "pq")):
            for x, y in zip(iter_shard(a), iter_shard(b)):
                for f in ("episode_id", "step", "scenario_seed", "actions", "positions", "observations"):
                    np.testing.assert_array_equal(getattr(x, f), getattr(y, f))
    info = json.loads(madp("dataset", "info", str(tmp_path / "pq"), "--json").stdout)
    assert info["num_samples"] == 120 and info["format"] == "parquet"
    table = madp("dataset", "info", str(tmp_path / "pq")).stdout.splitlines()
    assert table[0].startswith(f"{tmp_path / 'pq'}: 120 samples") and [t.split()[0] for t in table[2:5]] == [
        "train", "val", "test"]


def test_packed_launch_is_recorded_and_independent_of_workers(tmp_path):
    """``--launch packed`` starts every episode from a packed layout drawn from its scenario seed: the
    manifest and the reproducing command name it, the bytes do not depend on the worker count, and
    the first recorded positions of an episode are packed. A uniform dataset's plan keeps no
    ``launch`` key (its bytes are those of before the option existed)."""
    from madp.data_schema import iter_shard
    from madp.data_schema.dataset import open_dataset

    cfg = DatagenConfig(96, seed=5, samples_per_shard=24, launch="packed",
                        params=SimParams(world_size=1024, num_robots=8, num_features=4))
    run_datagen(cfg, tmp_path / "w1", workers=1, progress=False)
    run_datagen(cfg, tmp_path / "w2", workers=2, progress=False)
    assert tree_bytes(tmp_path / "w1") == tree_bytes(tmp_path / "w2")
    m = open_dataset(tmp_path / "w1")
    assert m.params["launch"] == "packed" and "--launch packed" in m.created_by
    assert "launch" not in small_cfg().to_dict() and DatagenConfig.from_dict(cfg.to_dict()) == cfg
    shard = sorted((tmp_path / "w1").rglob("*.mcap"))[0]
    first = next(iter_shard(shard, "mcap"))
    starts = first.positions[first.step == first.step.min()][0]
    assert np.median(np.linalg.norm(starts[:, None] - starts[None], axis=-1)) < 512


def test_unknown_launch_gets_one_line(tmp_path):
    r = madp("datagen", "--n", "10", "--launch", "ring", "--out", str(tmp_path / "d"))
    assert r.returncode == 2 and "--launch" in r.stderr and len(r.stderr.strip().splitlines()) == 1
