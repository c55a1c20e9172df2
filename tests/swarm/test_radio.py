"""The radio between robot processes: the network model with robots that did not send in a phase and
robots that fail at run time; each robot hears exactly what the model delivers to it."""

from __future__ import annotations

import numpy as np

from madp.sim.network import Message, Network, NetworkSettings
from madp.swarm.radio import Radio

N = 5
POSITIONS_M = np.array([[100.0, 100], [150, 100], [200, 120], [260, 90], [900, 900]])


def _network(**kw) -> Network:
    net = Network(NetworkSettings(**kw), N, 256.0, 1024, seed=3)
    net.record(0, POSITIONS_M)
    return net


def test_a_robot_that_did_not_send_is_not_heard_and_the_others_losses_stay():
    payload = np.arange(2 * N, dtype=float).reshape(N, 2)
    full = _network(loss=0.4).exchange("position", 0, payload)
    senders = np.array([True, False, True, True, True])
    part = _network(loss=0.4).exchange("position", 0, payload, senders)
    assert not part.valid[:, 1].any()
    keep = np.ones(N, bool)
    keep[1] = False
    assert np.array_equal(part.valid[:, keep], full.valid[:, keep])  # the same draws of loss on the other links
    assert full.valid.any() and not full.valid.all()


def test_a_robot_failed_at_run_time_stops_from_that_step():
    net = _network()
    assert net.alive(1).all()
    net.fail(2, 2)
    net.fail(2, 3)  # a later failure does not revive it earlier
    assert net.alive(1)[2] and not net.alive(2)[2] and not net.alive(3)[2] and net.failed[2]
    payload = np.ones((N, 2))
    for t in range(3):
        net.record(t, POSITIONS_M)
        rec = net.exchange("position", t, payload)
    assert not rec.valid[2].any() and not rec.valid[:, 2].any() and rec.valid[0, 1]


def test_the_radio_delivers_what_the_model_delivers_and_counts():
    net = _network(loss=0.3, seed=1)
    reference = _network(loss=0.3, seed=1)
    radio = Radio(net, token_dim=3)
    sent = {}
    for i in (0, 2, 3, 4):
        m = Message(i, 0, np.array([10.0 * i, 5.0]), np.full(3, i, np.float32))
        assert radio.accept("token", i, m, 60)
        sent[i] = m
    assert not radio.accept("token", 1, Message(2, 0, np.zeros(2), np.zeros(3, np.float32)), 60)  # not its own
    assert not radio.accept("token", 1, Message(1, 0, np.zeros(2), np.zeros(4, np.float32)), 60)  # wrong size
    heard = radio.exchange("token", 0, sent)
    payload = np.zeros((N, 5))
    for i, m in sent.items():
        payload[i] = [*m.position_m, *m.token]
    rec = reference.exchange("token", 0, payload, np.array([True, False, True, True, True]))
    for i in range(N):
        assert [m.sender for m in heard[i]] == list(np.flatnonzero(rec.valid[i]))
        for m in heard[i]:
            assert np.array_equal(m.token, sent[m.sender].token) and np.array_equal(m.position_m, sent[m.sender].position_m)
    assert radio.counts["token"].of(1) == {"sent": 0, "sent_bytes": 0, "late": 0, "malformed": 2, "delivered": 0,
                                           "delivered_bytes": 0}
    assert radio.counts["token"].total()["sent_bytes"] == 240
