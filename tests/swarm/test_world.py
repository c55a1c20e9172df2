"""The world's real-time rules, against stand-in robots that answer at once (no processes, no Zenoh):
what misses its phase's deadline is lost for that phase, a command that misses its step's deadline is
not applied (the robot keeps its last one), and each robot's misses are counted by phase; forged, malformed
and foreign records are counted and change nothing."""

from __future__ import annotations

import time

import numpy as np

from madp.robot import wire
from madp.sim.network import Message
from madp.swarm.bus import Arrival
from madp.swarm.world import World
from tests.swarm.swarm_testutils import scenario


class StandIns:
    """The bus and the robot processes of :class:`World`: every robot answers each STEP and DELIVER
    at once (beacon, token, command ``[1 + i + step / 10, 0]``; with ``costs`` K, a cost message of K
    values ``i`` between the token and the command), except the records listed in ``withheld`` as
    ``(robot, step, what)`` with what in beacon, token, cost, command."""

    def __init__(self, n: int, withheld=(), silent: bool = False, costs: int | None = None):
        self.n, self.withheld, self.silent, self.costs = n, set(withheld), silent, costs
        self.queue: list[Arrival] = []
        self.sent: list[tuple[int, str, object]] = []
        self.pids = list(range(1000, 1000 + n))

    def command(self, i: int, step: int) -> np.ndarray:
        return np.array([1.0 + i + step / 10, 0.0])

    def _answer(self, i: int, data: bytes) -> None:
        if not self.silent:
            self.queue.append(Arrival(i, data, time.perf_counter()))

    def send(self, i: int, name: str, data: bytes) -> None:
        rec = wire.decode(data)
        self.sent.append((i, name, rec))
        if isinstance(rec, wire.StepPacket) and not rec.stop and (i, rec.step, "beacon") not in self.withheld:
            self._answer(i, wire.encode_send(wire.PHASE_BEACON, Message(i, rec.step, rec.position_m)))
        elif isinstance(rec, wire.Delivery) and rec.phase == wire.PHASE_BEACON and (i, rec.step, "token") not in self.withheld:
            self._answer(i, wire.encode_send(wire.PHASE_TOKEN, Message(i, rec.step, np.zeros(2), np.zeros(34, np.float32))))
        elif isinstance(rec, wire.Delivery) and rec.phase == wire.PHASE_TOKEN and self.costs:
            if (i, rec.step, "cost") not in self.withheld:
                self._answer(i, wire.encode_send(wire.PHASE_COST, Message(i, rec.step, np.zeros(2),
                                                                          np.full(self.costs, i, np.float32))))
        elif isinstance(rec, wire.Delivery) and rec.phase == (wire.PHASE_COST if self.costs else wire.PHASE_TOKEN) \
                and (i, rec.step, "command") not in self.withheld:
            self._answer(i, wire.encode_command(i, rec.step, self.command(i, rec.step)))

    def receive(self, timeout_s: float):
        if self.queue:
            return self.queue.pop(0)
        time.sleep(max(timeout_s, 0.0))
        return None

    def exited(self, i: int):
        return None


class Log:
    def __init__(self):
        self.applied: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def poses(self, *a):
        pass

    def tokens(self, *a):
        pass

    def commands(self, t, u, robots):
        self.applied[t] = (u.copy(), np.asarray(robots))


def _world(stand_ins: StandIns, rate_hz: float, log: Log) -> World:
    w = World(scenario(), stand_ins, 34, rate_hz=rate_hz, log=log, costs=stand_ins.costs)
    w.robots, w.t0 = stand_ins, time.perf_counter()
    return w


