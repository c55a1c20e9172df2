"""Every user-facing failure ends in one line ``madp: error: …`` naming the file or flag, exit 2.

The failure cases: damaged or foreign checkpoints on ``train --resume`` (never torch's advice to
load less safely), option values that would divide by zero or run no step, scenarios whose J(0) is 0,
sizes that cannot be allocated, absurd sample counts, typer's range errors.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from madp.cli import main
from madp.training import resolve, train
from tests.conftest import tiny_dataset

REPO = Path(__file__).resolve().parents[1]
SHIPPED_LPAC = REPO / "madp" / "checkpoints" / "lpac-cpu.safetensors"


def cli(*args) -> tuple[int, str]:
    """Run ``madp ARGS`` in this process: (exit status, stderr). Any other exception propagates."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as e:
            code = e.code
    return code, err.getvalue()


def cli_subprocess(*args, memory_gib: int = 8, timeout: float = 120) -> tuple[int, str]:
    """Run ``madp ARGS`` as its own process, under an address-space limit (an unchecked size then
    fails fast here instead of exhausting the machine)."""
    limit = memory_gib << 30

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    r = subprocess.run([sys.executable, "-m", "madp.cli", *map(str, args)], capture_output=True, text=True,
                       preexec_fn=cap, timeout=timeout, env=dict(os.environ, OMP_NUM_THREADS="1"))
    return r.returncode, r.stderr


def assert_one_line(code: int, err: str, *needles: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2, (code, err[-2000:])
    assert len(lines) == 1 and lines[0].startswith("madp: error: "), err[-2000:]
    assert "Traceback" not in err and "weights_only=False" not in err and "Aborted" not in err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


# --- train --resume with a damaged or foreign checkpoint -------------------------------------------
@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "data")


TRAIN = ["--epochs", "1", "--batch-size", "8", "--workers", "0", "--val-samples", "8"]


