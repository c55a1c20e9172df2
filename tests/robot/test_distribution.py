"""The madp-robot distribution (robot/pyproject.toml) installed as a robot would: a fresh virtual
environment, ``uv pip install ./robot`` held to the dev environment's versions (uv's cache holds them
when uv installed it, as in CI; hatchling comes from the package index the first time), no torch in it, and
``madp-robot step`` running the shipped checkpoint that the dev environment exported."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import in_ci
from tests.robot.wheel_testutils import REPO, ROBOT, wheel_files, wheel_modules

BIN = Path(sys.executable).parent


def _env() -> dict:
    """This process's environment without what would point a process at another Python or the source tree."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}


def _run(cmd: list, cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, cwd=cwd, env=_env(), timeout=600)
    assert not check or r.returncode == 0, f"{' '.join(map(str, cmd))} exited {r.returncode}:\n{r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def robot_venv(tmp_path_factory) -> Path:
    """A fresh virtual environment with madp-robot installed from ``robot/``."""
    uv = BIN / "uv"
    if not uv.is_file():
        msg = f"uv not found at {uv}: the dev environment installs it (.ci/run)"
        if in_ci():
            pytest.fail(msg, pytrace=False)
        pytest.skip(msg)
    venv = tmp_path_factory.mktemp("robot") / "venv"
    here = venv.parent
    _run([uv, "venv", "-q", "--python", sys.executable, venv], here)
    # the dev environment's versions (in uv's cache when uv installed it, as in CI): no download, the same numpy
    freeze = _run([uv, "pip", "freeze", "--python", sys.executable], here).stdout.splitlines()
    (here / "constraints.txt").write_text("".join(f"{line}\n" for line in freeze
                                                  if "==" in line and not line.lower().startswith("madp")))
    _run([uv, "pip", "install", "-q", "--python", venv / "bin" / "python", "-c", here / "constraints.txt", ROBOT], here)
    return venv


def test_the_installed_robot_has_no_torch_and_exactly_the_wheel(robot_venv, tmp_path):
    python = robot_venv / "bin" / "python"
    listed = _run([BIN / "uv", "pip", "list", "--python", python, "--format", "json"], tmp_path).stdout
    names = {p["name"].lower() for p in json.loads(listed)}
    assert "madp-robot" in names and {"numpy", "onnxruntime", "eclipse-zenoh"} <= names
    assert not {n for n in names if n.startswith("torch") or n in ("madp", "typer", "matplotlib")}, names
    r = _run([python, "-c", "import torch"], tmp_path, check=False)
    assert r.returncode != 0 and "No module named 'torch'" in r.stderr
    # every module of the wheel imports there, from the venv, not this tree; its lazily imported packages too
    code = ("import importlib, json, sys; mods = json.loads(sys.argv[1]); [importlib.import_module(m) for m in mods]; "
            "import onnxruntime, zenoh; print(json.dumps([sys.modules[m].__file__ for m in mods]))")
    files = json.loads(_run([python, "-c", code, json.dumps(wheel_modules())], tmp_path).stdout)
    site = next((robot_venv / "lib").glob("python3*/site-packages"))
    assert all(Path(f).is_relative_to(site) for f in files), files
    installed = {p.relative_to(site).as_posix() for p in (site / "madp").rglob("*.py")}
    assert installed == set(wheel_files())


def test_madp_robot_step_runs_the_shipped_checkpoint(robot_venv, tmp_path):
    export = tmp_path / "export"
    _run([BIN / "madp", "export", REPO / "madp" / "checkpoints" / "madp-cpu.safetensors", "--out", export], tmp_path)
    u_max = json.loads((export / "runtime.json").read_text())["motion"]["max_speed_mps"]
    r = _run([robot_venv / "bin" / "madp-robot", "step", "--export", export, "--seed", "3"], tmp_path)
    lines = r.stdout.splitlines()
    assert len(lines) == 1
    action = json.loads(lines[0])["action_mps"]
    assert len(action) == 2 and all(math.isfinite(v) for v in action)
    assert math.hypot(*action) <= u_max + 1e-9
    assert "--endpoint" in _run([robot_venv / "bin" / "madp-robot", "run", "--help"], tmp_path).stdout
    bad = _run([robot_venv / "bin" / "madp-robot", "step", "--export", tmp_path / "missing"], tmp_path, check=False)
    assert bad.returncode == 2 and bad.stderr.startswith("madp-robot: error: ") and len(bad.stderr.splitlines()) == 1
