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
    from madp.controllers import make_controller
    from madp.eval.runner import EvalConfig
    from madp.eval.runner import make_controller as eval_controller
    from madp.eval.suites import EnvSpec
    from madp.policies import shipped_checkpoint
    from madp.sim import rollout

    if name == "madp" and shipped_checkpoint("madp") is None:
        pytest.skip("no shipped MADP checkpoint in this install")
    spec, steps = EnvSpec("uniform", "uniform", 0, SMALL), 3
    reference = rollout(CoverageEnv(spec.scenario()),
                        eval_controller(name, EvalConfig(suite="uniform", madp=str(shipped_checkpoint("madp"))), spec), steps)
    pz = coverage_v0.parallel_env(scenario=spec, max_steps=steps)
    pz.reset(seed=0)
    policy = make_controller(name, seed=spec.seed)
    costs = [1.0]
    while pz.agents:
        _, _, _, _, infos = pz.step(pz.actions_from(policy))
        costs.append(infos["robot_0"]["normalized_cost"])
    np.testing.assert_array_equal(costs, reference.normalized_cost)