@pytest.fixture(scope="module")
def run(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "r"
    train(resolve("madp", "cpu", data=str(dataset), out=str(out), epochs=1, batch_size=8, num_workers=0, val_samples=8,
                  max_steps_per_epoch=3), progress=False)
    return out


class Evil:
    """A pickle that would run a command when loaded without weights_only."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _damage(latest: Path, case: str, tmp: Path) -> str:
    """Damage checkpoint ``latest`` in one way; return the file the error must name."""
    state, model = latest / "state.pt", latest / "model.safetensors"
    if case == "truncated state.pt":
        state.write_bytes(state.read_bytes()[:300])
        return str(state)
    if case == "empty state.pt":
        state.write_bytes(b"")
        return str(state)
    if case == "garbage state.pt":
        state.write_bytes(os.urandom(4000))
        return str(state)
    if case == "state.pt of a list":
        torch.save([1, 2, 3], state)
        return str(state)
    if case == "state.pt without a key":
        s = torch.load(state, weights_only=True)
        del s["optimizer"]
        torch.save(s, state)
        return str(state)
    if case == "optimizer of another shape":
        s = torch.load(state, weights_only=True)
        k = next(iter(s["optimizer"]["state"]))
        s["optimizer"]["state"][k]["exp_avg"] = torch.zeros(3)
        torch.save(s, state)
        return str(state)
    if case == "pickle weights_only refuses":
        torch.save({"step": 1, "x": Evil(tmp / "MARKER")}, state)
        return str(state)
    if case == "truncated model.safetensors":
        model.write_bytes(model.read_bytes()[:1000])
        return str(model)
    if case == "garbage model.safetensors":
        model.write_bytes(os.urandom(5000))
        return str(model)
    if case == "another model's weights":
        shutil.copyfile(SHIPPED_LPAC, model)
        return str(model)
    raise AssertionError(case)


@pytest.mark.parametrize("case", [
    "truncated state.pt", "empty state.pt", "garbage state.pt", "state.pt of a list", "state.pt without a key",
    "optimizer of another shape", "pickle weights_only refuses", "truncated model.safetensors",
    "garbage model.safetensors", "another model's weights"])
def test_resume_from_a_damaged_checkpoint_is_one_line(run, dataset, tmp_path, case):
    copy = tmp_path / "r"
    shutil.copytree(run, copy)
    name = _damage(copy / "checkpoints" / "latest", case, tmp_path)
    line = assert_one_line(*cli("train", "--data", dataset, "--out", copy, "--resume", *TRAIN), name)
    assert not (tmp_path / "MARKER").exists()  # the pickle was never run
    assert "weights_only" not in line  # never torch's advice to load it less safely


def test_empty_state_pt_is_one_line_as_a_process_too(run, dataset, tmp_path):
    """click turns an EOFError into 'Aborted!' (exit 1); the real process must print one line."""
    copy = tmp_path / "r"
    shutil.copytree(run, copy)
    (copy / "checkpoints" / "latest" / "state.pt").write_bytes(b"")
    assert_one_line(*cli_subprocess("train", "--data", dataset, "--out", copy, "--resume", *TRAIN), "state.pt")


def test_resume_without_a_checkpoint_names_it(dataset, tmp_path):
    assert_one_line(*cli("train", "--data", dataset, "--out", tmp_path / "none", "--resume", *TRAIN), "--resume")


# --- option values -------------------------------------------------------------------------------------
@pytest.mark.parametrize("args,flag", [
    (["--checkpoint-every", "0"], "--checkpoint-every"),
    (["--max-steps-per-epoch", "-1"], "--max-steps-per-epoch"),
    (["--batch-size", "500"], "--batch-size"),  # larger than the 112-sample training split: no step
    (["--val-samples", "0"], "--val-samples"),
    (["--workers", "-2"], "--workers"),
])
def test_train_refuses_values_that_break_or_run_nothing(dataset, tmp_path, args, flag):
    out = tmp_path / "r"
    assert_one_line(*cli("train", "--data", dataset, "--out", out, *TRAIN, *args), flag)
    assert not out.exists()  # refused before anything was written


@pytest.mark.parametrize("args,flag", [
    (["datagen", "--n", "10", "--workers", "-1"], "--workers"),
    (["eval", "--eta", "2"], "--eta"),
    (["eval", "--num-envs", "0"], "--num-envs"),
    (["datagen", "--n", "ten"], "--n"),
    (["datagen"], "--n"),
    (["bench", "sim", "--steps", "5"], "--steps"),
])
def test_typer_range_errors_are_one_line(args, flag):
    assert_one_line(*cli(*args), flag)


def test_a_group_without_a_command_still_prints_its_help():
    r = subprocess.run([sys.executable, "-m", "madp.cli", "dataset"], capture_output=True, text=True)
    assert "Usage:" in r.stdout + r.stderr and "madp: error" not in r.stderr


# --- sizes and sample counts, checked before anything is allocated -------------------------------------
def test_absurd_sample_count_is_refused_up_front(tmp_path):
    out = tmp_path / "d"
    assert_one_line(*cli_subprocess("datagen", "--n", "99999999999999999999", "--out", out, timeout=60), "--n")
    assert not out.exists()


def test_sizes_that_cannot_be_allocated_are_refused_up_front(tmp_path):
    out = tmp_path / "d"
    assert_one_line(*cli_subprocess("datagen", "--n", "100", "--num-robots", "10000000", "--out", out, timeout=60),
                    "--num-robots", "GiB")
    assert not out.exists()
    sc = tmp_path / "huge.json"
    sc.write_text(json.dumps({"features": [{"mean": [5, 5], "sigma": 40, "peak": 1}], "robots": [[1, 1]],
                              "params": {"world_size": 16_000_000}}))
    assert_one_line(*cli_subprocess("rollout", "--scenario", sc, "--out", tmp_path / "r.json", timeout=60),
                    str(sc), "GiB")


# --- scenarios whose J(0) is 0 -------------------------------------------------------------------------
@pytest.mark.parametrize("features,reason", [
    ([], "no features"),
    ([{"mean": [5000, 5000], "sigma": 40, "peak": 1}, {"mean": [-300, 10], "sigma": 50, "peak": 1}], "outside the world"),
    ([{"mean": [500, 500], "sigma": 1e-200, "peak": 1}], "too small"),
])
def test_scenario_with_zero_initial_cost_is_refused_at_load(tmp_path, features, reason):
    sc = tmp_path / "s.json"
    sc.write_text(json.dumps({"features": features, "robots": [[1, 1], [700, 700]]}))
    line = assert_one_line(*cli("rollout", "--scenario", sc, "--steps", "3", "--out", tmp_path / "r.json"),
                           str(sc), "J(0) = 0", reason)
    assert "ZeroDivision" not in line and not (tmp_path / "r.json").exists()
