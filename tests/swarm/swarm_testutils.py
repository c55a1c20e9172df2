"""What the swarm tests share: a small scenario, the shipped policy's export (the one ``madp rollout
--runtime onnx`` runs), a lockstep swarm run that taps what robot 0 received and sent, process
listings, and a stand-in world that replays recorded records to one real robot process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from madp.robot.wire import Command, Hello, Ready, Sent, decode
from madp.sim import Scenario, SimParams

#: 4 robots on a 512 m world, 20 steps: a few seconds of robot processes.
PARAMS = SimParams(world_size=512, num_robots=4, num_features=8)
STEPS = 20


def scenario(seed: int = 7) -> Scenario:
    return Scenario.random(seed, PARAMS)


def proc_alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def children(pid: int) -> list[int]:
    """The pids of the running children of process ``pid``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid and proc_alive(int(d.name)):
                out.append(int(d.name))
    return sorted(out)


def wait_until(what, timeout_s: float, every_s: float = 0.05) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if what():
            return True
        time.sleep(every_s)
    return bool(what())


class Tap:
    """Records, during one swarm run, every record the world sent robot ``robot`` (``(key name, bytes)``)
    and the commands it sent (``{step: action [2]}``), by wrapping the world bus' send and receive."""

    def __init__(self, monkeypatch, robot: int = 0):
        from madp.swarm.bus import WorldBus

        self.robot, self.inputs, self.commands = robot, [], {}
        send, receive = WorldBus.send, WorldBus.receive

        def tapped_send(bus, i, name, data):
            if i == self.robot:
                self.inputs.append((name, bytes(data)))
            return send(bus, i, name, data)

        def tapped_receive(bus, timeout_s):
            a = receive(bus, timeout_s)
            if a is not None and a.robot == self.robot:
                rec = decode(a.data)
                if isinstance(rec, Command):
                    self.commands[rec.step] = rec.action_mps
            return a

        monkeypatch.setattr(WorldBus, "send", tapped_send)
        monkeypatch.setattr(WorldBus, "receive", tapped_receive)


def replay(export_dir: Path, inputs: list[tuple[str, bytes]], robot: int, num_robots: int, noise,
           silence_s: float = 60.0) -> tuple[dict[int, np.ndarray], subprocess.Popen]:
    """Start one real robot process ``robot`` and feed it, in order, the recorded ``inputs`` (what its
    world sent it), each DELIVER only after it sent that phase's message, as the world does. Before
    every record, ``noise(i)`` yields records for the other robots' keys (``[(robot j, key name,
    bytes)]``), published on the same bus. Returns its commands ``{step: action [2]}`` and the process
    (still running when the inputs end without a stop packet)."""
    from madp.swarm.bus import WorldBus
    from madp.swarm.robots import hand_key

    bus = WorldBus(num_robots)
    cmd = [sys.executable, "-m", "madp.robot", "run", "--export", str(export_dir), "--id", str(robot),
           "--endpoint", bus.endpoint, "--key", bus.run_key, "--secret", "-", "--silence-s", str(silence_s)]
    proc = subprocess.Popen(cmd, env={**os.environ, "OMP_NUM_THREADS": "1"}, stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    hand_key(proc, bus.key(robot))
    commands: dict[int, np.ndarray] = {}

    def take(timeout_s: float):
        a = bus.receive(timeout_s)
        rec = None if a is None else decode(a.data)
        if isinstance(rec, Command):
            commands[rec.step] = rec.action_mps
        return rec

    def await_record(kind, timeout_s: float = 120.0):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            rec = take(0.1)
            if isinstance(rec, kind):
                return rec
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        raise AssertionError(f"robot {robot} sent no {kind.__name__} within {timeout_s} s")

    try:
        await_record(Hello)
        started = False
        for n, (name, data) in enumerate(inputs):
            if name == "start" and started:
                continue  # the world answered several HELLOs; the robot uses the first START
            for j, other_name, other in noise(n):
                bus.send(j, other_name, other)
            if name in ("beacons", "tokens"):
                await_record(Sent)
            bus.send(robot, name, data)
            if name == "start":
                started = True
                await_record(Ready)
        last, end = _last_step(inputs), time.monotonic() + 30
        while (max(commands) if commands else -1) < last and time.monotonic() < end:
            take(0.1)
        return commands, proc
    except BaseException:
        proc.kill()
        raise
    finally:
        if proc.poll() is not None:
            bus.close()
        else:
            proc._madp_bus = bus  # keep the session while the caller still watches the process


def _last_step(inputs) -> int:
    steps = [decode(d).step for name, d in inputs if name == "step" and not decode(d).stop]
    return max(steps) if steps else -1


def kill_quietly(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    bus = getattr(proc, "_madp_bus", None)
    if bus is not None:
        bus.close()
