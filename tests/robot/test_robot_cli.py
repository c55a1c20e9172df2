"""The ``madp-robot`` command line (madp.robot.cli): one control step of an export as one JSON line, a
user's mistake as one line and exit status 2, ``run`` handing its arguments to the robot process."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import types

import pytest

from madp.robot.cli import main
from madp.robot.runtime import FORMAT
from tests.robot.robot_testutils import export_tiny


@pytest.fixture(scope="module")
def tiny_export(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    export_tiny(out)
    return out


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("madp-robot: error: "), err
    return err


def test_step_prints_the_action_as_one_json_line(tiny_export, capsys):
    assert main(["step", "--export", str(tiny_export), "--seed", "5"]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) == 1
    line = json.loads(out)
    u_max = json.loads((tiny_export / "runtime.json").read_text())["motion"]["max_speed_mps"]
    assert line["seed"] == 5 and line["rule"] == "explore"  # a rule that reads the robot's map
    assert len(line["action_mps"]) == 2 and all(math.isfinite(v) for v in line["action_mps"])
    assert math.hypot(*line["action_mps"]) <= u_max + 1e-9
    assert main(["step", "--export", str(tiny_export), "--seed", "5"]) == 0
    assert capsys.readouterr().out == out  # the input is a function of the seed alone


def test_step_takes_the_sampling_spec_over_the_exports(tiny_export, capsys):
    """Its rule, K and frame may change on the robot; the sampler and S are the export's: one line."""
    assert main(["step", "--export", str(tiny_export), "--seed", "5", "--sampling", "rule=none,k=1,frame=world"]) == 0
    line = json.loads(capsys.readouterr().out)
    assert line["rule"] == "none" and line["noise"] == "robot" and "k=1" in line["sampling"] and "frame=world" in line["sampling"]
    for spec, needle in (("steps=7", "steps=7: "), ("sampler=ddim", "sampler=ddim: "), ("rule=oracle", "is not one a robot runs"),
                         ("rule=none,k=4", "candidates"), ("frame=up", "frame: expected world or d4")):
        assert main(["step", "--export", str(tiny_export), "--sampling", spec]) == 2
        assert needle in _one_error_line(capsys), spec


BAD_SPECS = {"malformed": "{oops", "format": json.dumps({"format": "other/1"}),
             "incomplete": json.dumps({"format": FORMAT, "graphs": {"perception": "perception.onnx"}})}


@pytest.mark.parametrize("case", ["missing", *BAD_SPECS])
def test_a_bad_export_is_one_line(tmp_path, capsys, case):
    if case != "missing":
        (tmp_path / "runtime.json").write_text(BAD_SPECS[case])
    assert main(["step", "--export", str(tmp_path if case != "missing" else tmp_path / "nope")]) == 2
    assert "runtime.json" in _one_error_line(capsys)


@pytest.mark.parametrize("argv", [["step"], ["step", "--export", "x", "--seed", "one"], ["fly"]])
def test_a_bad_command_line_is_one_line(argv, capsys):
    assert main(argv) == 2
    _one_error_line(capsys)


def test_run_hands_every_argument_to_the_robot_process(monkeypatch):
    seen = []
    monkeypatch.setitem(sys.modules, "madp.robot.process", types.SimpleNamespace(main=lambda argv: seen.append(argv) or 7))
    assert main(["run", "--help", "--robot-id", "3", "step"]) == 7
    assert seen == [["--help", "--robot-id", "3", "step"]]


def test_python_m_madp_robot_is_the_same_command(tmp_path):
    r = subprocess.run([sys.executable, "-m", "madp.robot", "step", "--export", str(tmp_path / "nope")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.startswith("madp-robot: error: ") and len(r.stderr.splitlines()) == 1
