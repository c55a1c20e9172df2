"""PettingZoo's and Gymnasium's own checkers on madp.envs, on a small world so they run in seconds."""

import numpy as np
import pytest

pytest.importorskip("pettingzoo")
pytest.importorskip("gymnasium")

from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test  # noqa: E402

from madp.envs import coverage_v0  # noqa: E402
from madp.sim import CoverageEnv, Scenario, SimParams  # noqa: E402

SMALL = SimParams(world_size=128, local_map_size=64, sensor_size=16, num_robots=4, num_features=3,
                  sigma_range_m=(10.0, 20.0), comm_radius_m=48.0)
KW = dict(params=SMALL, max_steps=12, render_mode="rgb_array", render_size=64)


def test_parallel_api():
    parallel_api_test(coverage_v0.parallel_env(**KW), num_cycles=30)


@pytest.mark.filterwarnings("ignore:Observation:UserWarning")  # a Dict observation is this env's design
def test_aec_api():
    api_test(coverage_v0.env(**KW), num_cycles=30)


def test_seeding():
    parallel_seed_test(lambda: coverage_v0.parallel_env(**KW), num_cycles=20)
    seed_test(lambda: coverage_v0.env(**KW), num_cycles=20)


def test_same_world_as_the_simulator():
    """Same scenario, same actions: same positions, observations, and rewards summing to 1 − J(T)/J(0)."""
    scenario = Scenario.random(3, SMALL)
    pz = coverage_v0.parallel_env(scenario=scenario, max_steps=5)
    obs, _ = pz.reset(seed=1)
    sim = CoverageEnv(scenario)
    rng = np.random.default_rng(0)
    total = 0.0
    for _ in range(5):
        u = rng.uniform(-8, 8, (4, 2))  # beyond u_max: both clip the speed
        obs, rew, term, trunc, info = pz.step({f"robot_{i}": u[i] for i in range(4)})
        sim.step(u)
        total += rew["robot_0"]
        assert len(set(rew.values())) == 1
    assert all(trunc.values()) and not any(term.values()) and pz.agents == []
    np.testing.assert_array_equal(obs["robot_2"]["maps"], sim.observations()[2])
    np.testing.assert_allclose(obs["robot_1"]["position"], sim.positions_m[1], rtol=1e-6)
    assert total == pytest.approx(1.0 - sim.normalized_cost(), abs=1e-12)
    assert info["robot_0"]["normalized_cost"] == pytest.approx(sim.normalized_cost())


def test_neighbours_within_comm_radius():
    p = np.array([[10.0, 10.0], [20.0, 10.0], [100.0, 100.0], [10.0, 40.0]])
    table, mask = coverage_v0.neighbour_table(p, 31.0)
    assert mask.tolist() == [[1, 1, 0], [1, 0, 0], [0, 0, 0], [1, 0, 0]]  # |x1 - x3| = 31.6 > r_c
    np.testing.assert_array_equal(table[0, :2], [[10, 0], [0, 30]])  # nearest first
    assert not table[2].any()


def test_render_frame():
    pz = coverage_v0.parallel_env(**KW)
    pz.reset(seed=0)
    frame = pz.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
    assert (frame == 0).all(axis=2).any()  # robots drawn
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 3


def test_render_is_the_video_frame():
    """Both envs' render() at step t is frame t of the rollout's video: one renderer, with the trails
    since the reset, the step and J(t)/J(0)."""
    import gymnasium

    from madp.controllers import make_controller
    from madp.video import rollout_frames

    scenario = Scenario.random(3, SMALL)
    pz = coverage_v0.parallel_env(scenario=scenario, max_steps=6, render_mode="rgb_array", render_size=64)
    gym = gymnasium.make("madp/Coverage-v0", scenario=scenario, max_steps=6, render_mode="rgb_array", render_size=64)
    pz.reset(seed=0)
    gym.reset(seed=0)
    dcvt = make_controller("dcvt")
    frames, positions, costs = [pz.render()], [pz.state()], [1.0]
    while pz.agents:
        _, _, _, _, infos = pz.step(pz.actions_from(dcvt))
        gym.step(gym.unwrapped.actions_from(dcvt))
        frames.append(pz.render())
        positions.append(pz.state())
        costs.append(infos["robot_0"]["normalized_cost"])
    np.testing.assert_array_equal(gym.render(), frames[-1])
    video = list(rollout_frames(pz.sim.world_map, np.stack(positions), np.array(costs), 64))
    assert len(video) == len(frames) == 7
    for got, want in zip(frames, video):
        np.testing.assert_array_equal(got, want)
    assert (frames[-1] != frames[0]).any()
    pz.reset(seed=0)
    np.testing.assert_array_equal(pz.render(), frames[0])  # a reset clears the trails


