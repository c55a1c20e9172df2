"""Sizes and files beyond what a command can do are one line naming the setting or the field, before
any work: ``madp eval --candidates``, ``madp value collect --steps/--envs``, ``madp-robot step --seed``,
and a ``kept.json`` whose fields have the wrong types (``madp eval report``, ``--check``)."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from madp.selection import MAX_CANDIDATES
from madp.training.map_prior import MAX_COLLECT_ENVS, MAX_COLLECT_STEPS
from tests.test_reliability_errors import assert_one_line, cli, cli_subprocess

KEPT = Path(__file__).parents[1] / "docs" / "results" / "kept.json"


def test_eval_refuses_more_candidates_than_it_can_hold(tmp_path):
    code, err = cli_subprocess("eval", "--candidates", "1000000000", "--controllers", "madp", "--out", tmp_path / "e",
                               timeout=60)  # its own process, its memory capped: an unchecked K fails fast
    assert_one_line(code, err, "--candidates", f"at most {MAX_CANDIDATES}")
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize("flag,value,bound", [("--steps", "100000000000", MAX_COLLECT_STEPS),
                                              ("--envs", "1000000000", MAX_COLLECT_ENVS),
                                              ("--every", str(MAX_COLLECT_STEPS + 1), MAX_COLLECT_STEPS)])
def test_value_collect_is_bounded(tmp_path, flag, value, bound):
    code, err = cli_subprocess("value", "collect", "--out", tmp_path / "x.npz", flag, value, timeout=60)
    assert_one_line(code, err, flag, f"from 1 to {bound}")
    assert not (tmp_path / "x.npz").exists()


def test_robot_step_refuses_a_negative_seed_in_one_line(tmp_path):
    from madp.robot.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["step", "--export", str(tmp_path), "--seed", "-1"])
    lines = err.getvalue().strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("madp-robot: error: seed"), err.getvalue()


@pytest.mark.parametrize("change,field", [
    (lambda d: d["default"].__setitem__("dirs", 3), "default.dirs"),
    (lambda d: d["default"]["dirs"].__setitem__(0, None), "default.dirs[0]"),
    (lambda d: d["options"][1].__setitem__("label", 5), "options[1].label"),
    (lambda d: d.__setitem__("options", {"a": 1}), "options"),
    (lambda d: d["runs"][sorted(d["runs"])[0]].pop("commit"), ".commit: missing"),
    (lambda d: d.pop("default"), "default: missing"),
])
@pytest.mark.parametrize("check", [True, False], ids=["check", "write"])
def test_kept_json_is_checked_against_its_schema(tmp_path, change, field, check):
    results = tmp_path / "results"
    results.mkdir()
    spec = json.loads(KEPT.read_text())
    change(spec)
    (results / "kept.json").write_text(json.dumps(spec))
    args = ["eval", "report", "--results", results] + (["--check"] if check else [])
    assert_one_line(*cli(*args), "kept.json", field)
