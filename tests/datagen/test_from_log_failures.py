"""``madp dataset import`` of logs a swarm's failures shape: a robot that failed during the run has no
command from its failure on, so the import keeps the steps every robot ran (and says in one line why
when there are fewer than 2); a log whose metadata claims more steps than it holds is refused in one
line, without allocating by that count. Logs are written as ``madp swarm`` writes them
(:class:`madp.robot.ros2.RosbagWriter`: only the running robots' commands, every robot's pose)."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest

from madp.datagen.from_log import import_logs, read_log
from madp.errors import MadpError
from madp.robot.ros2 import RosbagWriter
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.controllers import make_controller
from tests.test_reliability_errors import assert_one_line, cli

PARAMS = SimParams(world_size=256, num_robots=4, num_features=4)


def write_log(path, steps: int, fail: dict[int, int], claimed_steps: int | None = None) -> Scenario:
    """A swarm-style log of ``steps`` DCVT steps in which robot i of ``fail`` stops at step ``fail[i]``
    (no command from then on, zero velocity applied); its metadata says ``claimed_steps`` (default
    ``steps``)."""
    sc = Scenario.random(5, PARAMS)
    env, ctrl = CoverageEnv(sc), make_controller("dcvt")
    meta = {"scenario": json.dumps(sc.to_dict()), "steps": claimed_steps or steps, "dt_s": sc.params.dt_s, "seed": 5}
    log = RosbagWriter(path, sc.params.dt_s, meta)
    log.poses(0, env.positions_m)
    for t in range(steps):
        alive = np.array([fail.get(i, steps + 1) > t for i in range(env.num_robots)])
        u = ctrl(env)
        u[~alive] = 0.0
        log.commands(t, u, np.flatnonzero(alive))
        env.step(u)
        log.poses(t + 1, env.positions_m)
    log.close()
    return sc


def test_a_log_with_a_failed_robot_imports_the_steps_every_robot_ran(tmp_path):
    write_log(tmp_path / "f.mcap", 10, {2: 6})
    run = read_log(tmp_path / "f.mcap")
    assert run.commands_mps.shape == (6, 4, 2) and run.positions_m.shape == (7, 4, 2)
    m = import_logs([tmp_path / "f.mcap"], tmp_path / "d", record_every=2)
    assert m.counts()["train"] == 4  # steps 0, 2, 4 and the last before robot 2 failed at 6, 5


def test_a_log_whose_robots_failed_at_once_is_one_line(tmp_path):
    write_log(tmp_path / "f.mcap", 6, {1: 1})
    assert_one_line(*cli("dataset", "import", tmp_path / "f.mcap", "--out", tmp_path / "d"), "/robot_1/cmd_vel")


def test_a_log_whose_metadata_lies_about_its_steps_is_refused_without_allocating(tmp_path):
    write_log(tmp_path / "lie.mcap", 6, {}, claimed_steps=10**10)
    tracemalloc.start()
    try:
        with pytest.raises(MadpError, match="says 10000000000 steps"):
            read_log(tmp_path / "lie.mcap")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50 * 2**20
    assert_one_line(*cli("dataset", "import", tmp_path / "lie.mcap", "--out", tmp_path / "d"), "10000000000 steps")
    assert not (tmp_path / "d" / "manifest.json").exists()