def test_what_misses_a_deadline_is_lost_and_a_late_command_is_not_applied():
    n = 4
    robots = StandIns(n, withheld={(1, 2, "command"), (1, 3, "beacon"), (3, 1, "token")})
    log = Log()
    w = _world(robots, 2.0, log)
    for k in range(4):
        w.step(k)
    u2 = log.applied[2][0]
    assert np.array_equal(u2[1], robots.command(1, 1))  # robot 1 keeps its step-1 command at step 2
    assert np.array_equal(u2[0], robots.command(0, 2)) and np.array_equal(log.applied[3][0][1], robots.command(1, 3))
    heard = [(i, rec) for i, name, rec in robots.sent if name == "beacons" and rec.step == 3]
    assert heard and all(1 not in [m.sender for m in rec.messages] for _, rec in heard)  # its late beacon is lost
    tokens = [(i, rec) for i, name, rec in robots.sent if name == "tokens" and rec.step == 1]
    assert all(3 not in [m.sender for m in rec.messages] for _, rec in tokens)
    s = w.summary([0] * n)
    assert [r["deadline_misses"] for r in s["robots"]] == [0, 2, 0, 1]
    assert s["robots"][1]["misses_by_phase"] == {"beacon": 1, "token": 0, "command": 1}
    assert s["robots"][3]["misses_by_phase"] == {"beacon": 0, "token": 1, "command": 0}
    assert s["robots"][0]["latency_ms"]["count"] == 4 and s["robots"][1]["latency_ms"]["count"] == 3


def test_with_no_command_in_time_no_robot_moves():
    robots, log = StandIns(4, silent=True), Log()
    w = _world(robots, 1000.0, log)
    for k in range(5):
        w.step(k)
    assert w.cost == [1.0] * 6 and all(not u.any() for u, _ in log.applied.values())
    assert w.summary([0] * 4)["deadline_misses"] == 20 and (w.misses == 5).all()


def test_the_cost_round_reaches_who_heard_the_beacon_and_a_late_cost_is_lost():
    """With a ``_joint`` rule's cost round (K = 4): each robot's cost DELIVER holds the costs of exactly
    the robots whose beacons it was delivered that step and whose costs came in time; a cost message
    that misses its phase is lost and counted as a miss of the cost phase."""
    n = 4
    robots = StandIns(n, withheld={(2, 1, "cost")}, costs=4)
    w = _world(robots, 2.0, Log())
    for k in range(3):
        w.step(k)
    got = {(i, rec.step): rec for i, name, rec in robots.sent if name == "costs"}
    beacons = {(i, rec.step): {m.sender for m in rec.messages} for i, name, rec in robots.sent if name == "beacons"}
    assert len(got) == 3 * n and any(beacons.values())
    for (i, k), rec in got.items():
        want = beacons[i, k] - ({2} if k == 1 else set())
        assert [m.sender for m in rec.messages] == sorted(want)
        assert all(np.array_equal(m.token, np.full(4, m.sender, np.float32)) for m in rec.messages)
    s = w.summary([0] * n)
    assert s["robots"][2]["misses_by_phase"] == {"beacon": 0, "token": 0, "cost": 1, "command": 0}
    assert s["messages"]["cost"]["sent"] == 3 * n - 1


class Forging(StandIns):
    """Stand-ins whose robot 1's keys also bring, before each of its answers, a forged record (its seal
    not robot 1's: data None), junk, a NaN beacon and a record of each kind naming robot 0."""

    def _answer(self, i: int, data: bytes) -> None:
        if i == 1:
            rec = wire.decode(data)
            step = getattr(rec, "step", None)
            step = rec.message.step if isinstance(rec, wire.Sent) else step
            now = time.perf_counter()
            self.queue += [Arrival(1, None, now), Arrival(1, b"\x02junk", now),
                           Arrival(1, wire.encode_send(0, Message(1, step, np.array([np.nan, 1.0]))), now),
                           Arrival(1, wire.encode_send(0, Message(0, step, np.array([1.0, 1.0]))), now),
                           Arrival(1, wire.encode_command(0, step, np.array([5.0, 5.0])), now)]
        super()._answer(i, data)


def test_forged_malformed_and_foreign_records_are_counted_and_change_nothing():
    clean, forged = Log(), Log()
    a, b = _world(StandIns(4), None, clean), _world(Forging(4), None, forged)
    for k in range(3):
        assert a.step(k) == b.step(k)
    for k in range(3):
        assert np.array_equal(clean.applied[k][0], forged.applied[k][0])
    codes = [0] * 4
    d = b.summary(codes)["robots"][1]["dropped"]
    assert d == {"forged": 9, "malformed": 18, "foreign": 18}, d  # before each of 3 answers a step, 3 steps
    assert a.summary(codes)["dropped"] == {"forged": 0, "malformed": 0, "foreign": 0}
    assert b.summary(codes)["robots"][0]["dropped"] == {"forged": 0, "malformed": 0, "foreign": 0}
