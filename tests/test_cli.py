"""The command line: rollout output, one-line errors for a user's mistakes, a traceback for a bug."""

import json
import subprocess
import sys

import pytest


def madp(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "madp.cli", *args], capture_output=True, text=True, cwd=cwd)


def test_rollout_writes_cost_and_positions(tmp_path):
    sc = tmp_path / "s.json"
    sc.write_text(json.dumps({"features": [{"mean": [300, 400], "sigma": 50, "peak": 0.8}],
                              "robots": [[100, 100], [900, 900], [500, 200]]}))
    out = tmp_path / "r.json"
    r = madp("rollout", "--scenario", str(sc), "--controller", "dcvt", "--steps", "40", "--out", str(out))
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert len(res["cost"]) == 41 and res["cost"][0] == 1.0
    assert len(res["positions"]) == 3 and len(res["positions"][0]) == 2


def test_rollout_writes_a_video(tmp_path):
    """``madp rollout --video out.mp4``: steps + 1 frames, read back with OpenCV."""
    from tests.test_video import assert_video

    sc = tmp_path / "s.json"
    sc.write_text(json.dumps({"features": [{"mean": [60, 70], "sigma": 15, "peak": 0.8}],
                              "robots": [[10, 10], [100, 100], [50, 20]],
                              "params": {"world_size": 128, "local_map_size": 64, "sensor_size": 16}}))
    video = tmp_path / "videos" / "r.mp4"
    r = madp("rollout", "--scenario", str(sc), "--controller", "dcvt", "--steps", "5", "--out", str(tmp_path / "r.json"),
             "--video", str(video))
    assert r.returncode == 0, r.stderr
    assert "6 frames" in r.stdout and str(video) in r.stdout
    assert_video(video, 6, 512)
    assert sorted(p.name for p in video.parent.iterdir()) == ["r.mp4"]  # no temporary file left


@pytest.mark.parametrize("args,needle", [
    (["rollout", "--scenario", "/nonexistent.json"], "/nonexistent.json"),
    (["rollout", "--scenario", "{sc}", "--controller", "lqr"], "--controller"),
    (["rollout", "--scenario", "{sc}", "--controller", "dcvt", "--checkpoint", "x.safetensors"], "--checkpoint"),
    (["rollout", "--scenario", "{sc}", "--controller", "dcvt", "--video", "{tmp}/r.avi"], "--video"),
    (["rollout", "--scenario", "{sc}", "--controller", "dcvt", "--video", "{sc}/r.mp4"], "s.json"),
])
def test_user_errors_are_one_line(tmp_path, args, needle):
    """In this process (the CLI's error path is the same; tests/test_reliability_errors.py runs a
    user error as its own process too)."""
    from tests.test_reliability_errors import assert_one_line, cli

    sc = tmp_path / "s.json"
    sc.write_text('{"features": [], "robots": [[1, 1]]}')
    assert_one_line(*cli(*[a.format(sc=sc, tmp=tmp_path) for a in args]), needle)


@pytest.mark.parametrize("controller", ["madp", "lpac"])
def test_rollout_with_a_learned_controller(tmp_path, controller):
    """``madp rollout --controller madp|lpac`` on a scenario file, with the shipped checkpoint."""
    from madp.policies import shipped_checkpoint

    if shipped_checkpoint(controller) is None:
        pytest.skip(f"no shipped {controller} checkpoint in this install")
    sc = tmp_path / "s.json"
    sc.write_text(json.dumps({"features": [{"mean": [60, 70], "sigma": 15, "peak": 0.8}],
                              "robots": [[10, 10], [100, 100], [50, 20]],
                              "params": {"world_size": 128, "local_map_size": 64, "sensor_size": 16}}))
    out = tmp_path / "r.json"
    from tests.test_reliability_errors import cli  # in this process: a new one would spend ~5 s importing

    code, err = cli("rollout", "--scenario", sc, "--controller", controller, "--steps", "2", "--out", out,
                    "--checkpoint", shipped_checkpoint(controller))
    assert code == 0, err
    res = json.loads(out.read_text())
    assert res["controller"] == controller and len(res["cost"]) == 3 and res["cost"][-1] != 1.0  # the robots moved


def test_a_bug_prints_its_traceback_and_asks_for_a_report(tmp_path, monkeypatch):
    """An exception that is not madp's own (here a deliberate IndexError inside a command) is a bug: the
    traceback, then one line asking for a report, exit status 1; never the one line of a user's mistake."""
    import madp.data_schema.dataset as dataset
    from tests.test_reliability_errors import cli

    def broken(root):
        return [][0]

    monkeypatch.setattr(dataset, "dataset_info", broken)
    code, err = cli("dataset", "info", tmp_path)
    lines = err.strip().splitlines()
    assert code == 1 and lines[0] == "Traceback (most recent call last):", err
    assert "IndexError: list index out of range" in err and "in broken" in err
    assert lines[-1].startswith("madp: internal error: this is a bug in madp") and "madp: error:" not in err


@pytest.mark.parametrize("args,line", [
    (["datagen", "--n", "0"], "madp: error: --n: expected a positive number of samples, got 0"),
    (["datagen", "--n", "8", "--beta", "0.5"], "madp: error: --beta: only meaningful with a policy"),
    (["eval", "--sampler", "euler"], "madp: error: --sampler: expected one of ['ddim', 'dpm++'], got 'euler'"),
    (["eval", "--suite", "moon"], "madp: error: --suite: expected one of ['uniform', 'sigma', 'cities', 'launch', "
                                  "'scale', 'all', 'symmetry', 'faults'] or a comma-separated list, got 'moon'"),
    (["datagen", "--n", "8", "--world-size", "100"],
     "madp: error: --world-size must be a multiple of 16 and >= local_map_size, got 100"),
])
def test_a_settings_error_names_its_flag(tmp_path, args, line):
    """The library describes the value by its own name (``num_samples``); the command line names the flag."""
    from tests.test_reliability_errors import assert_one_line, cli

    assert assert_one_line(*cli(*args, "--out", tmp_path / "o")) == line
