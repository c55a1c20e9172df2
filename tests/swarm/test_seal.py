"""What a record must be for a swarm process to read it, without processes: sealed with its robot's key
for the key expression it travels on; finite everywhere (positions, tokens, costs); a START that
holds a robot's own parameters only; a STEP whose finite but absurd position is clipped inside the
world before the policy sees it. And the keys' files, the machine's capacity and the run's bounds."""

from __future__ import annotations

import io
import json
import os
import struct

import numpy as np
import pytest

from madp.errors import InputError, SettingError
from madp.robot import wire
from madp.robot.process import own_step
from madp.robot.seal import new_secret, read_key, robot_key, seal, unseal
from madp.sim import Scenario, SimParams
from madp.sim.network import Message
from madp.swarm.robots import ROBOT_MB, ROBOTS_PER_CORE, check_capacity
from madp.swarm.run import MAX_STEPS, RATE_HZ, check_run
from madp.swarm.world import shared_seed


def test_a_record_reads_only_under_its_robots_key_and_key_expression():
    secret = new_secret()
    k0, k1 = robot_key(secret, 0), robot_key(secret, 1)
    assert k0 != k1 and robot_key(secret, 0) == k0 and robot_key(new_secret(), 0) != k0
    rec = wire.encode_command(0, 3, np.array([1.0, 2.0]))
    where = wire.out_key("run", 0, "cmd")
    sealed = seal(k0, where, rec)
    assert unseal(k0, where, sealed) == rec
    assert unseal(k1, where, sealed) is None  # another robot's key
    assert unseal(k0, wire.out_key("run", 1, "cmd"), sealed) is None  # moved to another robot's keys
    assert unseal(k0, wire.in_key("run", 0, "cmd"), sealed) is None  # sent back the other way
    assert unseal(k0, wire.out_key("other", 0, "cmd"), sealed) is None  # another run
    assert unseal(k0, where, rec) is None and unseal(k0, where, b"") is None  # unsealed
    flipped = bytearray(sealed)
    flipped[5] ^= 1
    assert unseal(k0, where, bytes(flipped)) is None


