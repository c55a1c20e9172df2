"""One robot of a swarm as its own process (``madp-robot run``, ``python -m madp.robot run``; ``madp swarm``
starts one per robot): the robot's :class:`madp.robot.agent.RobotAgent` behind a Zenoh session, speaking
the records of :mod:`madp.robot.wire`. numpy, onnxruntime and zenoh only (no torch).

``main(["--export", DIR, "--id", I, "--endpoint", "tcp/127.0.0.1:PORT", "--key", RUN, "--secret", "-"])``:

1. it exits as soon as its parent (the world) does (:func:`madp.io.workers.die_with_parent`), reads its
   key (``--secret``: ``-`` for one line of hex on standard input, as ``madp swarm`` hands it, or a
   file of mode 0600: :func:`madp.robot.seal.read_key`), loads the exported policy (``--threads``
   onnxruntime threads, default 1), opens a Zenoh session (peer mode, no scouting, connected to the
   world's endpoint only with its login, listening nowhere) and subscribes to its own keys
   ``madp/RUN/robot/I/in/*`` only; every record it sends is sealed with its key, and every record it
   receives whose seal is not its key's is dropped (:mod:`madp.robot.seal`);
2. **startup**: it sends HELLO every 0.2 s until the world's START brings the swarm's shared seed, the
   parameters of its sensor, radio and motion and the oldest message age its runtime uses; it builds
   its agent, runs one throwaway control step (:func:`warm_up`) and sends READY;
3. **each control step** k, on the world's STEP packet (its position estimate and its sensor's reading):
   ``agent.observe`` -> publishes its beacon -> awaits its radio's beacon DELIVER of step k ->
   ``agent.token`` -> publishes its token -> awaits the token DELIVER of step k -> ``agent.act`` ->
   (under a ``_joint`` rule: publishes its costs -> awaits the cost DELIVER of step k -> ``agent.choose``)
   -> publishes its COMMAND for step k. A STEP packet of a later step that arrives while it waits ends
   step k there (it was too late: the world has moved on) and starts the new one; records of older
   steps or other phases are ignored, and records that do not decode are dropped. A STEP packet's
   position is clipped to the world and one whose reading's window is not around that position is
   dropped, so no finite but absurd value reaches the policy;
4. it exits with status 0 on the world's stop packet, and with status 3 when nothing has come from the
   world for ``--silence-s`` seconds (default 120).
"""

from __future__ import annotations

import argparse
import os
from dataclasses import replace
import queue
import sys
from typing import Callable, Sequence

from madp.errors import MadpError, SettingError

from .seal import read_key, seal, transport_password, transport_user, unseal
from .wire import (Delivery, PHASE_BEACON, PHASE_COST, PHASE_TOKEN, Start, StepPacket, check_endpoint, check_run_key, decode,
                   encode_command, encode_hello, encode_ready, encode_send, in_key, out_key, zenoh_config,
                   HELLO_INTERVAL_S)

__all__ = ["EXIT_SILENT", "RobotLink", "main", "own_step", "serve", "warm_up"]

#: Exit status of a robot whose world stayed silent for ``--silence-s`` seconds.
EXIT_SILENT = 3
#: What a robot sends, by key name (``madp/RUN/robot/I/out/NAME``).
OUT_NAMES = ("hello", "ready", "beacon", "token", "cost", "cmd")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line (madp-robot's error path), not usage + exit
        raise SettingError("run", f"{self.prog}: {message}")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="madp-robot run", description="One robot process of a swarm (madp swarm starts them).")
    p.add_argument("--export", required=True, metavar="DIR", help="the directory madp export wrote")
    p.add_argument("--id", required=True, type=int, metavar="I", help="this robot's id (0 .. N-1)")
    p.add_argument("--endpoint", required=True, metavar="EP", help="the world's Zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--key", required=True, metavar="RUN", help="the run's key (madp/RUN/robot/I/...)")
    p.add_argument("--secret", required=True, metavar="FILE",
                   help="this robot's key: - for one line of hex on standard input, or a file only its owner can read")
    p.add_argument("--threads", type=int, default=1, metavar="T", help="onnxruntime threads (default 1)")
    p.add_argument("--sampling", default=None, metavar="SPEC", help="the export's rule, k or frame changed for this "
                   "robot, as NAME=VALUE items (madp.sampling: e.g. rule=value_joint,k=8)")
    p.add_argument("--parent", type=int, default=None, metavar="PID",
                   help="exit when this process does (default: the parent process)")
    p.add_argument("--silence-s", type=float, default=120.0, metavar="S",
                   help="exit (status 3) when the world has sent nothing for S seconds (default 120)")
    return p


