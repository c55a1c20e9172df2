"""The faults suite: the uniform suite's environments over its networks, its plot and tables (paired
differences, the failure against its survivors, bytes on the air), and the network's links in the MCAP
rollouts."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq

import pytest

from madp.errors import SettingError
from madp.eval.faults import fault_axes, faults_figure
from madp.eval.runner import EvalConfig, run_suite
from madp.eval.suites import FAULTS, MAX_NUM_ENVS, suite_envs
from madp.sim.network import LINK_DELIVERED, LINK_LOST
from tests.recordings.test_record import _read


def test_faults_groups_run_the_uniform_environments_over_their_networks():
    faults, uniform = suite_envs("faults", 3), suite_envs("uniform", 3)
    assert list(dict.fromkeys(e.group for e in faults)) == list(FAULTS)
    for group in FAULTS:
        envs = [e for e in faults if e.group == group]
        assert [e.seed for e in envs] == [e.seed for e in uniform]
        assert all(e.network == FAULTS[group] for e in envs)
        a, b = envs[0].scenario(), uniform[0].scenario()
        assert np.array_equal(a.features, b.features) and np.array_equal(a.robots_m, b.robots_m)
    assert FAULTS["ideal"].ideal and FAULTS["loss_30"].loss == 0.3 and FAULTS["delay_1s"].delay_steps == 5
    assert {"no_comm", "burst_30", "distance", "bandwidth", "survivors_25"} <= set(FAULTS)
    assert FAULTS["burst_30"].loss == FAULTS["loss_30"].loss and FAULTS["burst_30"].burst_len > 1
    assert FAULTS["survivors_25"].fail_fraction == FAULTS["fail_25"].fail_fraction and FAULTS["survivors_25"].fail_step == 0


def test_no_comm_delivers_nothing():
    from madp.sim import CoverageEnv, DecentralizedCVT

    spec = [e for e in suite_envs("faults", 1) if e.group == "no_comm"][0]
    env = CoverageEnv(spec.scenario(), network=spec.network)
    for _ in range(3):
        assert not env.neighbour_view()[0].any()
        env.step(DecentralizedCVT()(env))


def test_every_group_has_a_place_in_the_plot():
    axes = fault_axes(0.2)
    placed = [g for k in ("loss", "delay", "bursts", "other") for g, _ in axes[k]]
    assert set(placed) == set(FAULTS)
    assert ("no_comm", 100.0) in axes["loss"] and ("burst_30", 30.0) in axes["bursts"]
    assert "burst_30" not in dict(axes["loss"]) and {"distance", "bandwidth", "survivors_25"} <= dict(axes["other"]).keys()
    group = np.repeat(list(FAULTS), 2)
    fig = faults_figure(np.linspace(0.3, 0.9, len(group)), group, np.array(["dcvt"] * len(group)), ["dcvt"],
                        {"dcvt": "C0"}, "faults", 0.2)
    assert len(fig.axes) == 3


def test_absurd_numbers_of_environments_are_refused_before_anything_is_built():
    with pytest.raises(SettingError, match=str(MAX_NUM_ENVS)):
        suite_envs("faults", 10**11)
    with pytest.raises(SettingError, match="num_envs"):
        EvalConfig(suite="faults", num_envs=10**11)


def test_faults_suite_writes_its_plot_and_records_the_links(tmp_path):
    """DCVT on one environment of some groups for a few steps: results with the bytes on the air, the
    plot, the paired tables, and a recording of the ideal group with its links."""
    groups = ("loss_50", "ideal", "fail_25", "survivors_25", "no_comm", "bandwidth")
    cfg = EvalConfig(suite="faults", out=str(tmp_path), num_envs=1, steps=6, workers=1, controllers=("dcvt",),
                     record=1, groups=groups)
    run_suite(cfg, "faults", progress=False)
    suite_dir = tmp_path / "faults"
    results = pq.read_table(suite_dir / "results.parquet").to_pandas()
    assert sorted(results.group) == sorted(groups)
    assert (results.bytes_per_robot_step[results.group == "ideal"] == 35).all()  # DCVT: one beacon a step
    assert (results.bytes_per_robot_step[results.group == "survivors_25"] == 35).all()  # per running robot
    assert (suite_dir / "faults.png").stat().st_size > 0
    md = (suite_dir / "summary.md").read_text()
    assert "paired by environment" in md and "| loss_50 | " in md and "| fail_25 | " in md
    assert "against `survivors_25`, paired" in md and "Bytes each robot put on the air" in md
    assert "| no_comm | 35 |" in md  # a lost message was still put on the air
    _, meta, msgs = _read(suite_dir / "rollouts" / "ideal-000-dcvt.mcap")
    assert any(k.startswith("network.") for k in next(iter(meta.values())))
    links = [d for topic, _, _, d in msgs if topic == "/network/links"]
    robots = [d for topic, _, _, d in msgs if topic == "/robots"]
    assert len(links) == len(robots) >= 2 and {e.id for e in links[-1].entities} == {"links delivered", "links lost", "links kept"}


def test_links_hook_records_delivered_and_lost_links():
    from madp.sim import CoverageEnv, DecentralizedCVT
    from madp.sim.rollout import Links, act_alone, run

    spec = [e for e in suite_envs("faults", 1) if e.group == "loss_50"][0]
    env = CoverageEnv(spec.scenario(), network=spec.network)
    hook = Links(3)
    run([env], act_alone(DecentralizedCVT()), [hook], 3)
    assert (hook.links == LINK_DELIVERED).any() and (hook.links == LINK_LOST).any()
