"""madp datagen --policy: expert relabelling of a learned policy's rollouts (DAgger)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from madp.data_schema import Manifest, iter_shard
from madp.datagen.plan import scenario_seed
from madp.policies import SamplingSettings, shipped_checkpoint
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario, SimParams
from tests.test_reliability_errors import assert_one_line, cli

PARAMS = SimParams(world_size=256, num_robots=4, num_features=4)
SMALL = ["--num-robots", "4", "--num-features", "4", "--world-size", "256", "--samples-per-shard", "22",
         "--max-steps", "50", "--seed", "3"]


def madp(*args) -> None:
    """``madp ARGS`` in this process (no interpreter and torch start-up; ``--workers 2`` still starts two
    worker processes); it must succeed."""
    code, err = cli(*args)
    assert code == 0, err


def tree_bytes(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def first_episode(root: Path):
    m = Manifest.load(root / "manifest.json")
    b = next(iter_shard(m.shard_paths("train", root)[0]))
    first = b.episode_id == b.episode_id[0]
    return m, b, first


@pytest.fixture(scope="module")
def madp_relabelled(tmp_path_factory):
    root = tmp_path_factory.mktemp("relabel") / "w1"
    madp("datagen", "--n", 44, "--out", root, "--workers", 1, "--policy", shipped_checkpoint("madp"), "--beta", 0.25, *SMALL)
    return root


def test_relabelled_bytes_do_not_depend_on_workers(madp_relabelled, tmp_path):
    madp("datagen", "--n", 44, "--out", tmp_path / "w2", "--workers", 2, "--policy", shipped_checkpoint("madp"),
         "--beta", 0.25, *SMALL)
    assert tree_bytes(tmp_path / "w2") == tree_bytes(madp_relabelled)


def test_manifest_records_policy_beta_and_parent(madp_relabelled):
    from madp.io.checksum import sha256_file

    m, b, first = first_episode(madp_relabelled)
    pol = m.params["policy"]
    assert pol["sha256"] == sha256_file(shipped_checkpoint("madp")) and pol["kind"] == "madp" and pol["beta"] == 0.25
    prov = json.loads((shipped_checkpoint("madp").parent / "provenance.json").read_text())
    expert = prov["checkpoints"][shipped_checkpoint("madp").name]["dataset"]["command"]
    assert pol["parent"]["created_by"].startswith(expert)  # the data the policy learned from
    assert "--policy" in m.created_by and "--beta 0.25" in m.created_by
    # episodes run the whole horizon (t = 0, 5, ..., 50), not until the expert's labels are zero
    assert list(b.step[first]) == list(range(0, 51, 5))


def test_labels_are_the_expert_at_the_states_the_learner_visits(madp_relabelled):
    """Every label is the clairvoyant action at the recorded positions; with beta = 0.25 the swarm
    mostly follows MADP, so it leaves the path the expert alone would take."""
    m, b, first = first_episode(madp_relabelled)
    scen = Scenario.random(int(b.scenario_seed[0]), PARAMS)
    assert b.scenario_seed[0] == scenario_seed(3, "train", 0, 0)
    for k in np.flatnonzero(first):
        env = CoverageEnv(dataclasses.replace(scen, robots_m=b.positions[k].astype(np.float64)))
        np.testing.assert_allclose(b.actions[k], ClairvoyantCVT()(env), atol=1e-4)
    expert_env = CoverageEnv(scen)
    expert = ClairvoyantCVT()
    for _ in range(50):
        expert_env.step(expert(expert_env))
    assert np.abs(b.positions[first][-1] - expert_env.positions_m).max() > 1.0


def test_beta_one_is_the_expert_rollout(tmp_path):
    """beta = 1: every step executes the expert's action, so the states are the expert's own."""
    madp("datagen", "--n", 44, "--out", tmp_path / "b1", "--workers", 1, "--policy", shipped_checkpoint("lpac"), "--beta", 1,
         *SMALL)
    m, b, first = first_episode(tmp_path / "b1")
    env = CoverageEnv(Scenario.random(int(b.scenario_seed[0]), PARAMS))
    expert = ClairvoyantCVT()
    for t in range(51):
        u = expert(env)
        if t % 5 == 0:
            np.testing.assert_array_equal(b.positions[first][t // 5], env.positions_m.astype(np.float32))
            np.testing.assert_array_equal(b.actions[first][t // 5], u.astype(np.float32))
        env.step(u)


def test_relabelling_refusals(tmp_path):
    ckpt = tmp_path / "p.safetensors"
    ckpt.write_bytes(shipped_checkpoint("lpac").read_bytes())
    for args, needle in [(["--beta", 1.5, "--policy", ckpt], "--beta"), (["--beta", 0.5], "--beta"),
                         (["--select", "explore"], "--select"), (["--select", "explore", "--policy", ckpt], "--select"),
                         (["--select", "best", "--policy", shipped_checkpoint("madp")], "--select"),
                         (["--policy", tmp_path / "none.safetensors"], "none.safetensors")]:
        assert_one_line(*cli("datagen", "--n", 20, "--out", tmp_path / "x", *args, *SMALL), needle)
    # the checkpoint changes between the plan and a resumed run: its sha256 is part of the plan, so the
    # run is refused (a change while workers run is caught by the workers' own sha256 check)
    plan = tmp_path / "y"
    code, err = cli("datagen", "--n", 20, "--out", plan, "--policy", ckpt, "--shards", "0:1", "--workers", 1, *SMALL)
    assert code == 0, err
    ckpt.write_bytes(shipped_checkpoint("madp").read_bytes())
    assert_one_line(*cli("datagen", "--n", 20, "--out", plan, "--policy", ckpt, *SMALL), "other parameters")


def test_the_learner_draws_one_sample_per_robot_whatever_the_evaluation_default():
    """Relabelling rollouts are the learner's own actions: MADP with one sample per robot
    (``--select none``), not the evaluation default's choice among samples, so a dataset's bytes do
    not change with that default."""
    from madp.controllers import make_controller
    from madp.datagen.relabel import learner_driver, learner_settings
    from madp.policies import SamplingSettings
    from madp.selection import DEFAULT_RULE as DEFAULT_SELECT

    path, seed = shipped_checkpoint("madp"), 11
    drive = learner_driver(learner_settings(path), seed)
    one = make_controller("madp", str(path), seed=seed, sampling=SamplingSettings.of(select="none"))
    default = make_controller("madp", str(path), seed=seed)
    assert DEFAULT_SELECT != "none" and default.sampling.candidates > 1
    scen = Scenario.random(5, PARAMS)
    envs = [CoverageEnv(scen) for _ in range(3)]
    differs = False
    for _ in range(4):
        u_drive, u_one, u_default = drive(envs[0], None), one(envs[1]), default(envs[2])
        np.testing.assert_array_equal(u_drive, u_one)
        differs |= not np.array_equal(u_drive, u_default)
        for env in envs:
            env.step(u_drive)
    assert differs


def test_select_drives_as_the_evaluation_default_and_is_recorded(tmp_path):
    """``--select explore``: MADP drives choosing among its samples, as the evaluation default does
    (the same actions as that controller, step by step), and the plan and manifest say so."""
    from madp.controllers import make_controller
    from madp.datagen.relabel import learner_driver, learner_settings
    from madp.selection import DEFAULT_RULE as DEFAULT_SELECT

    path, seed = shipped_checkpoint("madp"), 11
    settings = learner_settings(path, select=DEFAULT_SELECT)
    assert settings["select"] == DEFAULT_SELECT and "select" not in learner_settings(path)
    default_sampling = make_controller("madp", str(path)).sampling
    assert (settings["candidates"], settings["sampling_steps"]) == (default_sampling.candidates,
                                                                     default_sampling.sampling_steps)
    # a plan that names the rule without K and S was made with K = 4 at S = 3, and still drives so
    old_plan = {k: v for k, v in settings.items() if k not in ("candidates", "sampling_steps")}
    old = make_controller("madp", str(path), seed=seed, sampling=SamplingSettings.of(candidates=4, sampling_steps=3))
    env_old = [CoverageEnv(Scenario.random(5, PARAMS)) for _ in range(2)]
    np.testing.assert_array_equal(learner_driver(old_plan, seed)(env_old[0], None), old(env_old[1]))
    drive, default = learner_driver(settings, seed), make_controller("madp", str(path), seed=seed)
    envs = [CoverageEnv(Scenario.random(5, PARAMS)) for _ in range(2)]
    for _ in range(4):
        u_drive, u_default = drive(envs[0], None), default(envs[1])
        np.testing.assert_array_equal(u_drive, u_default)
        for env in envs:
            env.step(u_drive)
    madp("datagen", "--n", 22, "--out", tmp_path / "s", "--workers", 1, "--policy", path, "--select", "explore",
         *SMALL)
    m = Manifest.load(tmp_path / "s" / "manifest.json")
    assert m.params["policy"]["select"] == "explore" and m.created_by.endswith("--select explore")