def test_a_robots_key_comes_from_stdin_or_a_file_only_its_owner_reads(tmp_path, monkeypatch):
    key = robot_key(new_secret(), 2)
    monkeypatch.setattr("sys.stdin", io.StringIO(key.hex() + "\n"))
    assert read_key("-") == key
    fd = os.open(tmp_path / "k", os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    os.write(fd, key.hex().encode() + b"\n")
    os.close(fd)
    assert read_key(str(tmp_path / "k")) == key and (tmp_path / "k").stat().st_mode & 0o777 == 0o600
    (tmp_path / "k").chmod(0o644)
    with pytest.raises(InputError, match="chmod 600"):
        read_key(str(tmp_path / "k"))
    monkeypatch.setattr("sys.stdin", io.StringIO("not hex\n"))
    with pytest.raises(InputError, match="64 hex digits"):
        read_key("-")
    with pytest.raises(InputError, match="cannot read"):
        read_key(str(tmp_path / "none"))


def _nan_at(record: bytes, offset: int) -> bytes:
    out = bytearray(record)
    struct.pack_into("<d", out, offset, float("nan"))
    return bytes(out)


def test_non_finite_beacons_tokens_costs_and_deliveries_do_not_decode():
    ok = Message(1, 4, np.array([3.0, 4.0]), np.ones(34, np.float32))
    assert wire.decode(wire.encode_send(1, ok)) is not None
    bad = [wire.encode_send(0, Message(1, 4, np.array([np.inf, 4.0]), None)),
           _nan_at(wire.encode_send(0, Message(1, 4, np.array([3.0, 4.0]), None)), 15),
           wire.encode_send(1, Message(1, 4, np.array([3.0, 4.0]), np.full(34, np.nan, np.float32))),
           wire.encode_send(2, Message(1, 4, np.array([3.0, 4.0]), np.array([1.0, np.inf, 2.0, 3.0], np.float32))),
           wire.encode_delivery(1, 0, 4, [ok, Message(2, 4, np.array([np.nan, 1.0]), np.ones(34, np.float32))]),
           wire.encode_delivery(1, 0, 4, [Message(2, 4, np.array([1.0, 1.0]), np.full(34, np.inf, np.float32))])]
    assert [wire.decode(b) for b in bad] == [None] * len(bad)


def test_start_carries_a_robots_own_parameters_and_a_seed_that_is_not_the_scenarios():
    sc = Scenario.random(7, SimParams(world_size=512, num_robots=4, num_features=8))
    start = wire.decode(wire.encode_start(1, shared_seed(sc), 0, sc.params.to_dict()))
    assert set(start.params) == set(wire.ROBOT_PARAMS) and "num_features" not in start.params
    assert SimParams.from_dict(start.params).sensor_size == sc.params.sensor_size
    assert start.seed not in (7, 0) and shared_seed(sc) == shared_seed(Scenario.from_dict(sc.to_dict()))
    assert shared_seed(Scenario.random(8, sc.params)) != start.seed
    text = json.dumps({**start.params, "num_features": 8}).encode()  # a START that tells of the world
    forged = struct.pack("<BBIQiBI", wire.VERSION, wire.START, 1, 7, 0, 1, len(text)) + text
    assert wire.decode(forged) is None


def test_a_step_packets_absurd_position_is_clipped_and_an_absurd_window_dropped():
    p = SimParams(world_size=512, num_robots=4, num_features=8)
    s = p.sensor_size
    values = np.zeros((s, s), np.float32)
    far = wire.decode(wire.encode_step(0, 3, np.array([1e300, -1e300]), np.array([100, 100]), values))
    got = own_step(far, p)
    assert got.position_m.tolist() == [512 - 1e-4, 1e-4] and got.step == 3
    assert own_step(wire.decode(wire.encode_step(0, 3, np.array([1.0, 1.0]), np.array([2**62, 0]), values)), p) is None
    small = wire.decode(wire.encode_step(0, 3, np.array([1.0, 1.0]), np.array([0, 0]), values[:8, :8]))
    assert own_step(small, p) is None


def test_the_robot_acts_on_a_clipped_absurd_position():
    from madp.export.swarm import exported
    from madp.policies import SamplingSettings, shipped_checkpoint
    from madp.robot import RobotAgent, RobotRuntime
    from madp.sim.robot_maps import SensorReading

    p = SimParams(world_size=512, num_robots=4, num_features=8)
    runtime = RobotRuntime(exported(shipped_checkpoint("madp"), SamplingSettings()))
    agent = RobotAgent(0, runtime, p, 5)
    s = p.sensor_size
    packet = own_step(wire.decode(wire.encode_step(0, 0, np.array([1e300, 1e300]), np.array([480, 480]),
                                                   np.ones((s, s), np.float32))), p)
    agent.observe(0, packet.position_m, SensorReading(packet.lo_cell, packet.values))
    agent.token([])
    assert np.isfinite(agent.act([]).action_mps).all()


def test_more_robots_than_the_machine_holds_are_refused_in_one_line():
    check_capacity(4, memory_mb=4 * ROBOT_MB + 1, cores=1)
    with pytest.raises(SettingError, match=r"200 robot processes need about 48\.8 GB .* at most 94 robots"):
        check_capacity(200, memory_mb=23 * 1024, cores=64)
    with pytest.raises(SettingError, match=f"at most {ROBOTS_PER_CORE} per core"):
        check_capacity(ROBOTS_PER_CORE * 2 + 1, memory_mb=1e9, cores=2)


def test_steps_and_rates_are_bounded():
    check_run(MAX_STEPS, RATE_HZ[0])
    check_run(1, RATE_HZ[1])
    for steps, rate in ((MAX_STEPS + 1, None), (10**11, None), (0, None), (10, 1e-9), (10, 1e6), (10, float("nan"))):
        with pytest.raises(SettingError):
            check_run(steps, rate)
