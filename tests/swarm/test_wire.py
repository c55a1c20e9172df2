"""The bytes between a swarm's processes: every record decodes to what was encoded, and no bytes at all
(random, truncated, extended, flipped, of another version) make decoding raise: no packet may stop a
robot or the world."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from madp.errors import SettingError
from madp.robot import wire
from madp.robot.wire import (Command, Delivery, Hello, PHASE_BEACON, PHASE_TOKEN, Ready, Sent, Start, StepPacket, decode)
from madp.sim.network import Message


def records() -> list[bytes]:
    """One encoding of every kind of record."""
    rng = np.random.default_rng(0)
    tok = rng.standard_normal(34).astype(np.float32)
    beacons = [Message(1, 4, np.array([10.5, 20.25])), Message(3, 3, np.array([0.0, 1023.9]))]
    tokens = [Message(2, 5, np.array([1.0, 2.0]), tok)]
    return [
        wire.encode_hello(3, 12345),
        wire.encode_start(3, (1 << 62) | 5, 5, {"world_size": 512, "sensor_size": 64}, exact_position=False),
        wire.encode_ready(3),
        wire.encode_step(3, 7, np.array([100.25, 200.5]), np.array([-20, 168]), rng.random((64, 64), dtype=np.float32)),
        wire.encode_stop(3, 8),
        wire.encode_send(PHASE_BEACON, Message(3, 7, np.array([1.5, 2.5]))),
        wire.encode_send(PHASE_TOKEN, Message(3, 7, np.array([1.5, 2.5]), tok)),
        wire.encode_delivery(PHASE_BEACON, 3, 7, beacons),
        wire.encode_delivery(PHASE_TOKEN, 3, 7, tokens),
        wire.encode_delivery(PHASE_TOKEN, 3, 7, []),
        wire.encode_command(3, 7, np.array([-4.5, 0.125])),
    ]


def test_every_record_decodes_to_what_was_encoded():
    rng = np.random.default_rng(0)
    tok = rng.standard_normal(34).astype(np.float32)
    hello, start, ready, step, stop, beacon, token, dbeacons, dtokens, dempty, command = map(decode, records())
    assert hello == Hello(3, 12345) and ready == Ready(3)
    assert start == Start(3, (1 << 62) | 5, 5, {"world_size": 512, "sensor_size": 64}, False)
    assert isinstance(step, StepPacket) and (step.robot, step.step, step.stop) == (3, 7, False)
    assert step.position_m.tolist() == [100.25, 200.5] and step.lo_cell.tolist() == [-20, 168]
    assert step.values.dtype == np.float32 and np.array_equal(step.values, rng.random((64, 64), dtype=np.float32))
    assert isinstance(stop, StepPacket) and stop.stop and stop.step == 8
    assert isinstance(beacon, Sent) and beacon.phase == PHASE_BEACON and beacon.message.token is None
    assert np.array_equal(token.message.token, tok) and token.message.position_m.tolist() == [1.5, 2.5]
    assert isinstance(dbeacons, Delivery) and [(m.sender, m.step) for m in dbeacons.messages] == [(1, 4), (3, 3)]
    assert dbeacons.messages[1].position_m.tolist() == [0.0, 1023.9] and dbeacons.messages[0].token is None
    assert np.array_equal(dtokens.messages[0].token, tok) and dempty.messages == []
    assert isinstance(command, Command) and command.action_mps.tolist() == [-4.5, 0.125] and command.step == 7


def test_a_start_without_a_limit_and_non_finite_values_are_refused():
    assert decode(wire.encode_start(0, 0, None, {})).max_age is None
    assert decode(wire.encode_command(0, 1, np.array([np.nan, 0.0]))) is None
    assert decode(wire.encode_step(0, 1, np.array([np.inf, 0.0]), np.zeros(2), np.zeros((4, 4)))) is None
    assert decode(wire.encode_step(0, 1, np.zeros(2), np.zeros(2), np.full((4, 4), np.nan))) is None
    assert decode(wire.encode_start(0, 0, 1, {})[:-1] + b"[") is None  # JSON that is not an object
    assert decode(bytes([wire.VERSION + 1]) + records()[0][1:]) is None  # another version
    assert decode(records()[0] + b"\0") is None and decode(b"") is None and decode(None) is None


@pytest.mark.parametrize("bad,setting", [(lambda: wire.check_run_key("a/b"), "key"),
                                         (lambda: wire.check_run_key("*"), "key"),
                                         (lambda: wire.check_endpoint("127.0.0.1:7447"), "endpoint")])
def test_keys_and_endpoints_are_checked(bad, setting):
    with pytest.raises(SettingError) as e:
        bad()
    assert e.value.setting == setting


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_never_raise(data):
    decode(data)
    decode(bytes([wire.VERSION]) + data)


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(range(11)), st.integers(0, 10_000), st.integers(0, 255), st.binary(max_size=40),
       st.sampled_from(["cut", "flip", "append", "splice"]))
def test_damaged_records_never_raise(which, at, byte, extra, how):
    good = records()[which]
    at %= len(good)
    bad = {"cut": good[:at], "flip": good[:at] + bytes([byte]) + good[at + 1:], "append": good + extra,
           "splice": good[:at] + extra + good[at:]}[how]
    rec = decode(bad)
    assert rec is None or type(rec) in (Hello, Start, Ready, StepPacket, Sent, Delivery, Command)


def test_cost_messages_decode_with_their_costs_and_an_unknown_phase_is_refused():
    costs = np.array([0.5, -1.25, 3.0, 8.0], np.float32)
    sent = decode(wire.encode_send(wire.PHASE_COST, Message(2, 9, np.array([4.0, 5.0]), costs)))
    assert isinstance(sent, Sent) and sent.phase == wire.PHASE_COST and np.array_equal(sent.message.token, costs)
    got = decode(wire.encode_delivery(wire.PHASE_COST, 1, 9, [Message(2, 9, np.array([4.0, 5.0]), costs)]))
    assert isinstance(got, Delivery) and got.phase == wire.PHASE_COST and np.array_equal(got.messages[0].token, costs)
    assert decode(wire.encode_send(3, Message(2, 9, np.array([4.0, 5.0]), costs))) is None
    assert decode(wire.encode_delivery(3, 1, 9, [])) is None
