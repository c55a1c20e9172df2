"""One job per output directory: the advisory lock, workers that die with their parent, temporary
names unique per writer ("a second writer")."""

from __future__ import annotations

import fcntl
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from madp.data_schema.dataset import convert_dataset
from madp.datagen import DatagenConfig, run_datagen
from madp.io.atomic import is_temp, temp_path
from madp.io.lock import LOCK_FILENAME, DirectoryLocked, locked_dir, pid_running
from madp.sim import SimParams

from .test_reliability_errors import assert_one_line, cli

SMALL = ["--num-robots", "4", "--num-features", "4", "--world-size", "256", "--samples-per-shard", "24"]


def small_cfg(n=72, seed=3):
    return DatagenConfig(n, seed=seed, samples_per_shard=24, params=SimParams(world_size=256, num_robots=4, num_features=4))


def hold_lock(directory: Path) -> int:
    """Take the directory's lock as another job would (a separate open file description), pid inside."""
    directory.mkdir(parents=True, exist_ok=True)
    fd = os.open(directory / LOCK_FILENAME, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.write(fd, f"{os.getpid()}\n".encode())
    return fd


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    run_datagen(small_cfg(), root, workers=1, progress=False)
    return root


def test_every_writing_command_refuses_a_locked_directory_naming_the_holder(dataset, tmp_path):
    locked = tmp_path / "busy"
    fd = hold_lock(locked)
    pid = f"pid {os.getpid()}"
    try:
        assert_one_line(*cli("datagen", "--n", "24", "--out", locked, *SMALL), str(locked), pid)
        assert_one_line(*cli("dataset", "convert", dataset, "--to", "parquet", "--out", locked), pid)
        assert_one_line(*cli("dataset", "merge", dataset, "--out", locked), pid)
        assert_one_line(*cli("train", "--data", dataset, "--out", locked, "--epochs", "1", "--batch-size", "4",
                             "--workers", "0"), pid)
        suite = tmp_path / "ev" / "uniform"
        os.close(fd)
        fd = hold_lock(suite)
        assert_one_line(*cli("eval", "--suite", "uniform", "--num-envs", "1", "--steps", "2", "--controllers", "dcvt",
                             "--workers", "1", "--out", tmp_path / "ev"), pid)
    finally:
        os.close(fd)
    assert sorted(p.name for p in locked.iterdir()) == [LOCK_FILENAME]  # nothing was written


def test_two_datagen_runs_on_one_directory(tmp_path):
    """The issue: both ran, and one exited 0 without a manifest. Now one runs, the other is refused."""
    out = tmp_path / "d"
    args = [sys.executable, "-m", "madp.cli", "datagen", "--n", "480", "--seed", "3", "--out", str(out), "--workers", "1",
            *SMALL]
    import madp.datagen  # noqa: F401 - imported before the race, so the second run below reaches the lock at once

    a = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not (out / LOCK_FILENAME).exists() and a.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    # the second run from this process: a new one spends seconds importing, and the first run (a few
    # seconds of compiled simulation) could be done by then
    refused = cli(*args[3:])
    a.wait(timeout=300)
    assert a.returncode == 0, a.stderr.read()
    assert_one_line(*refused, f"pid {a.pid}")
    assert (out / "manifest.json").exists() and not (out / LOCK_FILENAME).exists()


def test_a_stale_lock_file_does_not_block_and_a_finished_job_leaves_none(tmp_path):
    out = tmp_path / "d"
    out.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (out / LOCK_FILENAME).write_text(f"{dead.pid}\n")  # left by a job killed with -9
    run_datagen(small_cfg(24), out, workers=1, progress=False)
    assert (out / "manifest.json").exists() and not (out / LOCK_FILENAME).exists()
    convert_dataset(out, "parquet", tmp_path / "pq")
    assert not (tmp_path / "pq" / LOCK_FILENAME).exists()


def test_a_job_refused_at_once_leaves_no_directory(tmp_path):
    out = tmp_path / "new"
    with pytest.raises(ValueError):
        with locked_dir(out):
            raise ValueError("refused")
    assert not out.exists()


def test_lock_held_by_orphaned_children_is_waited_for(tmp_path):
    """A forked child (a DataLoader worker) keeps its dead parent's lock until it exits: the next job
    waits for it instead of refusing a directory nobody writes any more."""
    script = textwrap.dedent(f"""
        import os, signal, time
        from madp.io.lock import locked_dir
        with locked_dir({str(tmp_path / "d")!r}):
            if os.fork() == 0:
                time.sleep(1.5)
                os._exit(0)
            print("locked", flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    assert p.wait(timeout=60) == -signal.SIGKILL  # (not communicate(): the child holds the pipe too)
    t0 = time.monotonic()
    with locked_dir(tmp_path / "d"):
        waited = time.monotonic() - t0
    assert 0.3 < waited < 10, waited


def test_a_running_holder_is_refused_at_once(tmp_path):
    fd = hold_lock(tmp_path / "d")
    try:
        t0 = time.monotonic()
        with pytest.raises(DirectoryLocked, match=f"pid {os.getpid()}"):
            with locked_dir(tmp_path / "d", flag="--out"):
                pass
        assert time.monotonic() - t0 < 1
    finally:
        os.close(fd)


@pytest.mark.parametrize("fallback", [False, True], ids=["prctl", "parent-pid watch"])
def test_workers_exit_when_their_parent_is_killed(tmp_path, fallback):
    """The pools' initializer: a worker whose parent gets kill -9 ends at once (prctl on Linux, a
    parent-pid watch elsewhere) instead of finishing its task and writing files a rerun writes."""
    pidfile = tmp_path / "worker.pid"
    script = textwrap.dedent(f"""
        import multiprocessing as mp, os, signal, time
        from madp.io import workers

        def init(parent):
            if {fallback}:
                workers._prctl_pdeathsig = lambda: False
            workers.die_with_parent(parent)

        def task(_):
            open({str(pidfile)!r}, "w").write(str(os.getpid()))
            time.sleep(60)

        if __name__ == "__main__":
            pool = mp.get_context("spawn").Pool(1, initializer=init, initargs=(os.getpid(),))
            pool.apply_async(task, (0,))
            while not os.path.exists({str(pidfile)!r}):
                time.sleep(0.02)
            time.sleep(0.1)
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    (tmp_path / "s.py").write_text(script)
    p = subprocess.run([sys.executable, str(tmp_path / "s.py")], timeout=120)
    assert p.returncode == -signal.SIGKILL
    worker = int(pidfile.read_text())
    deadline = time.time() + 5
    while pid_running(worker) and time.time() < deadline:
        time.sleep(0.05)
    assert not pid_running(worker), "the worker outlived its parent"


def test_temporary_names_are_unique_per_writer(tmp_path):
    a = temp_path(tmp_path / "shard-00000.mcap")
    assert str(os.getpid()) in a.name and is_temp(a) and a.parent == tmp_path
    assert not is_temp(tmp_path / "notes.tmp") and not is_temp(tmp_path / "shard-00000.mcap")
    assert is_temp(temp_path(tmp_path / "job.npz", ".npz"))
