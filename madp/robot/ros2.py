"""The ROS 2 side of the robot runtime: message definitions and the one rosbag2 writer (MCAP storage,
``ros2msg`` schemas, CDR messages, written with ``mcap-ros2-support``; no ROS installation needed) of
``madp swarm`` (``DIR/swarm.mcap``) and ``madp rollout --record-format ros2``.

One namespace per robot, ``/robot_<id>`` (docs/guides/export.md); every stamp is the control step's time
``t * dt_s`` from 0 (header stamps, log and publish times alike), every frame ``world``:

* ``/robot_<id>/cmd_vel``  ``geometry_msgs/msg/TwistStamped``: the command applied at step t,
  ``twist.linear.x``/``.y`` in m/s (world axes), everything else 0; QoS reliable;
* ``/robot_<id>/pose``  ``geometry_msgs/msg/PoseStamped``: the robot's true position at step t = 0..T
  (``pose.position.x``/``.y``, z = 0, identity orientation); QoS reliable;
* ``/robot_<id>/madp_token``  ``madp_msgs/msg/Token`` (:data:`TOKEN_MSG`): the message it broadcast to
  its neighbours at step t (:class:`madp.sim.network.Message`: sender, step, position, token); QoS
  best effort, as a radio carries it.

Each channel's metadata holds ``offered_qos_profiles`` as rosbag2 records it (YAML, numeric enums:
reliability 1 reliable, 2 best effort; history 1 keep last, depth 10; durability 2 volatile). The
file's metadata record ``madp`` holds ``scenario`` (the scenario's JSON text), ``steps``, ``dt_s``,
``seed`` and ``controller`` (and, when given, more keys): with the file alone the run can be replayed.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from madp.io.atomic import named, temp_path

__all__ = ["MSGDEFS", "QOS_BEST_EFFORT", "QOS_RELIABLE", "RosbagWriter", "TOKEN_MSG", "topic", "write_rosbag"]

_SEP = "=" * 80 + "\n"
_VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_DEPS_HEADER = _SEP + "MSG: std_msgs/Header\n" + _HEADER + _SEP + "MSG: builtin_interfaces/Time\n" + _TIME
#: The token message: one robot's broadcast at one control step (madp.sim.network.Message), with a header.
TOKEN_MSG = "std_msgs/Header header\nuint32 sender\nuint64 step\nfloat64[2] position_m\nfloat32[] token\n"
#: ``{type: ros2msg definition text}`` of every message type written (dependencies appended, as rosbag2 stores them).
MSGDEFS = {
    "geometry_msgs/msg/TwistStamped": ("std_msgs/Header header\ngeometry_msgs/Twist twist\n" + _DEPS_HEADER + _SEP
                                       + "MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\n"
                                       "geometry_msgs/Vector3 angular\n" + _SEP + "MSG: geometry_msgs/Vector3\n" + _VECTOR3),
    "geometry_msgs/msg/PoseStamped": ("std_msgs/Header header\ngeometry_msgs/Pose pose\n" + _DEPS_HEADER + _SEP
                                      + "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\n"
                                      "geometry_msgs/Quaternion orientation\n" + _SEP + "MSG: geometry_msgs/Point\n"
                                      + _VECTOR3 + _SEP + "MSG: geometry_msgs/Quaternion\n" + _VECTOR3 + "float64 w\n"),
    "madp_msgs/msg/Token": TOKEN_MSG + _DEPS_HEADER,
}
_TYPES = {"cmd_vel": "geometry_msgs/msg/TwistStamped", "pose": "geometry_msgs/msg/PoseStamped",
          "madp_token": "madp_msgs/msg/Token"}


def _qos(reliability: int) -> str:
    never = "    sec: 2147483647\n    nsec: 4294967295\n"
    return (f"- history: 1\n  depth: 10\n  reliability: {reliability}\n  durability: 2\n  deadline:\n{never}"
            f"  lifespan:\n{never}  liveliness: 1\n  liveliness_lease_duration:\n{never}"
            "  avoid_ros_namespace_conventions: false")


#: ``offered_qos_profiles`` of the reliable topics (cmd_vel, pose) and of the best-effort ones (tokens).
QOS_RELIABLE, QOS_BEST_EFFORT = _qos(1), _qos(2)


def topic(robot: int, name: str) -> str:
    """``/robot_<id>/<name>``: a robot's topic under its namespace."""
    return f"/robot_{int(robot)}/{name}"


def _header(ns: int) -> dict:
    return {"stamp": {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}, "frame_id": "world"}


