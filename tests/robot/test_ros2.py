"""madp rollout --record-format ros2 (and madp swarm, the same writer): a rosbag2 MCAP file that the
rosbags package reads back without ROS: per robot a TwistStamped cmd_vel, a PoseStamped pose and MADP's
token messages (best-effort QoS), and the ``madp`` metadata record that makes the file replayable."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosReliability

from madp.robot.ros2 import write_rosbag
from madp.sim import Scenario, SimParams
from madp.sim.network import Message
from tests.test_cli import madp


def read_bag(path: Path) -> tuple[dict[str, str], list, dict]:
    """``({topic: type}, [(topic, log time ns, message)], {topic: [QoS reliability]})`` of a rosbag2 MCAP file."""
    with AnyReader([path]) as r:
        topics = {c.topic: c.msgtype for c in r.connections}
        qos = {c.topic: [q.reliability for q in c.ext.offered_qos_profiles] for c in r.connections}
        return topics, [(c.topic, t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages()], qos


def madp_metadata(path: Path) -> dict[str, str]:
    """The file's ``madp`` metadata record."""
    with open(path, "rb") as f:
        return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}["madp"]


def test_rollout_recorded_as_rosbag2_reads_back(tmp_path):
    sc = Scenario.random(0, SimParams(num_robots=4, num_features=4))
    sc.save(tmp_path / "sc.json")
    r = madp("rollout", "--scenario", str(tmp_path / "sc.json"), "--controller", "dcvt", "--steps", "3",
             "--out", str(tmp_path / "r.json"), "--record", str(tmp_path / "r.mcap"), "--record-format", "ros2")
    assert r.returncode == 0, r.stderr
    topics, msgs, qos = read_bag(tmp_path / "r.mcap")
    assert {t for t, ty in topics.items() if ty == "geometry_msgs/msg/TwistStamped"} == {f"/robot_{i}/cmd_vel" for i in range(4)}
    twists = [m for t, _, m in msgs if t == "/robot_0/cmd_vel"]
    assert len(twists) == 3 and all(np.hypot(m.twist.linear.x, m.twist.linear.y) <= 5.0 + 1e-9 for m in twists)
    assert [m.header.frame_id for m in twists] == ["world"] * 3
    assert [m.header.stamp.nanosec for m in twists] == [0, 200_000_000, 400_000_000]
    poses = [m for t, _, m in msgs if t == "/robot_3/pose"]
    assert topics["/robot_3/pose"] == "geometry_msgs/msg/PoseStamped" and len(poses) == 4
    assert np.allclose([poses[0].pose.position.x, poses[0].pose.position.y], sc.robots_m[3])
    assert qos["/robot_0/cmd_vel"] == [QosReliability.RELIABLE]
    meta = madp_metadata(tmp_path / "r.mcap")
    assert Scenario.from_dict(json.loads(meta["scenario"])).to_dict() == sc.to_dict()
    assert (meta["steps"], meta["controller"], float(meta["dt_s"]), meta["seed"]) == ("3", "dcvt", 0.2, "0")


def test_token_messages_read_back(tmp_path):
    pos = np.random.default_rng(0).uniform(0, 1024, (3, 2, 2))
    act = np.ones((2, 2, 2))
    sent = [[Message(i, t, pos[t, i], np.arange(34, dtype=np.float32) + i) for i in range(2)] for t in range(2)]
    write_rosbag(tmp_path / "b.mcap", pos, act, 0.2, sent)
    topics, msgs, qos = read_bag(tmp_path / "b.mcap")
    assert topics["/robot_1/madp_token"] == "madp_msgs/msg/Token"
    assert qos["/robot_1/madp_token"] == [QosReliability.BEST_EFFORT]
    tok = [m for t, _, m in msgs if t == "/robot_1/madp_token"]
    assert [m.step for m in tok] == [0, 1] and np.array_equal(tok[1].token, np.arange(34) + 1.0)
    assert tok[1].header.stamp.nanosec == 200_000_000 and tok[1].header.frame_id == "world"
    assert np.allclose(tok[1].position_m, pos[1, 1])
    assert [ts for t, ts, _ in msgs if t == "/robot_0/cmd_vel"] == [0, 200_000_000]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.mcap"]  # no temporary file left
