"""The ROS 2 side of the robot runtime: message definitions and rosbag2 recordings (MCAP storage,
``ros2msg`` schemas, CDR messages, written with ``mcap-ros2-support``; no ROS installation needed).

One ROS 2 node per robot, under the robot's namespace ``/robot_<id>`` (docs/guides/export.md):

* ``/robot_<id>/cmd_vel``  ``geometry_msgs/msg/Twist``: the action, ``linear.x``/``linear.y`` in m/s
  (world axes), everything else 0;
* ``/robot_<id>/position`` ``geometry_msgs/msg/PointStamped``: the position it reports (m, frame ``world``);
* ``/robot_<id>/madp_token`` ``madp_msgs/msg/Token``: the message it broadcasts to its neighbours
  (:class:`madp.sim.network.Message`: sender, step, position, token).

Time stamps are the control step times, ``t * dt_s`` from 0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from madp.io.atomic import atomic_path

__all__ = ["MSGDEFS", "TOKEN_MSG", "topic", "write_rosbag"]

_SEP = "=" * 80 + "\n"
_VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
#: The token message: one robot's broadcast at one control step (madp.sim.network.Message).
TOKEN_MSG = "uint32 sender\nuint64 step\nfloat64[2] position_m\nfloat32[] token\n"
#: ``{type: ros2msg definition text}`` of every message type written (dependencies appended, as rosbag2 stores them).
MSGDEFS = {
    "geometry_msgs/msg/Twist": ("geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n" + _SEP
                                + "MSG: geometry_msgs/Vector3\n" + _VECTOR3),
    "geometry_msgs/msg/PointStamped": ("std_msgs/Header header\ngeometry_msgs/Point point\n" + _SEP + "MSG: std_msgs/Header\n"
                                       + _HEADER + _SEP + "MSG: builtin_interfaces/Time\n" + _TIME + _SEP
                                       + "MSG: geometry_msgs/Point\n" + _VECTOR3),
    "madp_msgs/msg/Token": TOKEN_MSG,
}


def topic(robot: int, name: str) -> str:
    """``/robot_<id>/<name>``: a robot's topic under its namespace."""
    return f"/robot_{int(robot)}/{name}"


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def write_rosbag(path: str | Path, positions_m: np.ndarray, actions_mps: np.ndarray, dt_s: float,
                 messages: list | None = None) -> dict:
    """A rollout as one rosbag2 MCAP file at ``path`` (atomically): ``positions_m [T + 1, N, 2]``,
    ``actions_mps [T, N, 2]`` and, when given, ``messages[t]``: the :class:`Message`\\ s the robots
    broadcast at step t. Returns counts of what was written."""
    from mcap_ros2.writer import Writer

    n_steps, n = actions_mps.shape[:2]
    written = 0
    with atomic_path(path, ".mcap", fsync=False) as tmp, open(tmp, "wb") as f:
        w = Writer(f)
        schemas = {k: w.register_msgdef(k, v) for k, v in MSGDEFS.items()}
        for t in range(n_steps + 1):
            ns = int(round(t * dt_s * 1e9))
            for i in range(n):
                x, y = (float(v) for v in positions_m[t, i])
                w.write_message(topic(i, "position"), schemas["geometry_msgs/msg/PointStamped"],
                                {"header": {"stamp": _stamp(ns), "frame_id": "world"}, "point": {"x": x, "y": y, "z": 0.0}},
                                log_time=ns, publish_time=ns)
                written += 1
                if t < n_steps:
                    ux, uy = (float(v) for v in actions_mps[t, i])
                    w.write_message(topic(i, "cmd_vel"), schemas["geometry_msgs/msg/Twist"],
                                    {"linear": {"x": ux, "y": uy, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
                                    log_time=ns, publish_time=ns)
                    written += 1
            for m in (messages[t] if messages is not None and t < len(messages) else ()):
                w.write_message(topic(m.sender, "madp_token"), schemas["madp_msgs/msg/Token"],
                                {"sender": int(m.sender), "step": int(m.step),
                                 "position_m": [float(v) for v in m.position_m],
                                 "token": [float(v) for v in m.token]}, log_time=ns, publish_time=ns)
                written += 1
        w.finish()
    return {"path": str(path), "robots": n, "steps": n_steps, "messages": written}