class RobotLink:
    """Robot ``robot``'s Zenoh session, logged in with ``key`` (its key of the run): a subscription to its
    own ``in`` keys, feeding a queue of the records whose seal is its key's (others are dropped), and
    one publisher per ``out`` key (reliable, blocking when congested, sent at once)."""

    def __init__(self, endpoint: str, run_key: str, robot: int, key: bytes):
        import zenoh

        self.robot, self.key, self.run_key = int(robot), key, run_key
        login = (transport_user(self.robot), transport_password(key))
        self.session = zenoh.open(zenoh_config(connect=endpoint, login=login))
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.subscriber = self.session.declare_subscriber(in_key(run_key, self.robot, "*"), self._arrived)
        self.publishers = {name: self.session.declare_publisher(out_key(run_key, self.robot, name),
                                                                congestion_control=zenoh.CongestionControl.BLOCK,
                                                                express=True) for name in OUT_NAMES}

    def _arrived(self, sample) -> None:
        record = unseal(self.key, str(sample.key_expr), sample.payload.to_bytes())
        if record is not None:
            self.inbox.put(record)

    def send(self, name: str, data: bytes) -> None:
        self.publishers[name].put(seal(self.key, out_key(self.run_key, self.robot, name), data))

    def receive(self, timeout_s: float):
        """The next record for this robot that decodes (others are dropped), or None after ``timeout_s``
        seconds without any."""
        import time

        end = time.monotonic() + timeout_s
        while True:
            try:
                raw = self.inbox.get(timeout=max(end - time.monotonic(), 0.0))
            except queue.Empty:
                return None
            rec = decode(raw)
            if rec is not None and getattr(rec, "robot", None) == self.robot:
                return rec

    def close(self) -> None:
        try:
            self.session.close()
        except Exception:  # the session is gone with the process either way
            pass


def _handshake(link: RobotLink, robot: int, silence_s: float) -> Start | None:
    """HELLO every HELLO_INTERVAL_S until a START arrives; None after ``silence_s`` seconds of none."""
    import time

    end = time.monotonic() + silence_s
    while time.monotonic() < end:
        link.send("hello", encode_hello(robot, os.getpid()))
        rec = link.receive(HELLO_INTERVAL_S)
        if isinstance(rec, Start):
            return rec
    return None


def _await(receive: Callable[[float], object], step: int, phase: int, silence_s: float):
    """The DELIVER of ``phase`` of ``step``, or a STEP packet of a later step (or the stop packet) that
    ends this one, or None after ``silence_s`` seconds without a record."""
    while True:
        rec = receive(silence_s)
        if rec is None:
            return None
        if isinstance(rec, StepPacket) and (rec.stop or rec.step > step):
            return rec
        if isinstance(rec, Delivery) and rec.step == step and rec.phase == phase:
            return rec


def _control_step(agent, link: RobotLink, packet: StepPacket, silence_s: float, reading_type):
    """The robot's control step of ``packet``: returns the STEP packet that interrupted it, the packet
    itself when the world went silent, or None when it sent its command."""
    robot, k = link.robot, packet.step
    agent.observe(k, packet.position_m, reading_type(packet.lo_cell, packet.values))
    link.send("beacon", encode_send(PHASE_BEACON, agent.beacon()))
    rec = _await(link.receive, k, PHASE_BEACON, silence_s)
    if not isinstance(rec, Delivery):
        return rec or packet
    link.send("token", encode_send(PHASE_TOKEN, agent.token(rec.messages)))
    rec = _await(link.receive, k, PHASE_TOKEN, silence_s)
    if not isinstance(rec, Delivery):
        return rec or packet
    result = agent.act(rec.messages)
    action = result.action_mps
    if result.costs is not None:  # a _joint rule: the cost round
        link.send("cost", encode_send(PHASE_COST, agent.costs()))
        rec = _await(link.receive, k, PHASE_COST, silence_s)
        if not isinstance(rec, Delivery):
            return rec or packet
        action = agent.choose(rec.messages)
    link.send("cmd", encode_command(robot, k, action))
    return None


