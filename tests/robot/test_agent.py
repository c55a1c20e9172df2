"""The robot agent: one robot holding only what reaches it (its own sensor readings, its position
estimate, the messages its radio delivered) computes, step after step of a whole rollout, exactly the
observation and selection view the simulator computes for it among all robots, and the action of the
one-process swarm of robot runtimes (``madp rollout --runtime onnx``); its map holds its readings and
nothing else; bad beacons are dropped, never raised."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

import madp.export.swarm as swarm
from madp.export.swarm import OnnxMADPPolicy, token_inboxes
from madp.robot import RobotAgent, RobotRuntime, SensorReading
from madp.robot.choice import explore_prior, local_views
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.network import Message, NetworkSettings
from tests.robot.robot_testutils import export_tiny

PARAMS = SimParams(world_size=512, num_robots=8, num_features=8)
LOSSY = NetworkSettings(loss=0.3, max_age_steps=2, position_noise_m=2.0, seed=1)


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("agent-export")
    export_tiny(out)
    return out


def _swarm(env: CoverageEnv, runtime: RobotRuntime) -> list[RobotAgent]:
    from madp.swarm.world import shared_seed

    seed = shared_seed(env.scenario)  # what a swarm's START hands each robot
    exact = env.network is None or env.network.settings.position_noise_m == 0
    return [RobotAgent(i, runtime, env.params, seed, exact_position=exact) for i in range(env.num_robots)]


@pytest.mark.parametrize("network", [None, LOSSY], ids=["no-network", "lossy-noisy"])
def test_agents_hold_the_swarms_rows_and_act_as_the_one_process_swarm(tiny_dir, monkeypatch, network):
    """8 robots, 100 steps (windows past the world's border, neighbourhoods changing): each agent, fed only its own
    reading, estimate and the beacons and tokens the environment's network delivered to it, holds
    ``env.observations()[i]`` and the batched LocalViews row i bit for bit, and acts within 1e-4 m/s of
    the one-process swarm with robot noise (which runs on the same environment first)."""
    monkeypatch.setattr(swarm, "exported", lambda policy, sampling: tiny_dir)
    env = CoverageEnv(Scenario.random(3, PARAMS, launch=(40.0, 40.0, 260.0, 260.0)), network=network)
    reference = OnnxMADPPolicy("tiny", noise="robot")
    agents = _swarm(env, RobotRuntime(tiny_dir, max_age=0 if network is None else network.max_age))
    assert agents[0].runtime.rule == "explore"  # the rule that reads the map and the explored map
    worst, kept, lost, n, border = 0.0, 0, 0, env.num_robots, False
    for _ in range(100):
        want, _ = reference.act(env, None)
        obs, views = env.observations(), explore_prior(env, local_views(env))
        readings, own, beacons = env.sensor_readings(), env.estimates_m(), env.beacons()
        sent = []
        for i, agent in enumerate(agents):
            agent.observe(env.steps, own[i], readings[i])
            sent.append(agent.token(beacons[i]))
            assert np.array_equal(agent.observation, obs[i]), (env.steps, i)
            border |= bool(obs[i, 3].any())
            assert np.array_equal(sent[i].token, reference.sent[i].token)
        inboxes = token_inboxes(env, sent)
        actions = np.stack([agent.act(inboxes[i]).action_mps for i, agent in enumerate(agents)])
        for i, agent in enumerate(agents):
            row = agent.view
            for k in ("start_m", "offset_m", "weights", "origin_m"):
                assert np.array_equal(getattr(row, k)[0], getattr(views, k)[i]), (env.steps, i, k)
            assert np.array_equal(row.neighbours_m[0][row.valid[0]], views.neighbours_m[i][views.valid[i]])
        worst = max(worst, float(np.abs(actions - want).max()))
        heard = np.zeros((n, n), bool)
        for i, b in enumerate(beacons):
            heard[i, [m.sender for m in b]] = True
            kept += sum(m.step < env.steps for m in b)
        lost += int((env.neighbours() & ~heard).sum())
        env.step(actions)
    assert worst <= 1e-4
    moved = np.linalg.norm(env.positions_m - env.start_m, axis=1)
    assert moved.min() > 5.0 and border
    assert (kept > 0 and lost > 0) if network is not None else (kept == 0 and lost == 0)


def test_an_agents_map_is_its_readings_and_nothing_else(tiny_dir):
    """Robot 2's map (one robot's padded map, no world map) is the world inside the union of the
    squares of the readings it was given and zero everywhere else; a reading changed after it was
    given changes nothing the agent holds; two agents given the same inputs hold the same bits."""
    env = CoverageEnv(Scenario.random(5, PARAMS, launch=(30.0, 30.0, 70.0, 70.0)))
    rt = RobotRuntime(tiny_dir)
    a, b = RobotAgent(2, rt, env.params, 5), RobotAgent(2, rt, env.params, 5)
    w, s = PARAMS.world_size, PARAMS.sensor_size
    seen = np.zeros((w, w), bool)
    rng = np.random.default_rng(0)
    for _ in range(25):
        reading = env.sensor_readings()[2]
        x0, y0 = reading.lo_cell
        seen[max(x0, 0):max(x0 + s, 0), max(y0, 0):max(y0 + s, 0)] = True
        for agent in (a, b):
            agent.observe(env.steps, env.estimates_m()[2], SensorReading(reading.lo_cell.copy(), reading.values.copy()))
            agent.token(env.beacons()[2])
        reading.values[:] = 7.0  # the agent holds its own copy
        assert np.array_equal(a.observation, b.observation)
        env.step(rng.normal(0, 2, (env.num_robots, 2)) - 4.0)  # towards the lower-left corner: outside too
    maps = a.maps
    assert maps.world_padded is None and maps.maps_padded.shape == (1, w + 2 * maps.pad, w + 2 * maps.pad)
    assert np.array_equal(maps.robot_map(0), np.where(seen, env.world_map_f32, np.float32(0)))
    outside = maps.maps_padded[0].copy()
    outside[maps.pad:maps.pad + w, maps.pad:maps.pad + w] = 0.0
    assert not outside.any()  # nothing outside the world
    assert seen.any() and not seen.all() and np.array_equal(maps.maps_padded, b.maps.maps_padded)
    assert np.array_equal(maps.explored, env.maps.explored[2:3])


def test_bad_beacons_are_dropped_never_raised(tiny_dir):
    """Garbage, non-finite, own, future, stale and wrongly shaped beacons leave the observation as the
    good beacons alone make it; a sender heard twice is dropped (which one is genuine cannot be told)."""
    env = CoverageEnv(Scenario.random(1, SimParams(world_size=512, num_robots=4, num_features=4),
                                      launch=(200.0, 200.0, 300.0, 300.0)))
    rt = RobotRuntime(tiny_dir)
    reading, own, good = env.sensor_readings()[0], env.estimates_m()[0], env.beacons()[0]

    def observation(beacons):
        agent = RobotAgent(0, rt, env.params, 0)
        agent.observe(0, own, reading)
        agent.token(beacons)
        return agent.observation

    p = good[0].position_m
    bad = [None, "beacon", 3, Message(True, 0, p), Message(1, 0.5, p), Message(1, 0, np.array([np.nan, 1.0])),
           Message(1, 0, np.zeros(3)), Message(0, 0, p + 1.0), Message(1, 1, p), Message(1, -1, p),
           Message("x", 0, p)]
    want = observation(good)
    assert want[1:3].any()  # its neighbours are on the map
    assert np.array_equal(observation(bad + good[::-1] + bad), want)
    twice = good + [Message(good[0].sender, 0, good[0].position_m + 3.0)]
    assert np.array_equal(observation(twice), observation(good[1:]))


def test_rollout_onnx_runtime_is_the_agents_swarm(tmp_path, monkeypatch):
    """``madp rollout --runtime onnx`` (the shipped policy's export, robot noise) ends where a swarm of
    agents on the same scenario ends, step for step; a controller other than MADP, an unknown runtime
    and a missing onnxruntime are one-line errors."""
    from madp.export.swarm import exported
    from madp.policies import SamplingSettings, shipped_checkpoint
    from tests.test_reliability_errors import assert_one_line, cli

    sc = tmp_path / "s.json"
    sc.write_text(json.dumps({"features": [{"mean": [60, 70], "sigma": 15, "peak": 0.8}],
                              "robots": [[40, 40], [60, 50], [50, 70]], "seed": 4,
                              "params": {"world_size": 128, "local_map_size": 64, "sensor_size": 16}}))
    out = tmp_path / "r.json"
    code, err = cli("rollout", "--scenario", sc, "--controller", "madp", "--runtime", "onnx", "--steps", "4",
                    "--out", out)
    assert code == 0, err
    cost = json.loads(out.read_text())["cost"]
    env = CoverageEnv(Scenario.load(sc))
    agents = _swarm(env, RobotRuntime(exported(shipped_checkpoint("madp"), SamplingSettings())))
    mine = [1.0]
    for _ in range(4):
        readings, own, beacons = env.sensor_readings(), env.estimates_m(), env.beacons()
        for i, agent in enumerate(agents):
            agent.observe(env.steps, own[i], readings[i])
        inboxes = token_inboxes(env, [agent.token(beacons[i]) for i, agent in enumerate(agents)])
        env.step(np.stack([agent.act(inboxes[i]).action_mps for i, agent in enumerate(agents)]))
        mine.append(env.normalized_cost())
    assert np.allclose(cost, mine, rtol=0, atol=1e-9) and cost[-1] < 1.0

    assert_one_line(*cli("rollout", "--scenario", sc, "--controller", "dcvt", "--runtime", "onnx"), "--runtime", "dcvt")
    assert_one_line(*cli("rollout", "--scenario", sc, "--controller", "madp", "--runtime", "tensorrt"), "--runtime")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "onnxruntime" else real(name, *a))
    assert_one_line(*cli("rollout", "--scenario", sc, "--controller", "madp", "--runtime", "onnx", "--out", out),
                    "onnxruntime")
