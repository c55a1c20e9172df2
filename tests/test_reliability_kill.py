"""Fault injection: SIGKILL ``madp datagen``, ``train`` and ``eval`` at random points — the parent
alone (as the OOM killer does, leaving its workers) and the whole process group — then run the same
command again at once. The rerun must not be refused, the killed parent's workers must not outlive
it, and the finished result must be identical to an uninterrupted run's.

The default run kills each command a few times (seeded, so a failure reproduces); ``-m slow`` runs a
longer soak. ``MADP_FAULT_SEED`` picks other kill points.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from madp.datagen import DatagenConfig, run_datagen
from madp.eval.runner import EvalConfig, run_suite
from madp.io.lock import LOCK_FILENAME, pid_running
from madp.sim import SimParams
from madp.training import load_policy, resolve, train
from tests.conftest import one_torch_thread, tiny_dataset

SEED = int(os.environ.get("MADP_FAULT_SEED", "15"))
pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds worker processes through /proc")
ENV = dict(os.environ, OMP_NUM_THREADS="1")


def tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def descendants(pid: int) -> set[int]:
    """Every live descendant of ``pid`` (from /proc)."""
    parent = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                parent[int(d.name)] = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                pass
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = {c for c, pp in parent.items() if pp == p}
        out |= kids
        todo += kids
    return out


class Killer:
    """Runs a command and kills it once ``ready()`` holds, after a random delay; counts the kills."""

    def __init__(self, args: list[str], tmp: Path, seed: int, grace_s: float):
        self.args, self.tmp, self.rng, self.grace_s = args, tmp, random.Random(seed), grace_s
        self.kills = {"parent": 0, "group": 0}

    def run_and_kill(self, mode: str, ready, max_delay_s: float) -> bool:
        """True if the run was killed, False if it finished first (then it must have succeeded)."""
        log = self.tmp / "stderr.log"
        with open(log, "w") as err:
            p = subprocess.Popen(self.args, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True, env=ENV)
        deadline = time.time() + 300
        while p.poll() is None and not ready() and time.time() < deadline:
            time.sleep(0.01)
        time.sleep(self.rng.uniform(0, max_delay_s))
        if p.poll() is not None:
            assert p.returncode == 0, f"a rerun after a kill failed: {log.read_text()[-2000:]}"
            return False
        kids = descendants(p.pid)
        if mode == "parent":
            os.kill(p.pid, signal.SIGKILL)
        else:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        self.kills[mode] += 1
        deadline = time.time() + self.grace_s  # pool workers die at once; a DataLoader worker within its 5 s watchdog
        while any(pid_running(k) for k in kids) and time.time() < deadline:
            time.sleep(0.05)
        assert not any(pid_running(k) for k in kids), "workers outlived their killed parent"
        return True

    def finish(self, args: list[str] | None = None) -> None:
        r = subprocess.run(args or self.args, capture_output=True, text=True, env=ENV)
        assert r.returncode == 0, r.stderr[-2000:]


def hunt(k: Killer, kills: int, attempt, check, reset) -> int:
    """Kill runs until ``kills`` kills happened, alternating parent alone and whole group.

    ``attempt(mode)`` starts the command (as a user would rerun it) and kills it at a random point; when
    a run finishes before its kill, ``check()`` compares the result with the uninterrupted run's and
    ``reset()`` starts afresh. Returns the number of results checked (the last one included)."""
    checked = 0
    while sum(k.kills.values()) < kills:
        mode = "parent" if sum(k.kills.values()) % 2 == 0 else "group"
        if not attempt(mode):
            check()
            checked += 1
            reset()
    return checked


QUICK, SOAK = pytest.param(3, id="quick"), pytest.param(12, id="soak", marks=pytest.mark.slow)


# --- datagen ----------------------------------------------------------------------------------------------
DG = DatagenConfig(480, seed=3, samples_per_shard=240, params=SimParams(world_size=256, num_robots=4, num_features=4))
DG_ARGS = ["--n", "480", "--seed", "3", "--samples-per-shard", "240", "--num-robots", "4", "--num-features", "4",
           "--world-size", "256", "--workers", "2"]


@pytest.fixture(scope="module")
def datagen_reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("dg-ref")
    run_datagen(DG, root, workers=1, progress=False)
    return tree(root)


@pytest.mark.parametrize("kills", [QUICK, SOAK])
def test_datagen_killed_at_random_points_resumes_byte_identical(datagen_reference, tmp_path, kills):
    out = tmp_path / "d"
    k = Killer([sys.executable, "-m", "madp.cli", "datagen", "--out", str(out), *DG_ARGS], tmp_path, SEED, grace_s=0.5)
    records = out / ".datagen" / "shards"

    def count() -> int:
        return len(list(records.glob("*.json"))) if records.exists() else 0

    def attempt(mode: str) -> bool:
        want = count() + k.rng.randrange(0, 2)  # inside this run's first shards (or its start)
        return k.run_and_kill(mode, lambda: count() >= want, 1.0)

    def check() -> None:
        assert tree(out) == datagen_reference

    checked = hunt(k, kills, attempt, check, lambda: shutil.rmtree(out))
    k.finish()
    check()
    print(f"datagen: {k.kills} kills, {checked + 1} results byte-identical")


# --- train ------------------------------------------------------------------------------------------------
TRAIN = dict(epochs=2, batch_size=8, num_workers=1, val_samples=16, checkpoint_every=3, seed=7)
TRAIN_ARGS = ["--epochs", "2", "--batch-size", "8", "--workers", "1", "--val-samples", "16", "--checkpoint-every", "3",
              "--seed", "7", "--threads", "1"]


@pytest.fixture(scope="module")
def train_data(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "train-data")


@pytest.fixture(scope="module")
def train_reference(train_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("train-ref") / "r"
    with one_torch_thread():
        train(resolve("madp", "cpu", data=str(train_data), out=str(out), **TRAIN), progress=False)
    return out


def train_result(run: Path) -> tuple[list, dict]:
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    losses = [(d["step"], d.get("loss"), d.get("val_loss")) for d in lines]
    model, _ = load_policy(run / "checkpoints" / "latest" / "policy.safetensors")
    return losses, model.state_dict()


@pytest.mark.parametrize("kills", [QUICK, SOAK])
def test_train_killed_at_random_points_resumes_identical(train_data, train_reference, tmp_path, kills):
    out = tmp_path / "r"
    base = [sys.executable, "-m", "madp.cli", "train", "--data", str(train_data), "--out", str(out), *TRAIN_ARGS]
    k = Killer(base, tmp_path, SEED + 1, grace_s=12.0)
    ckpts = out / "checkpoints"

    def started() -> bool:
        return (ckpts / "latest").exists() or (ckpts / "latest.old").exists()

    def logged() -> int:
        return len((out / "metrics.jsonl").read_text().splitlines()) if (out / "metrics.jsonl").exists() else 0

    def attempt(mode: str) -> bool:
        k.args = base + (["--resume"] if started() else [])  # what the user would run again
        want = logged() + k.rng.randrange(0, 2)
        return k.run_and_kill(mode, lambda: logged() >= want, 1.5)

    def check() -> None:
        (losses, weights), (ref_losses, ref_weights) = train_result(out), train_result(train_reference)
        assert losses == ref_losses
        assert all(torch.equal(weights[n], ref_weights[n]) for n in ref_weights)
        assert not (out / LOCK_FILENAME).exists()

    checked = hunt(k, kills, attempt, check, lambda: shutil.rmtree(out))
    k.finish(base + (["--resume"] if started() else []))
    check()
    print(f"train: {k.kills} kills, {checked + 1} results identical")


# --- eval -------------------------------------------------------------------------------------------------
EV = dict(num_envs=4, steps=40, controllers=("clairvoyant", "dcvt"))
EV_ARGS = ["--suite", "uniform", "--num-envs", "4", "--steps", "40", "--controllers", "clairvoyant,dcvt", "--workers", "2"]


def eval_result(suite: Path) -> tuple[bytes, list, dict]:
    results = pq.read_table(suite / "results.parquet").drop_columns(["mean_step_ms"]).to_pylist()
    jobs = {p.name: np.load(p)["cost"].tobytes() for p in sorted((suite / "jobs").glob("*.npz"))}
    return (suite / "curves.parquet").read_bytes(), results, jobs


@pytest.fixture(scope="module")
def eval_reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval-ref")
    run_suite(EvalConfig(suite="uniform", out=str(out), workers=1, **EV), "uniform", progress=False)
    return eval_result(out / "uniform")


@pytest.mark.parametrize("kills", [pytest.param(2, id="quick"), pytest.param(8, id="soak", marks=pytest.mark.slow)])
def test_eval_killed_at_random_points_resumes_identical(eval_reference, tmp_path, kills):
    out = tmp_path / "ev"
    k = Killer([sys.executable, "-m", "madp.cli", "eval", "--out", str(out), *EV_ARGS], tmp_path, SEED + 2, grace_s=0.5)
    jobs = out / "uniform" / "jobs"

    def count() -> int:
        return len(list(jobs.glob("*.npz"))) if jobs.exists() else 0

    def attempt(mode: str) -> bool:
        want = count() + k.rng.randrange(0, 3)
        return k.run_and_kill(mode, lambda: count() >= want, 1.0)

    def check() -> None:
        assert eval_result(out / "uniform") == eval_reference

    checked = hunt(k, kills, attempt, check, lambda: shutil.rmtree(out))
    k.finish()
    check()
    print(f"eval: {k.kills} kills, {checked + 1} results identical")
