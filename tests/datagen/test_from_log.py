"""Logs back into data (``madp dataset import``): a swarm run's rosbag2 log replays on its scenario and
becomes expert-labelled samples that ``madp train`` reads beside another dataset; a one-process
rollout's ros2 recording imports the same way; a log that does not replay, a truncated log and a
foreign directory are one-line errors."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from madp.data_schema import Manifest, read_shard
from madp.datagen.from_log import import_logs, read_log
from madp.errors import MadpError
from madp.export.swarm import exported
from madp.policies import SamplingSettings, shipped_checkpoint
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario, SimParams
from madp.swarm import run_swarm
from tests.conftest import tiny_dataset
from tests.test_reliability_errors import assert_one_line, cli

#: The tiny training set's world (256 m, 4 robots), so the imported samples train beside it.
PARAMS = SimParams(world_size=256, num_robots=4, num_features=4)
STEPS = 12


@pytest.fixture(scope="module")
def swarm_log(tmp_path_factory):
    """A lockstep swarm run of 4 robot processes, 12 steps: its scenario and its swarm.mcap."""
    root = tmp_path_factory.mktemp("swarm-log")
    sc = Scenario.random(5, PARAMS)
    sc.save(root / "sc.json")
    run_swarm(root / "sc.json", exported(shipped_checkpoint("madp"), SamplingSettings()), STEPS, root / "run",
              progress=False)
    return sc, root / "run" / "swarm.mcap"


def test_a_swarm_log_becomes_samples_that_train_reads(swarm_log, tmp_path_factory, tmp_path):
    sc, log = swarm_log
    run = read_log(log)
    assert run.commands_mps.shape == (STEPS, 4, 2) and run.positions_m.shape == (STEPS + 1, 4, 2)
    m = import_logs([log], tmp_path / "imported", record_every=5)
    assert m.counts() == {"train": 4, "val": 0, "test": 0}  # steps 0, 5, 10 and the last, 11
    batch = read_shard(tmp_path / "imported" / m.splits["train"].shards[0].file)
    env, expert = CoverageEnv(sc), ClairvoyantCVT()  # the labels are the expert's at the logged states
    for t in range(STEPS):
        if t == 5:
            np.testing.assert_allclose(batch.actions[1], expert(env), rtol=0, atol=1e-5)
            np.testing.assert_allclose(batch.positions[1], run.positions_m[5], rtol=0, atol=1e-4)
        env.step(run.commands_mps[t])
    assert Manifest.load(tmp_path / "imported" / "manifest.json").action_stats is not None
    base = tiny_dataset(tmp_path_factory, "base")
    code, err = cli("train", "--model", "madp", "--data", base, "--data", tmp_path / "imported", "--out", tmp_path / "t",
                    "--epochs", "1", "--batch-size", "4", "--val-samples", "4", "--max-steps-per-epoch", "3",
                    "--workers", "0")
    assert code == 0, err
    assert (tmp_path / "t" / "checkpoints" / "latest" / "policy.safetensors").is_file()


def test_a_rollout_recording_imports_too(tmp_path):
    sc = Scenario.random(9, PARAMS)
    sc.save(tmp_path / "sc.json")
    code, err = cli("rollout", "--scenario", tmp_path / "sc.json", "--controller", "dcvt", "--steps", "7",
                    "--out", tmp_path / "r.json", "--record", tmp_path / "r.mcap", "--record-format", "ros2")
    assert code == 0, err
    code, err = cli("dataset", "import", tmp_path / "r.mcap", "--out", tmp_path / "d", "--record-every", "3")
    assert code == 0, err
    assert Manifest.load(tmp_path / "d" / "manifest.json").counts()["train"] == 3  # steps 0, 3, 6


def test_bad_logs_and_directories_are_one_line_errors(swarm_log, tmp_path):
    sc, log = swarm_log
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: log.stat().st_size // 2])
    assert_one_line(*cli("dataset", "import", cut, "--out", tmp_path / "a"), "cut.mcap")
    assert_one_line(*cli("dataset", "import", tmp_path / "none.mcap", "--out", tmp_path / "a"), "none.mcap")
    # the same log with another scenario's world does not replay: named, with the robot and the step
    other = tmp_path / "other.mcap"
    shutil.copy(log, other)
    run = read_log(other)
    moved = run.__class__(run.path, Scenario.random(6, PARAMS), run.dt_s, run.commands_mps, run.positions_m)
    from madp.datagen.from_log import log_episode

    with pytest.raises(MadpError, match="does not replay: robot"):
        log_episode(moved, 0)
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    assert_one_line(*cli("dataset", "import", log, "--out", user), "notes.txt")
    code, err = cli("dataset", "import", log, "--out", tmp_path / "d")
    assert code == 0, err
    assert_one_line(*cli("dataset", "import", log, "--out", tmp_path / "d"), "--overwrite")
    code, err = cli("dataset", "import", log, "--out", tmp_path / "d", "--overwrite", "--format", "parquet")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "d" / "train").iterdir()) == ["shard-00000.parquet"]
