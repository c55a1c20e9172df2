"""madp rollout --record-format ros2: a rosbag2 MCAP file that the rosbags package reads back without
ROS: one cmd_vel (geometry_msgs/Twist) topic per robot, the positions, and MADP's token messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from madp.robot.ros2 import write_rosbag
from madp.sim import Scenario, SimParams
from madp.sim.network import Message
from tests.test_cli import madp


def _read(path: Path) -> tuple[dict[str, str], list]:
    with AnyReader([path]) as r:
        topics = {c.topic: c.msgtype for c in r.connections}
        return topics, [(c.topic, t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages()]


def test_rollout_recorded_as_rosbag2_reads_back(tmp_path):
    Scenario.random(0, SimParams(num_robots=4, num_features=4)).save(tmp_path / "sc.json")
    r = madp("rollout", "--scenario", str(tmp_path / "sc.json"), "--controller", "dcvt", "--steps", "3",
             "--out", str(tmp_path / "r.json"), "--record", str(tmp_path / "r.mcap"), "--record-format", "ros2")
    assert r.returncode == 0, r.stderr
    topics, msgs = _read(tmp_path / "r.mcap")
    assert {t for t, ty in topics.items() if ty == "geometry_msgs/msg/Twist"} == {f"/robot_{i}/cmd_vel" for i in range(4)}
    twists = [m for t, _, m in msgs if t == "/robot_0/cmd_vel"]
    assert len(twists) == 3 and all(np.hypot(m.linear.x, m.linear.y) <= 5.0 + 1e-9 for m in twists)
    assert len([m for t, _, m in msgs if t == "/robot_3/position"]) == 4


def test_token_messages_read_back(tmp_path):
    pos = np.random.default_rng(0).uniform(0, 1024, (3, 2, 2))
    act = np.ones((2, 2, 2))
    sent = [[Message(i, t, pos[t, i], np.arange(34, dtype=np.float32) + i) for i in range(2)] for t in range(2)]
    write_rosbag(tmp_path / "b.mcap", pos, act, 0.2, sent)
    topics, msgs = _read(tmp_path / "b.mcap")
    assert topics["/robot_1/madp_token"] == "madp_msgs/msg/Token"
    tok = [m for t, _, m in msgs if t == "/robot_1/madp_token"]
    assert [m.step for m in tok] == [0, 1] and np.array_equal(tok[1].token, np.arange(34) + 1.0)
    assert np.allclose(tok[1].position_m, pos[1, 1])
    assert [ts for t, ts, _ in msgs if t == "/robot_0/cmd_vel"] == [0, 200_000_000]