class RosbagWriter:
    """A rosbag2 MCAP file written step by step (module docstring), atomically: nothing is at ``path``
    until :meth:`close` renames the finished file there (a writer left unclosed leaves only its
    temporary file, which the next job holding the directory's lock removes). ``metadata``: the
    ``madp`` record's keys (``scenario``, ``steps``, ``dt_s``, ``seed``, ``controller``, ...; values
    turned to text). Counts what it wrote in :attr:`written`."""

    def __init__(self, path: str | Path, dt_s: float, metadata: dict):
        from mcap_ros2.writer import Writer

        self.path, self.dt_s, self.written = Path(path), float(dt_s), 0
        self._tmp = temp_path(self.path, ".mcap")
        self._file = open(self._tmp, "wb")
        self._writer = Writer(self._file)
        self._schemas = {k: self._writer.register_msgdef(k, v) for k, v in MSGDEFS.items()}
        self._writer.add_metadata("madp", {k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()})

    def _ns(self, t: int) -> int:
        return int(round(t * self.dt_s * 1e9))

    def _write(self, robot: int, name: str, message: dict, ns: int) -> None:
        where = topic(robot, name)
        w = self._writer
        if where not in w._channel_ids:  # register it with its QoS (mcap-ros2-support registers without metadata)
            qos = QOS_BEST_EFFORT if name == "madp_token" else QOS_RELIABLE
            w._channel_ids[where] = w._writer.register_channel(topic=where, message_encoding="cdr",
                                                               schema_id=self._schemas[_TYPES[name]].id,
                                                               metadata={"offered_qos_profiles": qos})
        w.write_message(where, self._schemas[_TYPES[name]], message, log_time=ns, publish_time=ns)
        self.written += 1

    def poses(self, t: int, positions_m: np.ndarray, robots=None) -> None:
        """The true positions ``positions_m [N, 2]`` at step t (of ``robots``, default all)."""
        ns = self._ns(t)
        for i in range(len(positions_m)) if robots is None else robots:
            x, y = (float(v) for v in positions_m[i])
            self._write(i, "pose", {"header": _header(ns), "pose": {"position": {"x": x, "y": y, "z": 0.0},
                                                                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}, ns)

    def commands(self, t: int, actions_mps: np.ndarray, robots=None) -> None:
        """The commands ``actions_mps [N, 2]`` (m/s) applied at step t (of ``robots``, default all)."""
        ns = self._ns(t)
        zero = {"x": 0.0, "y": 0.0, "z": 0.0}
        for i in range(len(actions_mps)) if robots is None else robots:
            ux, uy = (float(v) for v in actions_mps[i])
            self._write(i, "cmd_vel", {"header": _header(ns), "twist": {"linear": {"x": ux, "y": uy, "z": 0.0},
                                                                        "angular": zero}}, ns)

    def tokens(self, t: int, messages) -> None:
        """The :class:`madp.sim.network.Message`\\ s the robots broadcast at step t (with their tokens)."""
        ns = self._ns(t)
        for m in messages:
            self._write(int(m.sender), "madp_token", {"header": _header(ns), "sender": int(m.sender), "step": int(m.step),
                                                      "position_m": [float(v) for v in m.position_m],
                                                      "token": [float(v) for v in m.token]}, ns)

    def close(self) -> None:
        """Finish the file and move it to ``path``."""
        try:
            self._writer.finish()
            self._file.close()
            os.replace(self._tmp, self.path)
        except OSError as e:
            self.abandon()
            raise named(e, self.path) from None

    def abandon(self) -> None:
        """Drop the file (an error ended the run): nothing is written to ``path``."""
        self._file.close()
        self._tmp.unlink(missing_ok=True)


def write_rosbag(path: str | Path, positions_m: np.ndarray, actions_mps: np.ndarray, dt_s: float,
                 messages: list | None = None, metadata: dict | None = None) -> dict:
    """A rollout as one rosbag2 MCAP file at ``path`` (atomically, :class:`RosbagWriter`):
    ``positions_m [T + 1, N, 2]``, the applied ``actions_mps [T, N, 2]`` and, when given, ``messages[t]``:
    the :class:`Message`\\ s the robots broadcast at step t; ``metadata``: the ``madp`` record's keys.
    Returns counts of what was written."""
    n_steps, n = actions_mps.shape[:2]
    w = RosbagWriter(path, dt_s, {"steps": n_steps, "dt_s": dt_s, **(metadata or {})})
    try:
        for t in range(n_steps + 1):
            w.poses(t, positions_m[t])
            if t < n_steps:
                w.commands(t, actions_mps[t])
            if messages is not None and t < len(messages):
                w.tokens(t, messages[t])
    except BaseException:
        w.abandon()
        raise
    w.close()
    return {"path": str(path), "robots": n, "steps": n_steps, "messages": w.written}
