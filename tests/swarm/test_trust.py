"""The swarm's trust boundary and the runs that must not score.

A separate process on loopback (``tests/swarm/forger.py``) reads the run's endpoint and key off the
robots' command lines and forges HELLO, READY, COMMAND, beacon and token records: without a login it
hears nothing and reaches no one; logged in as robot 1 it reaches robot 1's keys only, and what it
forges there is dropped and counted (forged, malformed, foreign) while the run stays, to the bit,
the one-process run. A run whose robots all fail during the run ends with a one-line error and its
summary says so."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from madp.errors import MadpError
from madp.export.swarm import exported
from madp.policies import SamplingSettings, shipped_checkpoint
from madp.robot.seal import new_secret, robot_key
from madp.swarm import run_swarm
from tests.swarm.swarm_testutils import scenario
from tests.swarm.test_swarm import _reference

FORGER = Path(__file__).with_name("forger.py")


@pytest.fixture(scope="module")
def export_dir():
    return exported(shipped_checkpoint("madp"), SamplingSettings())


def test_forgeries_of_another_local_process_are_dropped_counted_and_change_nothing(tmp_path, export_dir, monkeypatch):
    import madp.swarm.world as world

    steps = 8
    sc = scenario()
    sc.save(tmp_path / "sc.json")
    secret = new_secret()
    errors = open(tmp_path / "forger.err", "w")
    forger = subprocess.Popen([sys.executable, str(FORGER), str(os.getpid()), "120"], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=errors, text=True,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])})
    forger.stdin.write(robot_key(secret, 1).hex() + "\n")
    forger.stdin.close()
    connect = world.World.connect

    def connect_with_the_forger_in_place(self, robots):  # however slow the machine, it forges from startup on
        assert forger.stdout.readline().strip() == "connected", (tmp_path / "forger.err").read_text()[-2000:]
        return connect(self, robots)

    monkeypatch.setattr(world.World, "connect", connect_with_the_forger_in_place)
    try:
        s = run_swarm(tmp_path / "sc.json", export_dir, steps, tmp_path / "out", progress=False, secret=secret)
        forger.wait(timeout=60)
        out = forger.stdout.read()
    finally:
        if forger.poll() is None:
            forger.kill()
            forger.wait()
        errors.close()
    err = (tmp_path / "forger.err").read_text()[-2000:]
    report = json.loads(out.strip().splitlines()[-1]) if out.strip() else {"error": err}
    assert "error" not in report, report
    assert report["sent"]["forged"] > 0 and report["sent"]["outsider"] > 0
    # the result is the one-process run's, bit for bit (a forged command would have moved robot 1)
    assert np.abs(np.array(s["cost"]) - _reference(sc, None, steps)).max() <= 1e-6
    assert s["outcome"] == "completed" and s["failed"] == []
    # nobody without a login hears anything; robot 1's login hears nothing of robot 0
    assert report["heard"] == {"outsider": 0, "insider_robot0": 0}
    # what reached the world on robot 1's keys is dropped and counted; robot 0's keys were never reached
    d = s["robots"][1]["dropped"]
    assert d["forged"] > 0 and d["malformed"] > 0 and d["foreign"] > 0, d
    assert s["robots"][0]["dropped"] == {"forged": 0, "malformed": 0, "foreign": 0}
    assert s["dropped"]["forged"] == sum(r["dropped"]["forged"] for r in s["robots"])
    assert all(r["messages"]["position"]["sent"] == r["messages"]["token"]["sent"] == steps for r in s["robots"])
    assert all(r["latency_ms"]["count"] == steps for r in s["robots"])


def test_a_run_whose_robots_all_fail_during_the_run_ends_non_zero_and_says_so(tmp_path, export_dir, monkeypatch):
    import madp.swarm.world as world

    step = world.World.step

    def killing_step(self, k):
        if k == 2:
            for pid in self.robots.pids:
                os.kill(pid, signal.SIGKILL)
        return step(self, k)

    monkeypatch.setattr(world.World, "step", killing_step)
    scenario().save(tmp_path / "sc.json")
    with pytest.raises(MadpError, match="no robot left") as e:
        run_swarm(tmp_path / "sc.json", export_dir, 50, tmp_path / "out", progress=False)
    assert "\n" not in str(e.value) and "after 3 of 50 steps" in str(e.value)
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert s["outcome"].startswith("no robot left") and s["final_cost"] is None and s["steps_run"] == 3
    assert sorted(f["robot"] for f in s["failed"]) == [0, 1, 2, 3] and len(s["cost"]) == 4
