"""The network between the robots (``madp.sim.network``) and the environment over it: range, loss,
delay, the buffer's rules, failures, position noise, seeding, and the settings' one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from madp.errors import SettingError
from madp.sim import CoverageEnv, DecentralizedCVT, Scenario, SimParams
from madp.sim.network import LINK_DELIVERED, LINK_KEPT, LINK_LOST, Network, NetworkSettings

R_C = 100.0


def _net(n: int = 4, **kw) -> Network:
    """Robots on a line 5 m apart (all in range) over a network of settings ``kw``."""
    net = Network(NetworkSettings(**kw), n, R_C, 1024, seed=7)
    return net


def _line(n: int = 4) -> np.ndarray:
    return np.stack([100.0 + 5.0 * np.arange(n), np.full(n, 500.0)], axis=1)


def _run(net: Network, steps: int, n: int = 4) -> list:
    """Every robot sends its id and the step; what each holds after each step."""
    out = []
    for t in range(steps):
        net.record(t, _line(n))
        out.append(net.exchange("c", t, np.stack([np.arange(n), np.full(n, t)], 1).astype(float)))
    return out


def test_ideal_network_delivers_every_current_message_within_range():
    net = Network(NetworkSettings(), 3, R_C, 1024, seed=0)
    x = np.array([[100.0, 100.0], [150.0, 100.0], [300.0, 100.0]])  # robot 2 is 150 m from robot 1
    net.record(0, x)
    rec = net.exchange("c", 0, x)
    assert rec.valid.tolist() == [[False, True, False], [True, False, False], [False, False, False]]
    np.testing.assert_array_equal(rec.payload[0, 1], x[1])
    assert rec.sent_step[0, 1] == 0 and rec.sent_step[0, 2] == -1
    assert NetworkSettings().ideal and not NetworkSettings(loss=0.1).ideal


def test_delay_delivers_the_message_of_d_steps_ago():
    got = _run(_net(delay_steps=3), 6)
    assert not got[2].valid.any()  # nothing has arrived before step 3
    for t in range(3, 6):
        assert got[t].valid.sum() == 12
        assert (got[t].payload[..., 1][got[t].valid] == t - 3).all()  # the content of step t - 3
        assert (got[t].sent_step[got[t].valid] == t - 3).all()


def test_loss_rate_and_the_keep_and_drop_rules():
    n, steps = 12, 200
    lost = sum((~r.valid & ~np.eye(n, dtype=bool)).sum() for r in _run(_net(n, loss=0.3, missing="drop"), steps, n))
    assert abs(lost / (steps * n * (n - 1)) - 0.3) < 0.02
    kept = _run(_net(n, loss=0.3, max_age_steps=2), steps, n)
    ages = np.concatenate([(t - r.sent_step)[r.valid] for t, r in enumerate(kept)])
    assert ages.max() == 2 and (ages == 1).any()  # an older message stands in, never older than 2 steps
    held = sum(r.valid.sum() for r in kept)
    assert held > (1 - 0.3) * steps * n * (n - 1)  # keeping bridges lost messages


def test_links_say_what_happened_on_each_link():
    net = _net(6, loss=0.5, max_age_steps=3)
    _run(net, 5, 6)
    links = net.links("c")
    assert set(np.unique(links)) <= {0, LINK_DELIVERED, LINK_LOST, LINK_KEPT}
    assert (links == LINK_DELIVERED).any() and (links == LINK_LOST).any()
    assert (np.diag(links) == 0).all()


def test_same_seed_same_network_and_channels_draw_their_own_losses():
    a, b = _net(8, loss=0.5), _net(8, loss=0.5)
    np.testing.assert_array_equal(a.lost("c", 3), b.lost("c", 3))
    assert (a.lost("c", 3) != a.lost("d", 3)).any() and (a.lost("c", 3) != a.lost("c", 4)).any()
    other = Network(NetworkSettings(loss=0.5, seed=1), 8, R_C, 1024, seed=7)
    assert (other.lost("c", 3) != a.lost("c", 3)).any()


def test_failed_robots_stop_send_nothing_and_the_cost_counts_the_survivors():
    sc = Scenario.random(3, SimParams(num_robots=8, num_features=8))
    env = CoverageEnv(sc, network=NetworkSettings(fail_fraction=0.25, fail_step=2))
    dcvt = DecentralizedCVT()
    for _ in range(2):
        env.step(dcvt(env))
    failed = env.network.failed
    assert failed.sum() == 2 and not env.alive()[failed].any()
    before = env.positions_m.copy()
    env.step(dcvt(env))
    np.testing.assert_array_equal(env.positions_m[failed], before[failed])  # they no longer move
    assert not env.neighbour_view()[0][:, failed].any()  # and nobody hears from them
    from madp.sim.voronoi import coverage_cost

    assert env.cost() == coverage_cost(env.prefix, env.positions_m[~failed])


def test_position_noise_is_what_a_robot_uses_and_reports():
    sc = Scenario.random(4, SimParams(num_robots=6, num_features=8))
    env = CoverageEnv(sc, network=NetworkSettings(position_noise_m=5.0))
    err = env.estimates_m() - env.positions_m
    assert 0 < np.abs(err).max() < 30 and env.estimates_m() is not env.positions_m
    known, held = env.neighbour_view()
    i, j = np.argwhere(known)[0]
    np.testing.assert_array_equal(held[i, j], env.estimates_m()[j])  # what j reported
    exact = CoverageEnv(sc, network=NetworkSettings())
    assert exact.estimates_m() is exact.positions_m


@pytest.mark.parametrize("kw, field", [({"loss": 1.5}, "loss"), ({"delay_steps": -1}, "delay_steps"),
                                       ({"delay_steps": 5, "max_age_steps": 2}, "max_age_steps"),
                                       ({"missing": "maybe"}, "missing"), ({"position_noise_m": float("nan")},
                                                                           "position_noise_m")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(SettingError) as e:
        NetworkSettings(**kw)
    assert e.value.setting == field


def test_settings_parse_from_text():
    s = NetworkSettings.parse("loss=0.3, delay_steps=5,max_age_steps=10,missing=drop,position_noise_m=2")
    assert s == NetworkSettings(loss=0.3, delay_steps=5, max_age_steps=10, missing="drop", position_noise_m=2.0)
    with pytest.raises(SettingError, match="expected NAME=VALUE"):
        NetworkSettings.parse("latency=3")
    with pytest.raises(SettingError, match="expected a number"):
        NetworkSettings.parse("loss=high")


def test_weighted_sum_reduces_the_held_messages_of_every_step_as_the_payload_does():
    n = 10
    rng = np.random.default_rng(3)
    net = _net(n, loss=0.4, max_age_steps=3)
    for t in range(12):
        net.record(t, _line(n))
        sent = rng.normal(size=(n, 5))
        sent[0] = np.nan  # robot 0's messages are never held below: their content may not leak into a sum
        rec = net.exchange("c", t, sent, senders=np.arange(n) != 0)
        weights = rng.normal(size=(n, n))
        assert len(np.unique(rec.sent_step[rec.valid])) > (1 if t >= 3 else 0)  # messages of several steps
        np.testing.assert_allclose(rec.weighted_sum(weights), np.einsum("ij,ijf->if", np.where(rec.valid, weights, 0),
                                                                        rec.payload), rtol=1e-12, atol=1e-12)
        assert not rec.valid[:, 0].any()
