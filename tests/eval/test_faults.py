"""The faults suite: the uniform suite's environments over eight networks, its plot, and the network's
links in the MCAP rollouts."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq

from madp.eval.runner import EvalConfig, run_suite
from madp.eval.suites import FAULTS, suite_envs
from madp.sim.network import LINK_DELIVERED, LINK_LOST
from tests.eval.test_record import _read


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


def test_faults_suite_writes_its_plot_and_records_the_links(tmp_path):
    """DCVT on one environment of the ideal, 50 %-loss and failure groups for a few steps: results, the
    cost-against-loss plot, and a recording of the lossy group with delivered and lost links."""
    cfg = EvalConfig(suite="faults", out=str(tmp_path), num_envs=1, steps=6, workers=1, controllers=("dcvt",),
                     record=1, groups=("loss_50", "ideal", "fail_25"))
    run_suite(cfg, "faults", progress=False)
    suite_dir = tmp_path / "faults"
    results = pq.read_table(suite_dir / "results.parquet").to_pandas()
    assert sorted(results.group) == ["fail_25", "ideal", "loss_50"]
    assert (suite_dir / "faults.png").stat().st_size > 0
    md = (suite_dir / "summary.md").read_text()
    assert "paired by environment" in md and "| loss_50 | " in md and "| fail_25 | " in md
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
