"""``madp rollout --record PATH --record-format F``: a rollout recorded while it runs, as a Foxglove MCAP
(:func:`madp.recordings.record.write_rollout_mcap`) or a rosbag2 MCAP file (:func:`madp.robot.ros2.write_rosbag`)."""

from __future__ import annotations

import json
from pathlib import Path

from madp.sim.rollout import Actions, Hook, Positions

__all__ = ["RECORD_FORMATS", "recorder", "Recorder"]

#: ``--record-format``.
RECORD_FORMATS = ("foxglove", "ros2")


class Recorder(Hook):
    """Records positions and actions (and, for ``ros2``, the messages a controller that keeps them in
    ``sent``, the robot runtime's swarm, broadcast); :meth:`write` writes the file."""

    def __init__(self, fmt: str, env, controller, name: str, steps: int):
        self.fmt, self.env, self.controller, self.name = fmt, env, controller, name
        self.positions, self.actions_hook, self.messages = Positions(steps), Actions(steps), []

    def start(self, envs):
        self.positions.start(envs)
        self.actions_hook.start(envs)

    def actions(self, t, envs, actions, act_s):
        self.actions_hook.actions(t, envs, actions, act_s)
        sent = getattr(self.controller, "sent", None)
        if sent is not None:
            self.messages.append(list(sent))

    def stepped(self, t, envs):
        self.positions.stepped(t, envs)

    def write(self, path: str | Path) -> str:
        pos, act = self.positions.positions_m[0], self.actions_hook.actions_mps[0]
        dt = self.env.params.dt_s
        if self.fmt == "ros2":
            from madp.robot.ros2 import write_rosbag

            sc = self.env.scenario
            seed = getattr(self.controller, "seed", None)
            meta = {"scenario": json.dumps(sc.to_dict()), "seed": (sc.seed or 0) if seed is None else seed,
                    "controller": self.name}
            r = write_rosbag(path, pos, act, dt, self.messages or None, meta)
            return f"{r['messages']} messages, {r['robots']} robots' cmd_vel -> {path}"
        from .record import write_rollout_mcap

        write_rollout_mcap(path, self.env.world_map, pos, act, self.name, dt)
        return f"{len(act)} steps -> {path}"


def recorder(fmt: str, env, controller, name: str, steps: int) -> Recorder:
    return Recorder(fmt, env, controller, name, steps)
