"""The world process of a swarm: the simulator standing in for physics and sensors, and the radio between
the robot processes (:mod:`madp.swarm.radio`), driving one robot process per robot over Zenoh.

**Startup** (:meth:`World.connect`, not part of any step's latency): every robot sends HELLO until the
world answers START (the swarm's shared seed, :func:`shared_seed`, never the scenario's; the
parameters of its sensor, radio and motion; the oldest message age its runtime uses: the network's
``max_age``; whether its position estimates are exact); when every robot has sent READY, step 0 begins. A robot that ends during startup, or does not
connect within :data:`STARTUP_S` + :data:`STARTUP_PER_ROBOT_S` · N seconds, ends the run with a
one-line error.

**Control step k** (:meth:`World.step`), for the live robots (not failed, process running):

1. the world records the true positions with the network (range), and sends each robot a STEP packet:
   its position estimate (:meth:`madp.sim.network.Network.estimates`) and its sensor's reading
   (:meth:`madp.sim.CoverageEnv.sensor_readings`);
2. **beacon phase**: it collects the robots' beacons; the radio puts them through the ``position``
   channel and sends each robot its DELIVER of what the network model delivers to it;
3. **token phase**: the same with the robots' token messages and the ``token`` channel;
4. **cost phase**, only when the robots' rule is a ``_joint`` one (``costs``: their K): it collects
   each robot's costs of its candidates' copies and sends each robot those of the robots whose
   beacons it was delivered in step 2 (:meth:`madp.swarm.radio.Radio.relay`);
5. **command phase**: it collects the robots' commands and steps the world: a robot whose command did
   not come keeps its last one (zero before its first), a failed robot's is zero.

Lockstep (no rate): each phase waits for every live robot. A live robot process that sends nothing
in a phase for :data:`STALL_S` seconds is killed and failed.

Real time (``rate_hz`` R, period P = 1/R): step k's phases end at t0 + (k + f) · P with
f = :data:`BEACON_BY` (0.25), :data:`TOKEN_BY` (0.60), :data:`COST_BY` (0.90) and :data:`COMMAND_BY` (1.0), t0 the end of
startup; the world's own work of a step (sensing, the cost, the log) comes first in its period, so
the STEP packets go out at t0 + k · P plus that work. At each phase's end the radio delivers what came
in time; what comes later is lost for that phase (counted ``late``); a command that misses its step's
deadline is not applied (the robot keeps its last command). A robot misses a step's deadline when any
of its three messages missed its phase (``deadline_misses``; by phase in ``misses_by_phase``).

Failures: a robot process that has exited (SIGKILL, a crash) is failed from the step at which the
world sees it gone (:meth:`madp.sim.network.Network.fail`): it no longer moves or is heard, the cost
counts the others, and the run goes on. ``fail_fraction`` robots of the network fail at ``fail_step``
as in every rollout; the world sends them the stop packet. The cost J(t)/J(0) counts the running robots;
with none left, :meth:`World.running` is False and the run ends there (it does not score).

What the world drops, never reads and counts per robot (``dropped`` in the summary): ``forged``, a record
whose seal is not its robot's key (:mod:`madp.swarm.bus`); ``malformed``, one that does not decode
(junk, a NaN or infinite position, token or cost); ``foreign``, one naming another robot than its
key's. None of them changes a run.
"""

from __future__ import annotations

import hashlib
import json
import time

import numpy as np

from madp.robot.wire import (Command, PHASE_BEACON, PHASE_COST, PHASE_TOKEN, Ready, Sent, decode, encode_delivery,
                             encode_start, encode_step, encode_stop, Hello)
from madp.errors import MadpError
from madp.sim import CoverageEnv, Scenario
from madp.sim.network import Network, NetworkSettings
from madp.sim.voronoi import coverage_cost

from .radio import CHANNELS, Radio
from .robots import describe_exit

