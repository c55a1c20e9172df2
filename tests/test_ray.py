"""--ray on a real Ray cluster (local, 2 CPUs, one per module): datagen and eval write what a local run
writes, a worker killed mid-shard is retried by Ray with the same bytes, and without Ray --ray is a
one-line error."""

import logging
import os
import shlex
import signal
import sys
import threading
import time

import numpy as np
import pyarrow.parquet as pq
import pytest

from madp.commands.main import optional_ray_value
from madp.data_schema.dataset import verify_dataset
from madp.datagen import DatagenConfig, run_datagen
from madp.io.atomic import is_temp
from madp.sim import SimParams
from tests.conftest import REPO, in_ci
from tests.guides import first_commands, small
from tests.test_reliability_errors import assert_one_line, cli

#: Small swarms (2 robots, 2 features, 256 m world) in small shards: 400 samples in 20 shards (14 train, 4 val,
#: 2 test), 2 s locally.
TINY = ["--num-robots", "2", "--num-features", "2", "--world-size", "256", "--samples-per-shard", "20"]


def tree_bytes(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def cluster():
    """One local Ray instance with 2 CPUs for the module; madp's --ray uses the connection it finds."""
    try:
        import ray
    except ImportError:
        if in_ci():
            pytest.fail('Ray is not installed; CI must install madp[ray] and run these tests', pytrace=False)
        pytest.skip('Ray is not installed (pip install "madp[ray]")')
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    yield ray
    ray.shutdown()


def test_datagen_on_ray_writes_the_local_bytes(cluster, tmp_path):
    args = ["datagen", "--n", "400", "--seed", "5", *TINY]
    code, err = cli(*args, "--out", tmp_path / "local", "--workers", "1")
    assert code == 0, err
    code, err = cli(*args, "--out", tmp_path / "ray", "--ray")
    assert code == 0, err
    local, remote = tree_bytes(tmp_path / "local"), tree_bytes(tmp_path / "ray")
    assert len([k for k in local if k.endswith(".mcap")]) == 20
    assert remote == local  # shards, shard records, plan and manifest (with its checksums)
    assert verify_dataset(tmp_path / "ray") == 400
    # resume: a lost shard is made again on Ray, and only that one
    (tmp_path / "ray" / "val" / "shard-00002.mcap").unlink()
    (tmp_path / "ray" / "manifest.json").unlink()
    kept = (tmp_path / "ray" / "train" / "shard-00000.mcap").stat().st_mtime_ns
    code, err = cli(*args, "--out", tmp_path / "ray", "--ray")
    assert code == 0, err
    assert tree_bytes(tmp_path / "ray") == local
    assert (tmp_path / "ray" / "train" / "shard-00000.mcap").stat().st_mtime_ns == kept


def test_the_ray_guides_first_command_runs_on_a_fresh_clone(cluster, tmp_path, monkeypatch):
    """docs/guides/ray.md opens with a one-machine run (at small sizes here, on the module's Ray)."""
    [command] = first_commands(REPO / "docs" / "guides" / "ray.md")
    words = shlex.split(small(command))
    assert words[:2] == ["madp", "datagen"] and words[-1] == "--ray"
    monkeypatch.chdir(tmp_path)
    code, err = cli(*words[1:])
    assert code == 0, err
    assert verify_dataset(tmp_path / "data" / "ray") == 16


def test_a_worker_killed_mid_shard_is_retried_with_the_same_bytes(cluster, tmp_path):
    cfg = DatagenConfig(400, seed=7, samples_per_shard=100, params=SimParams(world_size=256, num_robots=2, num_features=2))
    run_datagen(cfg, tmp_path / "local", workers=1, progress=False)
    out = tmp_path / "ray"
    failed = []

    def run():
        try:
            run_datagen(cfg, out, ray="local", progress=False)
        except BaseException as e:  # noqa: BLE001 - reported by the test below
            failed.append(e)

    thread = threading.Thread(target=run)
    thread.start()
    killed = None
    deadline = time.time() + 120
    while killed is None and thread.is_alive() and time.time() < deadline:
        for p in out.rglob("shard-*.tmp") if out.exists() else ():
            pid = int(p.name.split(".")[-2])  # shard-NNNNN.mcap.<pid>.tmp: the Ray worker writing it
            if not is_temp(p) or pid == os.getpid():
                continue
            os.kill(pid, signal.SIGKILL)
            time.sleep(0.2)
            if p.exists():  # the writer died before its rename: killed mid-shard
                killed = (pid, p.name)
                break
        time.sleep(0.005)
    thread.join(timeout=180)
    assert not thread.is_alive() and not failed, failed
    assert killed is not None, "no shard was being written when the test looked"
    assert tree_bytes(out) == tree_bytes(tmp_path / "local")  # the dead attempt's temporary file is gone too
    assert verify_dataset(out) == 400


@pytest.mark.parametrize("steps", [20, pytest.param(100, marks=pytest.mark.slow)])  # 100: the figures (~70 s here)
def test_eval_on_ray_writes_the_local_tables(cluster, tmp_path, steps):
    args = ["eval", "--suite", "uniform", "--num-envs", "4", "--steps", steps]
    code, err = cli(*args, "--out", tmp_path / "local", "--workers", "1")
    assert code == 0, err
    code, err = cli(*args, "--out", tmp_path / "ray", "--ray")
    assert code == 0, err
    local, remote = tmp_path / "local" / "uniform", tmp_path / "ray" / "uniform"
    assert (remote / "curves.parquet").read_bytes() == (local / "curves.parquet").read_bytes()
    a = pq.read_table(local / "results.parquet").to_pandas()
    b = pq.read_table(remote / "results.parquet").to_pandas()
    assert len(a) == 16 and set(a.controller) == {"clairvoyant", "dcvt", "lpac", "madp"}
    timing = ["mean_step_ms"]  # wall time: the only column that may differ
    assert a.drop(columns=timing).equals(b.drop(columns=timing))
    for f in sorted((local / "jobs").glob("*.npz")):
        np.testing.assert_array_equal(np.load(f)["cost"], np.load(remote / "jobs" / f.name)["cost"])
    assert sorted(p.name for p in (remote / "jobs").iterdir()) == sorted(p.name for p in (local / "jobs").iterdir())


def test_ray_without_an_address_means_a_local_ray():
    assert optional_ray_value(["datagen", "--ray"]) == ["datagen", "--ray", "local"]
    assert optional_ray_value(["datagen", "--ray", "--n", "5"]) == ["datagen", "--ray", "local", "--n", "5"]
    assert optional_ray_value(["eval", "--ray", "auto"]) == ["eval", "--ray", "auto"]
    assert optional_ray_value(["eval", "--ray=10.0.0.1:6379"]) == ["eval", "--ray=10.0.0.1:6379"]


@pytest.mark.parametrize("command", [["datagen", "--n", "10"], ["eval", "--steps", "1"]])
@pytest.mark.parametrize("address", [[], ["auto"]])
def test_ray_not_installed_is_one_line(monkeypatch, tmp_path, command, address):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    code, err = cli(*command, "--out", tmp_path / "out", "--ray", *address)
    assert_one_line(code, err, 'pip install "madp[ray]"')
    assert not (tmp_path / "out").exists()


def test_bench_measures_the_ray_overhead_per_task(cluster):
    from madp.datagen.bench import bench_ray_overhead

    r = bench_ray_overhead(shard_samples=8, repeats=1, trivial=2)
    assert r["cpus"] == 2 and r["repeats"] == 1 and r["shard_samples"] == 8
    assert 0 < r["trivial_task_ms"] < 5000 and 0 < r["shard_local_s"] and 0 < r["shard_ray_s"]
    assert r["shard_ratio"] == pytest.approx(r["shard_ray_s"] / r["shard_local_s"])
    assert 0 <= r["shard_dispatch_ms"] < 1e3 * r["shard_ray_s"]