def test_gymnasium_checker():
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    import madp.envs  # noqa: F401  (registers madp/Coverage-v0)

    env = gymnasium.make("madp/Coverage-v0", params=SMALL, max_steps=6, render_mode="rgb_array", render_size=64)
    check_env(env.unwrapped, skip_render_check=False)
    obs, info = env.reset(seed=5)
    assert obs["maps"].shape == (4, 4, 32, 32) and obs["positions"].shape == (4, 2)
    sim = CoverageEnv(Scenario.random(5, SMALL))  # reset(seed=s) replays madp's scenario of seed s
    np.testing.assert_array_equal(obs["maps"], sim.observations())
    for t in range(6):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert truncated and not terminated


@pytest.mark.parametrize("name", ["dcvt", "madp"])
def test_env_driven_by_a_controller_matches_madp_eval(name):
    """The PettingZoo env driven by a controller gives the J(t)/J(0) of madp eval's own loop, bit for bit."""
    from madp.eval.runner import EvalConfig
    from madp.eval.suites import EnvSpec
    from madp.policies import shipped_checkpoint
    from madp.sim import rollout

    if name == "madp" and shipped_checkpoint("madp") is None:
        pytest.skip("no shipped MADP checkpoint in this install")
    spec, steps = EnvSpec("uniform", "uniform", 0, SMALL), 3
    reference = rollout(CoverageEnv(spec.scenario()),
                        EvalConfig(suite="uniform", madp=str(shipped_checkpoint("madp"))).controller(name, spec), steps)
    np.testing.assert_array_equal(env_costs(name, spec, steps), reference.normalized_cost)


def env_costs(name: str, spec, steps: int) -> list[float]:
    """J(t)/J(0), t = 0..steps, of the PettingZoo env on ``spec`` driven by controller ``name`` (the
    shipped checkpoint; MADP's noise seeded by the scenario's seed, as madp eval does)."""
    from madp.controllers import make_controller

    pz = coverage_v0.parallel_env(scenario=spec, max_steps=steps)
    pz.reset(seed=0)
    policy = make_controller(name, seed=spec.seed)
    costs = [1.0]
    while pz.agents:
        _, _, _, _, infos = pz.step(pz.actions_from(policy))
        costs.append(infos["robot_0"]["normalized_cost"])
    return costs


def shipped_madp_on_cities(tmp_path, steps: int):
    """The shipped MADP (decentralized, default sampler) on the first ``cities`` environment for
    ``steps`` steps, by ``madp eval`` and by the env: (eval's J(t)/J(0) curve, the env's, the spec)."""
    import pyarrow.parquet as pq

    from madp.eval.runner import EvalConfig, run_suite
    from madp.eval.suites import suite_envs
    from madp.policies import shipped_checkpoint

    if shipped_checkpoint("madp") is None:
        pytest.skip("no shipped MADP checkpoint in this install")
    spec = suite_envs("cities", 1)[0]
    cfg = EvalConfig(suite="cities", out=str(tmp_path), num_envs=1, steps=steps, controllers=("madp",), workers=1,
                     madp=str(shipped_checkpoint("madp")))
    run_suite(cfg, "cities", progress=False)
    curves = pq.read_table(tmp_path / "cities" / "curves.parquet").to_pandas()
    evaluated = curves[(curves.group == spec.group) & (curves.controller == "madp")].sort_values("step").cost.to_numpy()
    return evaluated, np.array(env_costs("madp", spec, steps)), spec


def test_shipped_madp_env_matches_madp_eval_on_a_city(tmp_path):
    """``madp eval`` and the env driven by the shipped MADP (decentralized): the same J(t)/J(0) curve on a
    full-size ``cities`` environment (the 600-step run of the done-when is the slow test below)."""
    evaluated, env, _ = shipped_madp_on_cities(tmp_path, 20)
    assert len(evaluated) == 21
    np.testing.assert_array_equal(env, evaluated)


@pytest.mark.slow
def test_shipped_madp_600_steps_env_eval_and_rollout_agree(tmp_path):
    """The env driven by the shipped MADP for 600 steps gives madp eval's
    J(600)/J(0) for that scenario (same seed), and so does ``madp rollout`` on the scenario as a file."""
    import json
    import subprocess
    import sys

    evaluated, env, spec = shipped_madp_on_cities(tmp_path, 600)
    np.testing.assert_array_equal(env, evaluated)
    scenario_file = tmp_path / "city.json"
    spec.scenario().save(scenario_file)
    out = tmp_path / "rollout.json"
    r = subprocess.run([sys.executable, "-m", "madp.cli", "rollout", "--scenario", str(scenario_file), "--controller",
                        "madp", "--steps", "600", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rolled = json.loads(out.read_text())["cost"]
    print(f"{spec.group}: J(600)/J(0) eval {evaluated[-1]!r}, env {env[-1]!r}, rollout {rolled[-1]!r}")
    assert rolled[-1] == env[-1]