def own_step(packet: StepPacket, params) -> StepPacket | None:
    """``packet`` with its position estimate clipped inside the world, 1e-4 m from its border (as the
    world clips its own estimates: :meth:`madp.sim.network.Network.estimates`), or None when its reading
    is not ``sensor_size`` square or its window lies outside the world (a window no sensor reads)."""
    import numpy as np

    s, w = params.sensor_size, params.world_size
    if packet.values.shape != (s, s) or not ((packet.lo_cell >= -s) & (packet.lo_cell <= w)).all():
        return None
    return replace(packet, position_m=np.clip(packet.position_m, 1e-4, w - 1e-4))


def serve(agent, link: RobotLink, silence_s: float, params) -> int:
    """Robot ``link.robot``'s control steps until the stop packet (returns 0) or ``silence_s`` seconds of
    silence (returns :data:`EXIT_SILENT`). A STEP packet :func:`own_step` refuses is dropped."""
    from madp.sim.robot_maps import SensorReading

    last, packet = -1, None
    while True:
        if packet is None:
            packet = link.receive(silence_s)
            if packet is None:
                return EXIT_SILENT
        if isinstance(packet, StepPacket) and not packet.stop and packet.step > last:
            packet = own_step(packet, params)
        if not isinstance(packet, StepPacket) or (not packet.stop and packet.step <= last):
            packet = None  # a delivery of a step it gave up, an old or malformed step packet
            continue
        if packet.stop:
            return 0
        last = packet.step
        nxt = _control_step(agent, link, packet, silence_s, SensorReading)
        if nxt is packet:
            return EXIT_SILENT
        packet = nxt


def warm_up(agent, params) -> None:
    """One control step of a throwaway ``agent`` on a blank reading at the world's centre, alone: loads
    and compiles what a step runs (numba's kernels, onnxruntime's first inferences) before READY, so
    the first real step is not slower than the others."""
    import numpy as np

    from madp.sim.robot_maps import SensorReading, robot_cells

    s, centre = params.sensor_size, np.full(2, params.world_size / 2.0)
    agent.observe(0, centre, SensorReading(robot_cells(centre[None])[0] - s // 2, np.zeros((s, s), np.float32)))
    agent.token([])
    if agent.act([]).costs is not None:
        agent.choose([])


def main(argv: Sequence[str] | None = None) -> int:
    """One robot process (module docstring); returns its exit status."""
    args = _parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    from madp.io.workers import die_with_parent

    die_with_parent(args.parent if args.parent is not None else os.getppid())
    run_key, endpoint = check_run_key(args.key), check_endpoint(args.endpoint)
    key = read_key(args.secret)
    if args.id < 0:
        raise SettingError("id", f"expected a robot id >= 0, got {args.id}")
    if args.threads < 1:
        raise SettingError("threads", f"expected >= 1, got {args.threads}")
    if not args.silence_s > 0:
        raise SettingError("silence-s", f"expected a number of seconds > 0, got {args.silence_s}")
    from madp.sim.params import SimParams

    from .agent import RobotAgent
    from .runtime import RobotRuntime

    runtime = RobotRuntime(args.export, threads=args.threads, sampling=args.sampling)
    link = RobotLink(endpoint, run_key, args.id, key)
    try:
        start = _handshake(link, args.id, args.silence_s)
        if start is None:
            return EXIT_SILENT
        try:
            params = SimParams.from_dict(start.params)
        except (MadpError, TypeError, ValueError) as e:
            raise MadpError(f"the world's START holds unusable parameters: {e}") from None
        runtime.max_age = start.max_age
        agent = RobotAgent(args.id, runtime, params, start.seed, exact_position=start.exact_position)
        warm_up(RobotAgent(args.id, runtime, params, start.seed), params)
        link.send("ready", encode_ready(args.id))
        return serve(agent, link, args.silence_s, params)
    finally:
        link.close()
