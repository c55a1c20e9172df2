"""A full disk: datagen and train stop with one line naming the file they could not write, leave no
temporary file and no lock, and — once there is room again — the same command finishes with the bytes
of an uninterrupted run. Needs a small tmpfs (root, mount allowed); skipped where the machine does not
allow one."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from madp.datagen import DatagenConfig, run_datagen
from madp.io.atomic import is_temp
from madp.io.lock import LOCK_FILENAME
from madp.sim import SimParams

from .test_reliability_errors import assert_one_line

DG = DatagenConfig(240, seed=3, samples_per_shard=24, params=SimParams(world_size=256, num_robots=4, num_features=4))
DG_ARGS = ["--n", "240", "--seed", "3", "--samples-per-shard", "24", "--num-robots", "4", "--num-features", "4",
           "--world-size", "256", "--workers", "1"]


def madp(*args):
    r = subprocess.run([sys.executable, "-m", "madp.cli", *map(str, args)], capture_output=True, text=True,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
    return r.returncode, r.stderr


def tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs at tmp_path/disk; ``resize(kib)`` makes room."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("needs root to mount a small tmpfs")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip()})")

    def resize(kib: int) -> None:
        subprocess.run(["mount", "-o", f"remount,size={kib}k", str(mnt)], check=True)

    try:
        yield mnt, resize
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def no_leftovers(root: Path) -> None:
    left = [p for p in root.rglob("*") if is_temp(p) or p.name == LOCK_FILENAME]
    assert not left, left


def test_datagen_on_a_full_disk_then_with_room(small_disk, tmp_path):
    mnt, resize = small_disk
    out = mnt / "d"
    code, err = madp("datagen", "--out", out, *DG_ARGS)  # ~2.8 MB into 1 MiB
    assert_one_line(code, err, str(out), "No space left on device")
    no_leftovers(mnt)
    assert not (out / "manifest.json").exists()
    resize(16 * 1024)
    code, err = madp("datagen", "--out", out, *DG_ARGS)
    assert code == 0, err
    ref = tmp_path / "ref"
    run_datagen(DG, ref, workers=1, progress=False)
    assert tree(out) == tree(ref)


def test_train_on_a_full_disk(small_disk, tmp_path):
    mnt, _ = small_disk
    data = tmp_path / "data"
    run_datagen(DatagenConfig(64, seed=1, samples_per_shard=16, params=SimParams(world_size=256, num_robots=4,
                                                                                  num_features=4)),
                data, workers=1, progress=False)
    filler = mnt / "filler"
    filler.write_bytes(b"\0" * (1024 * 1024 - 200 * 1024))  # leave ~200 KiB: config fits, a checkpoint does not
    run = mnt / "run"
    code, err = madp("train", "--data", data, "--out", run, "--epochs", "1", "--batch-size", "4", "--workers", "0",
                     "--val-samples", "4", "--max-steps-per-epoch", "2")
    line = assert_one_line(code, err, str(run))
    assert "No space left on device" in line or "cannot write" in line
    no_leftovers(mnt)