__all__ = ["BEACON_BY", "COMMAND_BY", "COST_BY", "DROPS", "PHASE_NAMES", "STALL_S", "TOKEN_BY", "World", "shared_seed"]

#: Phase deadlines of real time, as fractions of the period after the step's scheduled start.
BEACON_BY, TOKEN_BY, COST_BY, COMMAND_BY = 0.25, 0.60, 0.90, 1.0
#: The phases of a control step, as counted in ``misses_by_phase`` (``cost`` only with a cost round).
PHASE_NAMES = ("beacon", "token", "cost", "command")
COMMAND_PHASE = 3
#: Lockstep: seconds a live robot may send nothing in a phase before it is killed and failed.
STALL_S = 60.0
#: Startup: seconds every robot has to connect, plus as many per robot.
STARTUP_S, STARTUP_PER_ROBOT_S = 60.0, 5.0
#: Seconds between checks that the robot processes still run while the world waits.
POLL_S = 0.05
#: Why the world drops a record a robot's keys brought (module docstring).
DROPS = ("forged", "malformed", "foreign")


def shared_seed(scenario: Scenario, seed: int = 0) -> int:
    """The seed a swarm's robots share (their frames and starting noise): a one-way hash of the scenario
    (its seed, or ``seed`` when it has none, and its whole content), so robots agree without being told
    what rebuilds the world."""
    h = hashlib.sha256(b"madp-swarm-seed\x00")
    h.update(str(scenario.seed if scenario.seed is not None else int(seed)).encode() + b"\x00")
    h.update(json.dumps(scenario.to_dict(), sort_keys=True).encode())
    return int.from_bytes(h.digest()[:8], "little") & ((1 << 63) - 1)


