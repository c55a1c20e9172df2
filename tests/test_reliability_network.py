"""The probes' classes of bad input around the network and the rollout's outputs, each a one-line
``madp: error: …`` (exit status 2) before any work: sizes that would allocate without bound, nonsense
``--network`` values (named as ``--network`` and the key), a missing extra, and ``--record`` checked
with ``--out``."""

from __future__ import annotations

import importlib.util
import json

import pytest

from madp.sim import Scenario, SimParams
from tests.test_reliability_errors import assert_one_line, cli, cli_subprocess


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    path = tmp_path_factory.mktemp("scenario") / "s.json"
    Scenario.random(1, SimParams(num_robots=4, num_features=4)).save(path)
    return path


def rollout(scenario, out, *args):
    return cli("rollout", "--scenario", scenario, "--controller", "dcvt", "--steps", "3", "--out", out, *args)


# --- sizes -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("network, key", [("max_age_steps=1000000000", "max_age_steps"),
                                          ("delay_steps=99999999999", "delay_steps")])
def test_network_sizes_are_bounded_up_front(scenario, tmp_path, network, key):
    out = tmp_path / "r.json"
    line = assert_one_line(*cli_subprocess("rollout", "--scenario", scenario, "--controller", "dcvt", "--out", out,
                                           "--network", network, timeout=120), "--network", key, "100000")
    assert "MemoryError" not in line and not out.exists()


def test_an_absurd_number_of_environments_is_refused_up_front(tmp_path):
    assert_one_line(*cli_subprocess("eval", "--suite", "faults", "--num-envs", "100000000000", "--controllers", "dcvt",
                                    "--out", tmp_path, timeout=120), "--num-envs", "10000")
    assert not (tmp_path / "faults").exists()


# --- nonsense --network values ---------------------------------------------------------------------
@pytest.mark.parametrize("network, needles", [
    ("", ["--network", "NAME=VALUE"]), (",,", ["--network", "NAME=VALUE"]),
    ("loss=0.1,loss=0.9", ["--network", "loss is given twice"]),
    ("loss=1.5", ["--network: loss:", "probability"]),
    ("position_noise_m=-3", ["--network: position_noise_m:"]),
    ("seed=-1", ["--network: seed:"]),
    ("fail_fraction=1", ["--network: fail_fraction:"]),
    ("fail_fraction=0.9", ["--network: fail_fraction:", "no robot would survive"]),  # 4 robots of 4
    ("burst_len=0.5,loss=0.3", ["--network: burst_len:"]),
])
def test_bad_network_values_are_one_line_naming_the_network(scenario, tmp_path, network, needles):
    out = tmp_path / "r.json"
    line = assert_one_line(*rollout(scenario, out, "--network", network), *needles)
    assert not line.startswith("madp: error: --seed") and not out.exists()


def test_rollout_over_a_network_reports_the_bytes_on_the_air(scenario, tmp_path):
    out = tmp_path / "r.json"
    assert rollout(scenario, out, "--network", "loss=0.5,burst_len=3,max_bytes_per_step=100")[0] == 0
    doc = json.loads(out.read_text())
    assert doc["network"]["settings"]["burst_len"] == 3.0
    assert doc["network"]["bytes_per_robot_step"] == {"position": 35.0, "total": 35.0}  # DCVT: its beacons


# --- missing extras, before any work -----------------------------------------------------------------
@pytest.fixture
def without(monkeypatch):
    """``without("m")``: module ``m`` looks uninstalled to ``importlib.util.find_spec``."""
    real = importlib.util.find_spec

    def hide(*names):
        monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a, **k: None if name in names else real(name, *a, **k))
    return hide


def test_a_missing_extra_is_reported_before_any_work(scenario, tmp_path, without):
    out, rec = tmp_path / "r.json", tmp_path / "r.mcap"
    without("onnxruntime", "mcap_ros2")
    assert_one_line(*cli("rollout", "--scenario", scenario, "--controller", "madp", "--runtime", "onnx", "--steps", "3",
                         "--out", out), "--runtime", "onnxruntime", "pip install 'madp[onnx]'")
    assert_one_line(*rollout(scenario, out, "--record", rec, "--record-format", "ros2"),
                    "--record-format", "mcap_ros2", "pip install 'madp[ros2]'")
    assert_one_line(*cli("eval", "--suite", "faults", "--num-envs", "1", "--controllers", "madp", "--runtime", "onnx",
                         "--out", tmp_path), "--runtime", "onnxruntime")
    assert not out.exists() and not rec.exists() and not (tmp_path / "faults").exists()


# --- --record with --out ---------------------------------------------------------------------------
def test_record_is_checked_with_out_before_the_rollout(scenario, tmp_path):
    out = tmp_path / "r.json"
    assert_one_line(*rollout(scenario, out, "--record", out), "--record", "also --out")
    assert_one_line(*rollout(scenario, out, "--record", tmp_path), "--record", str(tmp_path), "directory")
    blocked = tmp_path / "a-file"
    blocked.write_text("x")
    line = assert_one_line(*rollout(scenario, out, "--record", blocked / "r.mcap"), "--record", str(blocked / "r.mcap"))
    assert ".tmp" not in line and "tmp-" not in line.replace(str(tmp_path), "")  # no temporary file's name
    assert_one_line(*rollout(scenario, tmp_path, "--record", tmp_path / "r.mcap"), "--out", "directory")
    assert not out.exists() and not (tmp_path / "r.mcap").exists()
