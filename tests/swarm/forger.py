"""An attacker on the same machine as a swarm, as its own process (``python tests/swarm/forger.py PARENT
SECONDS``; robot 1's key as one line of hex on standard input, as a robot process is handed it).

It finds the swarm's robot processes among PARENT's children and reads the run's endpoint and key off
their command lines, as any local user can. Then, for SECONDS or until the robots are gone:

- ``outsider``: a session without a login subscribes to what the world sends every robot and publishes forged
  HELLO, READY, COMMAND, beacon and token records on every robot's keys;
- ``insider``: a session logged in as robot 1 (its key) publishes on robot 1's keys records sealed
  without its key (forged), records sealed with it but not decoding (a NaN beacon, an infinite
  position, NaN tokens and costs: malformed) and records naming another robot (foreign), and on robot
  0's keys; it subscribes to what the world sends robot 0.

It prints ``connected`` after its first round, then, at the end, one JSON line: the records each
session heard of another robot's keys and what it sent.
"""

from __future__ import annotations

import json
import struct
import sys
import time
from pathlib import Path

import numpy as np

from madp.robot import wire
from madp.robot.seal import seal, transport_password, transport_user
from madp.sim.network import Message


def robot_command_lines(parent: int) -> list[list[str]]:
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            argv = (d / "cmdline").read_bytes().decode().split("\0")
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == parent and "madp.robot" in argv and "run" in argv:
            out.append(argv)
    return out


def arg(argv: list[str], name: str) -> str:
    return argv[argv.index(name) + 1]


def forged_records(steps: int, robot: int) -> list[tuple[str, bytes]]:
    """Records that decode, naming ``robot``: what a forger wants the world to take."""
    recs = [("hello", wire.encode_hello(robot, 1)), ("ready", wire.encode_ready(robot))]
    for k in range(steps):
        recs += [("cmd", wire.encode_command(robot, k, np.array([5.0, -5.0]))),
                 ("beacon", wire.encode_send(0, Message(robot, k, np.array([1.0, 1.0]), None))),
                 ("token", wire.encode_send(1, Message(robot, k, np.array([1.0, 1.0]), np.ones(34, np.float32))))]
    return recs


def non_finite_records(steps: int, robot: int) -> list[tuple[str, bytes]]:
    """Records of ``robot`` that must not decode: NaN and infinite positions, NaN tokens and costs."""
    recs = []
    for k in range(steps):
        nan_beacon = bytearray(wire.encode_send(0, Message(robot, k, np.array([1.0, 1.0]), None)))
        struct.pack_into("<d", nan_beacon, 15, float("nan"))  # position_m[0] of the SEND record
        recs += [("beacon", bytes(nan_beacon)),
                 ("beacon", wire.encode_send(0, Message(robot, k, np.array([np.inf, 1.0]), None))),
                 ("token", wire.encode_send(1, Message(robot, k, np.array([1.0, 1.0]), np.full(34, np.nan, np.float32)))),
                 ("cost", wire.encode_send(2, Message(robot, k, np.array([1.0, 1.0]), np.full(4, np.inf, np.float32))))]
    return recs


def main() -> None:
    import zenoh

    parent, seconds = int(sys.argv[1]), float(sys.argv[2])
    key = bytes.fromhex(sys.stdin.readline().strip())
    end = time.monotonic() + seconds
    lines = []
    while not lines and time.monotonic() < end:
        lines = robot_command_lines(parent)
        time.sleep(0.02)
    if not lines:
        print(json.dumps({"error": "no robot process found"}), flush=True)
        return
    endpoint, run = arg(lines[0], "--endpoint"), arg(lines[0], "--key")
    outsider = zenoh.open(wire.zenoh_config(connect=endpoint))
    insider = zenoh.open(wire.zenoh_config(connect=endpoint, login=(transport_user(1), transport_password(key))))
    heard = {"outsider": 0, "insider_robot0": 0}

    def count(name):
        def callback(sample):
            heard[name] += 1
        return callback

    # what the world sends the robots (a session hears its own puts, so not the out keys it forges on)
    subs = [outsider.declare_subscriber(wire.in_key(run, "*", "*"), count("outsider")),
            insider.declare_subscriber(wire.in_key(run, 0, "*"), count("insider_robot0"))]
    sent = {"forged": 0, "malformed": 0, "foreign": 0, "robot0": 0, "outsider": 0}
    steps, first = 40, True
    while time.monotonic() < end and robot_command_lines(parent):
        for name, rec in forged_records(steps, 1):
            k = wire.out_key(run, 1, name)
            insider.put(k, rec + b"\0" * 16)  # a tag that is not robot 1's
            insider.put(k, seal(b"\1" * 32, k, rec))  # sealed with another key
            sent["forged"] += 2
        for name, rec in non_finite_records(steps, 1):
            insider.put(wire.out_key(run, 1, name), seal(key, wire.out_key(run, 1, name), rec))
            sent["malformed"] += 1
        for name, rec in forged_records(2, 0)[:3]:  # HELLO, READY, a COMMAND naming robot 0, on robot 1's keys
            insider.put(wire.out_key(run, 1, name), seal(key, wire.out_key(run, 1, name), rec))
            sent["foreign"] += 1
        for name, rec in forged_records(steps, 0):
            insider.put(wire.out_key(run, 0, name), seal(key, wire.out_key(run, 0, name), rec))
            outsider.put(wire.out_key(run, 0, name), rec)
            sent["robot0"] += 1
            sent["outsider"] += 1
        if first:
            print("connected", flush=True)  # in place: the test's world may start its startup barrier
            first = False
        time.sleep(0.1)
    for s in subs:
        s.undeclare()
    print(json.dumps({"heard": heard, "sent": sent, "endpoint": endpoint}), flush=True)
    insider.close()
    outsider.close()


if __name__ == "__main__":
    main()
