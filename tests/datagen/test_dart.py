"""madp datagen --dart-sigma: the expert labels, its noisy actions drive, the noise is the scenario's."""

from pathlib import Path

import numpy as np
import pytest

from madp.data_schema import Manifest, iter_shard
from madp.datagen import DatagenConfig
from madp.datagen.episodes import DART_STREAM
from madp.datagen.plan import scenario_seed
from madp.policies import shipped_checkpoint
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario, SimParams
from madp.sim.rules import clip_speed
from tests.test_reliability_errors import assert_one_line, cli

PARAMS = SimParams(world_size=256, num_robots=4, num_features=4)
SMALL = ["--num-robots", "4", "--num-features", "4", "--world-size", "256", "--samples-per-shard", "22",
         "--max-steps", "50", "--seed", "3"]
SIGMA_MPS = 2.0


def madp(*args) -> None:
    """``madp ARGS`` in this process; it must succeed."""
    code, err = cli(*args)
    assert code == 0, err


def tree_bytes(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def dart(tmp_path_factory):
    root = tmp_path_factory.mktemp("dart") / "w1"
    madp("datagen", "--n", 44, "--out", root, "--workers", 1, "--dart-sigma", SIGMA_MPS, *SMALL)
    return root


def test_labels_are_the_noiseless_expert_while_its_noisy_actions_drive(dart):
    """Replaying the first episode by hand — the expert's action plus N(0, σ²) from the scenario
    seed's own stream, clipped to u_max — gives exactly the recorded labels and positions; the
    positions leave those of the noiseless expert, and the episode runs to max_steps."""
    m = Manifest.load(dart / "manifest.json")
    b = next(iter_shard(m.shard_paths("train", dart)[0]))
    first = b.episode_id == b.episode_id[0]
    seed = int(b.scenario_seed[0])
    assert seed == scenario_seed(3, "train", 0, 0)
    assert list(b.step[first]) == list(range(0, 51, 5))
    env, clean = CoverageEnv(Scenario.random(seed, PARAMS)), CoverageEnv(Scenario.random(seed, PARAMS))
    expert, clean_expert = ClairvoyantCVT(), ClairvoyantCVT()
    rng = np.random.default_rng([seed, DART_STREAM])
    for t in range(51):
        u = expert(env)
        if t % 5 == 0:
            np.testing.assert_array_equal(b.actions[first][t // 5], u.astype(np.float32))
            np.testing.assert_array_equal(b.positions[first][t // 5], env.positions_m.astype(np.float32))
        env.step(clip_speed(u[None] + SIGMA_MPS * rng.standard_normal((1, *u.shape)), PARAMS.max_speed_mps)[0])
        clean.step(clean_expert(clean))
    assert np.abs(b.positions[first][1:] - b.positions[first][:1]).max() > 0  # the swarm moved
    assert np.abs(env.positions_m - clean.positions_m).max() > 0.5


def test_bytes_do_not_depend_on_workers_and_the_plan_records_sigma(dart, tmp_path):
    madp("datagen", "--n", 44, "--out", tmp_path / "w2", "--workers", 2, "--dart-sigma", SIGMA_MPS, *SMALL)
    assert tree_bytes(tmp_path / "w2") == tree_bytes(dart)
    m = Manifest.load(dart / "manifest.json")
    assert m.params["dart_sigma_mps"] == SIGMA_MPS and m.created_by.endswith(f"--dart-sigma {SIGMA_MPS!r}")
    cfg = DatagenConfig.from_dict(m.params)
    assert cfg.dart_sigma_mps == SIGMA_MPS and DatagenConfig.from_dict(cfg.to_dict()) == cfg
    plain = DatagenConfig(44, params=PARAMS)  # a noiseless plan keeps the plan.json of before the option
    assert "dart_sigma_mps" not in plain.to_dict() and "--dart-sigma" not in plain.command()


def test_dart_refusals(tmp_path):
    for args in (["--dart-sigma", 0.5, "--policy", shipped_checkpoint("lpac")], ["--dart-sigma", -1],
                 ["--dart-sigma", "nan"], ["--dart-sigma", "inf"]):
        assert_one_line(*cli("datagen", "--n", 20, "--out", tmp_path / "x", *args, *SMALL), "--dart-sigma")
    assert not (tmp_path / "x").exists()
