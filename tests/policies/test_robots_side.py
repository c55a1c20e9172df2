"""Each robot on its own inbox (``madp.sim.network``): with an ideal network every controller gives the
actions of the batched computation on the true state, and a robot's action never depends on what it
has not received."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from madp.controllers import make_controller
from madp.policies import noise_generator
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.network import NetworkSettings

CONTROLLERS = ("dcvt", "lpac", "madp")


def _scenario(seed: int) -> Scenario:
    return Scenario.random(seed, SimParams(num_robots=16, num_features=16))


def _act(name: str, ctrl, envs: list[CoverageEnv], generators) -> np.ndarray:
    if name == "dcvt":
        return np.stack([ctrl(e) for e in envs])
    return ctrl.act_batch(envs, generators)


@pytest.mark.parametrize("name", CONTROLLERS)
def test_an_ideal_network_gives_the_true_state_actions(name):
    """DCVT and LPAC-K3 bit for bit; MADP (the evaluation default: K = 4, explore, d4 frame) to 1e-6 m/s,
    with the same noise, over a batch of two environments and 6 steps."""
    ctrl = make_controller(name)
    seeds = (11, 12)
    truth = [CoverageEnv(_scenario(s)) for s in seeds]
    robots = [CoverageEnv(_scenario(s), network=NetworkSettings()) for s in seeds]
    g_truth, g_robots = [noise_generator(s) for s in seeds], [noise_generator(s) for s in seeds]
    for _ in range(6):
        u, v = _act(name, ctrl, truth, g_truth), _act(name, ctrl, robots, g_robots)
        if name == "madp":
            np.testing.assert_allclose(v, u, rtol=0, atol=1e-6)
        else:
            np.testing.assert_array_equal(v, u)
        for e, f, x in zip(truth, robots, u):
            e.step(x)
            f.step(x)  # the same states, so every step compares the same inputs


def _silence(env: CoverageEnv, j: int) -> None:
    """From now on every message robot j sends is lost, on every channel (it stays in range)."""
    lost = env.network.lost

    def without_j(channel: str, step: int) -> np.ndarray:
        out = lost(channel, step).copy()
        out[:, j] = True
        return out

    env.network.lost = without_j


@pytest.mark.parametrize("name", CONTROLLERS)
@pytest.mark.parametrize("silenced", [True, False])
def test_an_action_does_not_change_with_what_the_robot_has_not_received(name, silenced):
    """Robot j's own map (so its observation and token) and position change between two copies of a
    swarm over a lossy network. When every message of j is lost, no other robot's action changes; when
    they arrive (the control), some robot's does."""
    ctrl = make_controller(name)
    env = CoverageEnv(_scenario(21), network=NetworkSettings(loss=0.2, max_age_steps=2))
    gen = noise_generator(21)
    for _ in range(4):
        env.step(_act(name, ctrl, [env], [gen])[0])
    j = 3
    if silenced:
        _silence(env, j)
        for _ in range(3):  # nothing from j arrives any more, and what was kept ages out (2 steps)
            env.step(_act(name, ctrl, [env], [gen])[0])
        assert not env.neighbour_view()[0][:, j].any()
    other = copy.deepcopy(env)
    other.maps.maps_padded[j] = np.roll(other.maps.maps_padded[j], 40, axis=0)  # what j has sensed
    other.positions_m[j] += 7.0  # and where it is (its position beacon of this step sent again)
    other._beacon()
    g1, g2 = copy.deepcopy(gen), copy.deepcopy(gen)
    u, v = _act(name, ctrl, [env], [g1])[0], _act(name, ctrl, [other], [g2])[0]
    rest = np.arange(len(u)) != j
    assert np.abs(v[j] - u[j]).max() > 1e-3  # the change matters to j itself
    if silenced:
        np.testing.assert_allclose(v[rest], u[rest], rtol=0, atol=1e-6)
    else:
        assert np.abs(v[rest] - u[rest]).max() > 1e-4


def test_lpac_reads_of_its_neighbours_only_what_they_sent():
    """With every message one step late, robot i's LPAC-K3 action at step t reads of robot j only what j
    sent at t − 1. Emptying what j holds now (its own graph, so its degree, which gcn_norm's edge
    weights use) changes j's action and no other robot's."""
    ctrl = make_controller("lpac")
    env = CoverageEnv(_scenario(21), network=NetworkSettings(delay_steps=1))
    for _ in range(3):
        env.step(ctrl(env))
    known = env.neighbour_view()[0]
    j = int(known.sum(1).argmax())  # a robot with neighbours, so its degree matters
    other = copy.deepcopy(env)
    other._received.valid[j, :] = False  # j now holds no neighbour; nothing it has sent changes
    u, v = ctrl(env), ctrl(other)
    rest = np.arange(len(u)) != j
    assert np.abs(v[j] - u[j]).max() > 1e-4
    np.testing.assert_allclose(v[rest], u[rest], rtol=0, atol=1e-6)


def test_a_late_token_is_used_only_in_the_frame_it_was_computed_in():
    """With every message one step late, a robot's MADP action ignores the tokens its neighbours sent at
    t − 1 when the frame of t − 1 differs from t's (d4: a token is computed in its own step's frame):
    changing those tokens changes nothing. At a step whose frame equals the last one's it uses them."""
    from madp.robot.frame import frame_element

    ctrl = make_controller("madp")
    env = CoverageEnv(_scenario(31), network=NetworkSettings(delay_steps=1))
    gen = noise_generator(31)
    checked = set()
    while len(checked) < 2 and env.steps < 40:
        t = env.steps
        same = t > 1 and frame_element(31, t - 1) == frame_element(31, t)
        if t > 1 and same not in checked:
            other = copy.deepcopy(env)
            ch = other.network._channels["token"]
            ch.sent[t - 1][0][:, 2:] += 3.0  # the tokens sent at t − 1 (in flight), changed
            g1, g2 = copy.deepcopy(gen), copy.deepcopy(gen)
            u, v = ctrl.act_batch([env], [g1])[0], ctrl.act_batch([other], [g2])[0]
            if same:
                assert np.abs(v - u).max() > 1e-4
            else:
                np.testing.assert_array_equal(v, u)
            checked.add(same)
        env.step(ctrl.act_batch([env], [gen])[0])
    assert checked == {True, False}


def test_the_runtime_drops_a_late_token_of_another_frame(tmp_path):
    from madp.robot import RobotRuntime
    from madp.robot.frame import frame_element
    from madp.sim.network import Message
    from tests.robot.robot_testutils import export_tiny

    from madp.policies import SamplingSettings

    export_tiny(tmp_path, SamplingSettings.of(select="none"))
    rt = RobotRuntime(tmp_path, max_age=1)
    seed = 5
    steps = [t for t in range(1, 40) if frame_element(seed, t - 1) != frame_element(seed, t)]
    same = [t for t in range(1, 40) if frame_element(seed, t - 1) == frame_element(seed, t)]
    obs, pos = np.zeros((4, 32, 32), np.float32), np.array([500.0, 500.0])
    for t, expect in ((steps[0], "other_frame"), (same[0], "accepted")):
        late = Message(1, t - 1, pos + 10.0, np.zeros(rt.token_dim, np.float32))
        counts = rt.step(0, t, obs, pos, [late], seed).counts.as_dict()
        assert counts[expect] == 1, counts