class World:
    """A swarm of ``scenario``'s robots over ``network`` (ideal when None), reached through ``bus``
    (:class:`madp.swarm.bus.WorldBus`); tokens of ``token_dim`` values; ``rate_hz``: real time (None:
    lockstep); ``log``: a :class:`madp.robot.ros2.RosbagWriter` or None; ``costs``: the robots' K
    when their rule has a cost round (None: none). Its robot processes
    (:class:`madp.swarm.robots.RobotProcesses`) join at :meth:`connect`."""

    def __init__(self, scenario: Scenario, bus, token_dim: int, network: NetworkSettings | None = None,
                 rate_hz: float | None = None, log=None, costs: int | None = None):
        self.env = CoverageEnv(scenario)  # physics and sensors; the network is the radio's, below
        self.settings = network or NetworkSettings()
        p, n = self.env.params, self.env.num_robots
        self.seed = scenario.seed if scenario.seed is not None else 0
        self.shared_seed = shared_seed(scenario)
        self.network = Network(self.settings, n, p.comm_radius_m, p.world_size, self.seed)
        self.radio = Radio(self.network, token_dim, costs)
        self.cost_round = costs is not None
        self.phases = PHASE_NAMES if self.cost_round else tuple(p for p in PHASE_NAMES if p != "cost")
        self.channels = CHANNELS if self.cost_round else CHANNELS[:2]
        self._holders: list[set[int]] = [set() for _ in range(n)]  # whose beacons each robot holds this step
        self.bus, self.robots, self.rate_hz, self.log = bus, None, rate_hz, log
        self.n = n
        self.missed = np.zeros(n, bool)  # this step's robots that missed a phase
        self.last_u = np.zeros((n, 2))
        self.cost = [1.0]
        self.latency_ms: list[list[float]] = [[] for _ in range(n)]
        self.misses = np.zeros((n, len(self.phases)), np.int64)  # by phase of self.phases
        self.deadline_misses = np.zeros(n, np.int64)
        self.late_commands = np.zeros(n, np.int64)
        self.failed_at: list[int | None] = [None] * n
        self.why: list[str | None] = [None] * n
        self.wire = {"step": np.zeros((n, 2), np.int64), "command": np.zeros((n, 2), np.int64)}  # [count, bytes]
        self.dropped = {why: np.zeros(n, np.int64) for why in DROPS}
        self.world_ms: list[float] = []
        self.sent_at: dict[int, np.ndarray] = {}
        self.t0 = 0.0

    # --- startup --------------------------------------------------------------------------------
    def connect(self, robots) -> float:
        """The startup barrier of ``robots`` (module docstring); returns its duration (s)."""
        p, started = self.env.params, time.perf_counter()
        self.robots = robots
        exact = self.settings.position_noise_m == 0
        start = [encode_start(i, self.shared_seed, self.settings.max_age, p.to_dict(), exact) for i in range(self.n)]
        ready: set[int] = set()
        limit = STARTUP_S + STARTUP_PER_ROBOT_S * self.n
        next_poll = 0.0
        while len(ready) < self.n:
            a = self.bus.receive(POLL_S)
            now = time.perf_counter()
            rec = None if a is None else self._record(a)
            if isinstance(rec, Hello):
                self.bus.send(a.robot, "start", start[a.robot])
            elif isinstance(rec, Ready):
                ready.add(a.robot)
            if now >= next_poll:
                next_poll = now + POLL_S
                for i in sorted(set(range(self.n)) - ready):
                    code = self.robots.exited(i)
                    if code is not None:
                        words = self.robots.last_words(i)
                        raise MadpError(f"robot {i} ended during startup ({describe_exit(code)})" + (f": {words}" if words else ""))
            if now - started > limit:
                missing = sorted(set(range(self.n)) - ready)
                raise MadpError(f"robot(s) {', '.join(map(str, missing[:8]))} did not start within {limit:.0f} s")
        self.t0 = time.perf_counter()
        if self.log is not None:
            self.log.poses(0, self.env.positions_m)
        return self.t0 - started

    # --- one control step ----------------------------------------------------------------------------
    def _fail(self, robot: int, step: int, why: str) -> None:
        if self.failed_at[robot] is None:
            self.failed_at[robot], self.why[robot] = step, why
        self.network.fail(robot, step)

    def _poll(self, step: int, robots) -> None:
        """Fail, from ``step``, every robot of ``robots`` whose process has exited."""
        for i in list(robots):
            code = self.robots.exited(i)
            if code is not None and self.network.alive(step)[i]:
                self._fail(i, step, f"process ended ({describe_exit(code)})")

    def _live(self, step: int) -> np.ndarray:
        """[N] bool: the robots running at ``step`` (the network's failures stopped, dead processes failed)."""
        before = self.network.alive(step)
        self._poll(step, np.flatnonzero(before))
        alive = self.network.alive(step)
        for i in np.flatnonzero(~alive):
            if self.failed_at[i] is None:  # the network's fail_fraction: stop its process
                self.failed_at[i], self.why[i] = step, f"failed by the network (fail_fraction, fail_step {self.settings.fail_step})"
                self.bus.send(int(i), "step", encode_stop(int(i), step))
        return alive

    def _deadline(self, step: int, fraction: float) -> float | None:
        return None if self.rate_hz is None else self.t0 + (step + fraction) / self.rate_hz

    def _record(self, a):
        """The record arrival ``a`` brings, or None (counted under :data:`DROPS`) when it is forged,
        does not decode or names another robot."""
        i = a.robot
        if a.data is None:
            self.dropped["forged"][i] += 1
            return None
        rec = decode(a.data)
        if rec is None:
            self.dropped["malformed"][i] += 1
        elif (rec.message.sender if isinstance(rec, Sent) else getattr(rec, "robot", i)) != i:
            self.dropped["foreign"][i] += 1
            return None
        return rec

    def running(self, step: int) -> bool:
        """Whether any robot is still running at ``step``."""
        return bool(self.network.alive(step).any())

    def _take(self, a, step: int, phase: int, want: set, got: dict) -> bool:
        """File one arrival during ``phase`` of ``step``; True when it is one the phase waits for."""
        rec, i = self._record(a), a.robot
        if isinstance(rec, Sent) and rec.phase < len(self.channels) and i < self.n:
            channel = CHANNELS[rec.phase]
            if rec.message.step == step and rec.phase == phase and i in want and i not in got:
                if self.radio.accept(channel, i, rec.message, len(a.data)):
                    got[i] = rec.message
                    return True
            elif rec.message.step < step or (rec.message.step == step and rec.phase < phase):
                self.radio.late(channel, i)
        elif isinstance(rec, Command):
            sent = self.sent_at.get(rec.step)
            if sent is not None and sent[i] > 0:
                self.latency_ms[i].append(1e3 * (a.at_s - sent[i]))
                sent[i] = 0.0  # one latency per robot and step
            if rec.step == step and phase == COMMAND_PHASE and i in want and i not in got:
                self.wire["command"][i] += (1, len(a.data))
                got[i] = rec
                return True
            if rec.step <= step:
                self.late_commands[i] += 1
        return False

    def _collect(self, step: int, phase: int, live: np.ndarray, deadline: float | None) -> dict:
        """What the live robots send in ``phase`` of ``step``, until all have sent (lockstep) or the
        deadline; counts the misses (module docstring)."""
        want, got = set(int(i) for i in np.flatnonzero(live)), {}
        last, next_poll = time.perf_counter(), 0.0
        while want - got.keys():
            now = time.perf_counter()
            if deadline is not None and now >= deadline:
                break
            a = self.bus.receive(POLL_S if deadline is None else min(POLL_S, deadline - now))
            now = time.perf_counter()
            if a is not None and self._take(a, step, phase, want, got):
                last = now
            if now >= next_poll or a is None:
                next_poll = now + POLL_S
                self._poll(step, want - got.keys())
                want &= set(int(i) for i in np.flatnonzero(self.network.alive(step)))
                if deadline is None and now - last > STALL_S:
                    for i in want - got.keys():
                        self.robots.procs[i].kill()
                        self._fail(i, step, f"sent nothing for {STALL_S:.0f} s in the {PHASE_NAMES[phase]} phase (killed)")
                    want = set(got)
        self._poll(step, want - got.keys())
        for i in want - got.keys():
            if self.network.alive(step)[i]:
                self.misses[i, self.phases.index(PHASE_NAMES[phase])] += 1
                self.missed[i] = True
        return got

    def _deliver(self, step: int, phase: int, sent: dict) -> None:
        channel, name = CHANNELS[phase], ("beacons", "tokens", "costs")[phase]
        if phase == PHASE_COST:
            heard = self.radio.relay(sent, self._holders)
        else:
            heard = self.radio.exchange(channel, step, sent)
        if phase == PHASE_BEACON:
            self._holders = [{int(m.sender) for m in h} for h in heard]
        for i in np.flatnonzero(self.network.alive(step)):
            data = encode_delivery(phase, int(i), step, heard[i])
            self.bus.send(int(i), name, data)
            self.radio.delivered(channel, int(i), len(heard[i]), len(data))

    def step(self, step: int) -> float:
        """Control step ``step`` (module docstring); returns J(step + 1)/J(0)."""
        env, net = self.env, self.network
        work = time.perf_counter()
        live = self._live(step)
        net.record(step, env.positions_m)
        estimates = net.estimates(step, env.positions_m)
        readings = env.sensor_readings()
        packets = {int(i): encode_step(int(i), step, estimates[i], readings[i].lo_cell, readings[i].values)
                   for i in np.flatnonzero(live)}
        self.world_ms.append(1e3 * (time.perf_counter() - work))
        if self.rate_hz is not None:
            time.sleep(max(self._deadline(step, 0.0) - time.perf_counter(), 0.0))
        self.missed = np.zeros(self.n, bool)
        sent_at = self.sent_at[step] = np.zeros(self.n)
        self.sent_at.pop(step - 8, None)
        for i, data in packets.items():
            sent_at[i] = time.perf_counter()
            self.bus.send(i, "step", data)
            self.wire["step"][i] += (1, len(data))
        beacons = self._collect(step, PHASE_BEACON, live, self._deadline(step, BEACON_BY))
        self._deliver(step, PHASE_BEACON, beacons)
        tokens = self._collect(step, PHASE_TOKEN, net.alive(step), self._deadline(step, TOKEN_BY))
        self._deliver(step, PHASE_TOKEN, tokens)
        if self.cost_round:
            costs = self._collect(step, PHASE_COST, net.alive(step), self._deadline(step, COST_BY))
            self._deliver(step, PHASE_COST, costs)
        commands = self._collect(step, COMMAND_PHASE, net.alive(step), self._deadline(step, COMMAND_BY))
        work = time.perf_counter()
        self.deadline_misses += self.missed
        alive = net.alive(step)
        u = self.last_u.copy()
        for i, c in commands.items():
            u[i] = c.action_mps
        u[~alive] = 0.0
        self.last_u = u
        env.step(u)
        running = net.alive(step + 1)
        if not running.any():  # no robot left: nothing covers, the cost keeps its last value
            self.cost.append(self.cost[-1])
        else:
            j = coverage_cost(env.prefix, env.positions_m[running]) if net.failed.any() else env.cost()
            self.cost.append(j / env.cost0)
        if self.log is not None:
            self.log.commands(step, u, np.flatnonzero(alive))
            self.log.tokens(step, [tokens[i] for i in sorted(tokens)])
            self.log.poses(step + 1, env.positions_m)
        self.world_ms[-1] += 1e3 * (time.perf_counter() - work)
        return self.cost[-1]

    def stop(self, step: int) -> list[int | None]:
        """Send the stop packet to every robot still running; return every robot's return code."""
        for i in range(self.n):
            if self.robots.exited(i) is None:
                self.bus.send(i, "step", encode_stop(i, step))
        return self.robots.wait_all()

    # --- the summary ---------------------------------------------------------------------------------
    def summary(self, codes: list[int | None]) -> dict:
        """Per robot and in total: latencies, misses, failures, messages (module docstring)."""
        def pct(v: list[float], q: float) -> float | None:
            return float(np.percentile(v, q)) if v else None

        robots = []
        for i in range(self.n):
            lat = self.latency_ms[i]
            robots.append({
                "id": i, "pid": self.robots.pids[i],
                "latency_ms": {"p50": pct(lat, 50), "p99": pct(lat, 99), "max": float(max(lat)) if lat else None,
                               "count": len(lat)},
                "deadline_misses": int(self.deadline_misses[i]),
                "misses_by_phase": {name: int(self.misses[i, k]) for k, name in enumerate(self.phases)},
                "late_commands": int(self.late_commands[i]),
                "dropped": {why: int(v[i]) for why, v in self.dropped.items()},
                "failed_at_step": self.failed_at[i], "failure": self.why[i], "exit": describe_exit(codes[i]),
                "messages": {**{ch: self.radio.counts[ch].of(i) for ch in self.channels},
                             **{k: {"count": int(v[i, 0]), "bytes": int(v[i, 1])} for k, v in self.wire.items()}},
            })
        every = [x for lat in self.latency_ms for x in lat]
        return {
            "robots": robots,
            "latency_ms": {"p50": pct(every, 50), "p99": pct(every, 99), "max": float(max(every)) if every else None},
            "deadline_misses": int(self.deadline_misses.sum()),
            "dropped": {why: int(v.sum()) for why, v in self.dropped.items()},
            "world_ms": {"p50": pct(self.world_ms, 50), "p99": pct(self.world_ms, 99)},
            "failed": [{"robot": i, "step": self.failed_at[i], "why": self.why[i]} for i in range(self.n)
                       if self.failed_at[i] is not None],
            "messages": {**{ch: self.radio.counts[ch].total() for ch in self.channels},
                         **{k: {"count": int(v[:, 0].sum()), "bytes": int(v[:, 1].sum())} for k, v in self.wire.items()}},
        }
