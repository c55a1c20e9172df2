"""The network model's newer parts (``madp.sim.network``): bursty loss (Gilbert–Elliott), loss with
distance, bytes on the air and the bandwidth limit, a team without survivors, the bounds on sizes and
``NetworkSettings.parse``'s one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from madp.errors import SettingError
from madp.sim import CoverageEnv, DecentralizedCVT, Scenario, SimParams
from madp.sim.network import (HEADER_BYTES, MAX_NETWORK_STEPS, Message, Network, NetworkSettings, message_bytes)

R_C = 100.0


def _line(n: int, gap_m: float = 5.0) -> np.ndarray:
    return np.stack([100.0 + gap_m * np.arange(n), np.full(n, 500.0)], axis=1)


def _losses(net: Network, steps: int, n: int, x: np.ndarray, channel: str = "c") -> np.ndarray:
    """[steps, N, N] bool: which links in range lost the message of each step."""
    out = []
    for t in range(steps):
        net.record(t, x)
        net.exchange(channel, t, np.zeros((n, 1)))
        out.append(net.lost(channel, t) & net.in_range(t))
    return np.stack(out)


def _runs(lost: np.ndarray) -> float:
    """Mean length of the runs of consecutive lost steps, over every link."""
    lengths = []
    for series in lost.reshape(len(lost), -1).T:
        edges = np.diff(np.concatenate([[0], series.astype(int), [0]]))
        lengths += list(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1))
    return float(np.mean(lengths))


def test_bursts_keep_the_mean_loss_and_last_burst_len_steps():
    n, steps = 8, 600
    x = _line(n)
    iid = _losses(Network(NetworkSettings(loss=0.3), n, R_C, 1024, seed=3), steps, n, x)
    burst = _losses(Network(NetworkSettings(loss=0.3, burst_len=5), n, R_C, 1024, seed=3), steps, n, x)
    links = steps * n * (n - 1)
    assert abs(iid.sum() / links - 0.3) < 0.02 and abs(burst.sum() / links - 0.3) < 0.03
    assert _runs(iid) < 1.6 and 4.0 < _runs(burst) < 6.0  # i.i.d.: 1/(1 - 0.3); bursts: 5 steps on average


def test_bursts_are_drawn_from_the_seed_whatever_the_order_of_the_questions():
    s = NetworkSettings(loss=0.3, burst_len=4)
    a, b = Network(s, 6, R_C, 1024, seed=9), Network(s, 6, R_C, 1024, seed=9)
    walked = [a.lost("c", t) for t in range(30)]
    np.testing.assert_array_equal(b.lost("c", 29), walked[29])  # straight to step 29: the same chain
    np.testing.assert_array_equal(b.lost("c", 7), walked[7])  # and back
    np.testing.assert_array_equal(a.lost("lpac/7", 29), walked[29])  # a link in a burst loses every channel


def test_a_burst_takes_every_round_of_a_step_at_once():
    """LPAC-K3's rounds inside one step are not independent under bursts: a link that loses one loses all
    (i.i.d. loss draws each round afresh)."""
    n = 8
    x = _line(n)
    for settings, together in ((NetworkSettings(loss=0.3, burst_len=4), True), (NetworkSettings(loss=0.3), False)):
        net = Network(settings, n, R_C, 1024, seed=2)
        net.record(5, x)
        rounds = np.stack([net.lost(f"lpac/{r}", 5) for r in range(15)])
        assert (rounds == rounds[0]).all() == together


def test_loss_rises_with_distance():
    n, steps = 2, 4000
    near = _losses(Network(NetworkSettings(loss_at_range=0.8), n, R_C, 1024, seed=1), steps, n, _line(n, 20.0))
    far = _losses(Network(NetworkSettings(loss_at_range=0.8), n, R_C, 1024, seed=1), steps, n, _line(n, 90.0))
    links = steps * n * (n - 1)
    assert abs(near.sum() / links - 0.8 * 0.2 ** 2) < 0.01  # 0.8 (d / r_c)^2 at 20 m
    assert abs(far.sum() / links - 0.8 * 0.9 ** 2) < 0.02
    both = _losses(Network(NetworkSettings(loss=0.5, loss_at_range=0.8), n, R_C, 1024, seed=1), steps, n, _line(n, 90.0))
    assert abs(both.sum() / links - (1 - 0.5 * (1 - 0.8 * 0.81))) < 0.02  # two independent causes


def test_a_message_is_as_many_bytes_as_madp_swarm_puts_on_the_wire():
    from madp.robot.wire import PHASE_BEACON, PHASE_TOKEN, encode_send

    beacon, token = Message(3, 7, np.array([1.0, 2.0])), Message(3, 7, np.array([1.0, 2.0]), np.zeros(34, np.float32))
    assert message_bytes("position", 2) == len(encode_send(PHASE_BEACON, beacon)) == 35
    assert message_bytes("token", 36) == len(encode_send(PHASE_TOKEN, token)) == 35 + 4 * 34
    assert message_bytes("lpac/4", 256) == HEADER_BYTES + 4 * 256


def test_bytes_are_counted_per_robot_step_and_channel_once_per_broadcast():
    n = 4
    net = Network(NetworkSettings(fail_fraction=0.25, fail_step=2), n, R_C, 1024, seed=0)
    for t in range(4):
        net.record(t, _line(n))
        net.exchange("position", t, _line(n))
        net.exchange("token", t, np.zeros((n, 36)), senders=np.array([True, True, True, False]))
        net.exchange("token", t, np.zeros((n, 36)), senders=np.array([True, True, True, False]))  # sent again: once
    sent = net.bytes_sent(4)
    assert set(sent) == {"position", "token"} and sent["position"].shape == (4, n)
    failed = net.failed
    assert (sent["position"][:2] == 35).all() and (sent["position"][2:, failed] == 0).all()
    assert (sent["position"][2:, ~failed] == 35).all()
    assert (sent["token"][:, 3] == 0).all() and (sent["token"][:2, :3] == 171).all()
    per = net.bytes_per_robot_step(4)  # over the 2 · 4 + 2 · 3 steps of running robots
    assert per["total"] == pytest.approx((sent["position"].sum() + sent["token"].sum()) / 14)
    assert per["position"] == 35 and per["token"] == pytest.approx(sent["token"].sum() / 14)


def test_bandwidth_sends_first_come_first_sent_and_holds_back_the_rest():
    n = 3
    net = Network(NetworkSettings(max_bytes_per_step=35 + 171 + 50), n, R_C, 1024, seed=0)
    net.record(0, _line(n))
    assert net.exchange("position", 0, _line(n)).valid.sum() == 6
    assert net.exchange("token", 0, np.ones((n, 36))).valid.sum() == 6  # 206 bytes: within the budget
    assert not net.exchange("lpac/0", 0, np.ones((n, 34))).valid.any()  # 155 more bytes: over it, not sent
    assert net.exchange("lpac/1", 0, np.ones((n, 2))).valid.sum() == 6  # 27 bytes still fit
    assert (net.bytes_sent(1)["lpac/0"] == 0).all() and (net.bytes_sent(1)["lpac/1"] == 27).all()
    net.record(1, _line(n))
    assert net.exchange("position", 1, _line(n)).valid.sum() == 6  # a new step, a new budget


def test_a_team_without_survivors_is_an_error_not_a_score():
    with pytest.raises(SettingError, match="fail_fraction"):
        NetworkSettings(fail_fraction=1.0)
    with pytest.raises(SettingError, match="no robot would survive") as e:
        CoverageEnv(Scenario.random(2, SimParams(num_robots=3, num_features=4)),
                    network=NetworkSettings(fail_fraction=0.9))  # round(2.7) = 3 of 3
    assert e.value.setting == "network"


def test_survivors_from_the_start_are_the_survivors_of_the_failure():
    sc = Scenario.random(5, SimParams(num_robots=8, num_features=8))
    late = CoverageEnv(sc, network=NetworkSettings(fail_fraction=0.25, fail_step=3))
    start = CoverageEnv(sc, network=NetworkSettings(fail_fraction=0.25, fail_step=0))
    np.testing.assert_array_equal(late.network.failed, start.network.failed)
    assert start.cost0 == late.cost0 and not start.alive()[start.network.failed].any()
    assert start.normalized_cost() > 1.0  # J of the 6 survivors over J(0) of all 8
    before = start.positions_m.copy()
    start.step(DecentralizedCVT()(start))
    np.testing.assert_array_equal(start.positions_m[start.network.failed], before[start.network.failed])


@pytest.mark.parametrize("kw, field", [({"delay_steps": MAX_NETWORK_STEPS + 1}, "delay_steps"),
                                       ({"max_age_steps": 1_000_000_000}, "max_age_steps"),
                                       ({"burst_len": 0.5}, "burst_len"), ({"loss": 0.9, "burst_len": 2}, "burst_len"),
                                       ({"loss_at_range": -0.1}, "loss_at_range"),
                                       ({"max_bytes_per_step": -1}, "max_bytes_per_step"),
                                       ({"fail_fraction": 1.0}, "fail_fraction")])
def test_new_settings_and_sizes_are_bounded(kw, field):
    with pytest.raises(SettingError) as e:
        NetworkSettings(**kw)
    assert e.value.setting == field
    if "steps" in field:
        assert str(MAX_NETWORK_STEPS) in str(e.value)


def test_default_settings_stay_ideal_and_parse_round_trips():
    assert NetworkSettings().ideal and NetworkSettings(burst_len=3).ideal
    assert not NetworkSettings(loss_at_range=0.1).ideal and not NetworkSettings(max_bytes_per_step=10**6).ideal
    s = NetworkSettings.parse("loss=0.3,burst_len=5,loss_at_range=0.6,max_bytes_per_step=2000")
    assert s == NetworkSettings(loss=0.3, burst_len=5.0, loss_at_range=0.6, max_bytes_per_step=2000)


@pytest.mark.parametrize("text, needle", [("", "NAME=VALUE"), (",,", "NAME=VALUE"), ("loss=0.3,", "NAME=VALUE"),
                                          ("loss=0.1,loss=0.9", "loss is given twice"),
                                          ("loss=1.5", "loss: expected a probability"),
                                          ("seed=-1", "seed: expected a whole number"),
                                          ("delay_steps=2.5", "delay_steps: expected a whole number"),
                                          ("max_age_steps=1000000000", f"max_age_steps: expected a whole number in [0, {MAX_NETWORK_STEPS}]")])
def test_parse_errors_name_the_network_and_the_key(text, needle):
    with pytest.raises(SettingError) as e:
        NetworkSettings.parse(text)
    assert e.value.setting == "network" and str(e.value).startswith("network: ") and needle in str(e.value)
