"""What an export guarantees a robot: it never overwrites files it did not write, an interrupted or
mixed export is refused at load (each graph's sha256 in runtime.json), a checkpoint of non-finite
weights does not export, graphs and runtime.json of different exports do not load together, the
robot refuses its own non-finite inputs in one line, and ``--runtime onnx`` leaves no folder behind."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from madp.errors import InputError, SettingError
from madp.export import onnx as export_onnx
from madp.models import MADP
from madp.policies import shipped_checkpoint
from madp.robot import RobotRuntime
from tests.models.models_testutils import tiny_madp_config
from tests.robot.robot_testutils import export_tiny


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny-export")
    export_tiny(out)
    return out


def _tiny_policy(monkeypatch, tmp_path, poison: bool = False) -> None:
    """export_policy reads a tiny MADP instead of a checkpoint file (NaN in one weight with ``poison``)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).eval()
    model.set_action_stats(torch.tensor([0.1, -0.2]), torch.tensor([2.0, 1.5]))
    if poison:
        with torch.no_grad():
            next(model.parameters()).view(-1)[0] = float("nan")
    monkeypatch.setattr(export_onnx, "load_policy", lambda path: (model, {"kind": "madp"}))
    monkeypatch.setattr(export_onnx, "carried", lambda path: ())  # no learned network: the default's fallback
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.safetensors").write_bytes(b"a policy file")


def test_export_refuses_foreign_files_and_replaces_only_with_overwrite(tmp_path, monkeypatch):
    _tiny_policy(monkeypatch, tmp_path)
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="notes.txt: not a file madp export writes"):
        export_onnx.export_policy("p.safetensors", user)
    assert sorted(p.name for p in user.iterdir()) == ["notes.txt"]  # nothing written
    out = tmp_path / "export"
    export_onnx.export_policy("p.safetensors", out)
    with pytest.raises(InputError, match="already holds an export"):
        export_onnx.export_policy("p.safetensors", out)
    spec = export_onnx.export_policy("p.safetensors", out, overwrite=True)
    assert set(spec["graph_sha256"]) == set(export_onnx.GRAPHS)
    RobotRuntime(out)


def test_non_finite_weights_do_not_export(tmp_path, monkeypatch):
    _tiny_policy(monkeypatch, tmp_path, poison=True)
    with pytest.raises(InputError, match="non-finite weights"):
        export_onnx.export_policy("p.safetensors", tmp_path / "export")
    assert not (tmp_path / "export").exists() or not any((tmp_path / "export").glob("*.onnx"))


def test_a_mixed_or_unchecked_export_does_not_load(tiny_dir, tmp_path):
    mixed = tmp_path / "mixed"
    shutil.copytree(tiny_dir, mixed)
    shutil.copy(mixed / "perception.onnx", mixed / "encoder.onnx")  # an interrupted re-export's leftovers
    with pytest.raises(InputError, match="encoder.onnx: its sha256 differs"):
        RobotRuntime(mixed)
    old = tmp_path / "old"
    shutil.copytree(tiny_dir, old)
    spec = json.loads((old / "runtime.json").read_text())
    del spec["graph_sha256"]
    (old / "runtime.json").write_text(json.dumps(spec))
    with pytest.raises(InputError, match="no sha256 of each graph"):
        RobotRuntime(old)


def test_a_runtime_json_that_contradicts_its_graphs_does_not_load(tiny_dir, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(tiny_dir, bad)
    spec = json.loads((bad / "runtime.json").read_text())
    spec["model"]["token_dim"] += 1
    (bad / "runtime.json").write_text(json.dumps(spec))
    with pytest.raises(InputError, match="token"):
        RobotRuntime(bad)


def test_a_robot_refuses_its_own_non_finite_inputs(tiny_dir):
    rt = RobotRuntime(tiny_dir)
    obs = np.zeros((4, 32, 32), np.float32)
    obs[0, 3, 4] = np.nan
    with pytest.raises(SettingError, match="observation: expected finite values"):
        rt.step(0, 0, obs, np.array([500.0, 500.0]), [], seed=1)
    with pytest.raises(SettingError, match="position_m: expected finite values"):
        rt.message(0, 0, np.zeros((4, 32, 32), np.float32), np.array([np.inf, 3.0]), np.zeros((0, 2)), seed=1)


def test_runtime_onnx_leaves_no_export_folder_behind(tmp_path):
    code = textwrap.dedent(f"""
        from madp.export.swarm import exported
        from madp.policies import SamplingSettings
        print(exported({str(shipped_checkpoint("madp"))!r}, SamplingSettings()).parent)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    folder = r.stdout.strip().splitlines()[-1]
    assert "madp-export-" in folder and not __import__("os").path.exists(folder)
