"""madp export: each graph against PyTorch on the same inputs (1e-5), a dynamic token axis, and the
command on the shipped policy (graphs, runtime.json with the sampler's constants and the sha256)."""

from __future__ import annotations

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch

from madp.io.checksum import sha256_file
from madp.export.onnx import GRAPHS, LEARNED_GRAPHS, graph_modules
from madp.policies import shipped_checkpoint
from tests.robot.robot_testutils import export_tiny


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny-export")
    return export_tiny(out), out


def _inputs(model, tokens: int, batch: int, gen: torch.Generator) -> dict[str, torch.Tensor]:
    cfg = model.config
    pos = torch.rand(batch, tokens, 2, generator=gen) * 600 + 200
    d2 = (pos[:, :, None] - pos[:, None]).square().sum(-1)
    return {"observation": torch.rand(batch, 4, 32, 32, generator=gen),
            "tokens": torch.randn(batch, tokens, cfg.token_dim, generator=gen), "positions_m": pos,
            "mask": (d2 < cfg.comm_radius_m ** 2) | torch.eye(tokens, dtype=torch.bool),
            "noisy_actions": torch.randn(batch, tokens, 2, generator=gen),
            "step": torch.randint(1, 1001, (batch,), generator=gen),
            "memory": torch.randn(batch, tokens, cfg.d_model, generator=gen)}


@pytest.mark.parametrize("tokens,batch", [(1, 1), (5, 4), (13, 2)])
def test_each_graph_matches_pytorch(tiny, tokens, batch):
    model, out = tiny
    x = _inputs(model, tokens, batch, torch.Generator().manual_seed(tokens))
    for role, (module, inputs, _) in graph_modules(model).items():
        with torch.no_grad():
            ref = module(*(x[n] for n in inputs)).numpy()
        sess = ort.InferenceSession(str(out / GRAPHS[role]), providers=["CPUExecutionProvider"])
        got = sess.run(None, {n: x[n].numpy() for n in inputs})[0]
        assert got.shape == ref.shape
        assert np.abs(got - ref).max() <= 1e-5, role


def test_a_model_that_predicts_the_sample_exports_the_noise_it_implies(tmp_path):
    """A distilled student (``prediction = "sample"``): its denoiser graph returns the noise derived
    from the predicted sample, as PyTorch's ``denoise`` does, so the runtime's samplers drive it."""
    from dataclasses import replace

    from madp.export.onnx import export_graphs
    from madp.models import MADP
    from tests.robot.robot_testutils import tiny_madp_config

    torch.manual_seed(1)
    model = MADP(replace(tiny_madp_config(), prediction="sample")).eval()
    export_graphs(model, tmp_path)
    x = _inputs(model, 5, 3, torch.Generator().manual_seed(2))
    module, inputs, _ = graph_modules(model)["denoiser"]
    with torch.no_grad():
        ref = module(*(x[n] for n in inputs)).numpy()
    sess = ort.InferenceSession(str(tmp_path / GRAPHS["denoiser"]), providers=["CPUExecutionProvider"])
    got = sess.run(None, {n: x[n].numpy() for n in inputs})[0]
    assert np.abs(got - ref).max() <= 1e-4 * max(1.0, float(np.abs(ref).max()))
    plain = MADP(tiny_madp_config()).eval()
    plain.load_state_dict(model.state_dict())
    with torch.no_grad():  # not the head's raw output: the noise it implies
        raw = graph_modules(plain)["denoiser"][0](*(x[n] for n in inputs)).numpy()
    assert np.abs(got - raw).max() > 1e-2


def test_export_command_on_the_shipped_policy(tmp_path):
    from typer.testing import CliRunner

    from madp.cli import app

    ship = shipped_checkpoint("madp")
    res = CliRunner().invoke(app, ["export", str(ship), "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    # the shipped file carries a critic: the default rule, critic, exports its graph too
    assert {p.name for p in tmp_path.iterdir()} == {*GRAPHS.values(), *LEARNED_GRAPHS["critic"].values(), "runtime.json"}
    spec = json.loads((tmp_path / "runtime.json").read_text())
    assert spec["source"]["sha256"] == sha256_file(ship)
    assert spec["sampler"]["name"] == "dpm++" and spec["sampler"]["steps"] == 3 == len(spec["sampler"]["coefficients"])
    assert spec["selection"] == {"frame": "d4", "rule": "critic", "candidates": 4, "grid_m": 4}
    assert spec["radii"]["comm_radius_m"] == 256.0 and len(spec["action_stats"]["std"]) == 2
    # the real policy's graphs against PyTorch too, on a neighbourhood of 7 tokens
    from madp.policies import load

    model = load(ship, "madp")[0]
    x = _inputs(model, 7, 4, torch.Generator().manual_seed(1))
    for role, (module, inputs, _) in graph_modules(model).items():
        with torch.no_grad():
            ref = module(*(x[n] for n in inputs)).numpy()
        got = ort.InferenceSession(str(tmp_path / GRAPHS[role]), providers=["CPUExecutionProvider"]).run(
            None, {n: x[n].numpy() for n in inputs})[0]
        assert np.abs(got - ref).max() <= 1e-5, role


def test_export_refuses_what_a_robot_cannot_run(tmp_path):
    from tests.test_cli import madp

    r = madp("export", str(shipped_checkpoint("madp")), "--out", str(tmp_path), "--select", "oracle")
    assert r.returncode == 2 and "oracle" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = madp("export", str(shipped_checkpoint("lpac")), "--out", str(tmp_path))
    assert r.returncode == 2 and "lpac" in r.stderr


def test_robot_runtime_bench_runs_the_evaluation_default():
    """``madp bench infer``'s robot rows: the runtime at the evaluation default's sampling, which
    its figures and printed line name (structure, not speed)."""
    from madp.export.bench import bench_robot_runtime, format_robot_runtime
    from madp.policies import SamplingSettings

    r = bench_robot_runtime(num_robots=6, repeats=1)
    d = SamplingSettings()
    assert (r["candidates"], r["num_steps"], r["select"], r["frame"]) == (d.candidates, d.sampling_steps, d.select, d.frame)
    assert r["onnxruntime_per_robot_s"] > 0 and r["torch_swarm_s"] > 0
    assert f"among K = {d.candidates}," in format_robot_runtime(r)[0]


def test_a_value_rule_exports_the_policy_files_map_prior(tmp_path):
    """``--select value``: the export holds the map prior's graph (against PyTorch, 1e-5, on windows of
    any side), runtime.json names it with its sha256, and so does ``value_joint``'s; ``oracle_joint`` (it
    reads the true map) and a file without a prior are refused in one line."""
    from madp.export.onnx import PRIOR_GRAPH, export_policy
    from madp.models.map_prior import MapPrior
    from madp.policies import SamplingSettings
    from madp.training.map_prior import add_prior
    from tests.test_cli import madp

    torch.manual_seed(0)
    net = MapPrior().eval()
    policy = tmp_path / "policy.safetensors"
    add_prior(shipped_checkpoint("madp"), policy, net, {})
    spec = export_policy(policy, tmp_path / "value", SamplingSettings.of(select="value"))
    assert spec["graphs"]["map_prior"] == PRIOR_GRAPH["map_prior"] and set(spec["graph_sha256"]) == {*GRAPHS, "map_prior"}
    sess = ort.InferenceSession(str(tmp_path / "value" / PRIOR_GRAPH["map_prior"]), providers=["CPUExecutionProvider"])
    for side in (16, 9):
        x = torch.rand(5, 3, side, side, generator=torch.Generator().manual_seed(side))
        with torch.no_grad():
            ref = net(x).numpy()
        assert np.abs(sess.run(None, {"windows": x.numpy()})[0] - ref).max() <= 1e-5
    plain = export_policy(shipped_checkpoint("madp"), tmp_path / "explore")
    assert "map_prior" not in plain["graphs"] and not (tmp_path / "explore" / PRIOR_GRAPH["map_prior"]).exists()
    joint = export_policy(policy, tmp_path / "joint", SamplingSettings.of(select="value_joint"))
    assert joint["selection"]["rule"] == "value_joint" and "map_prior" in joint["graphs"]
    r = madp("export", str(policy), "--out", str(tmp_path / "j"), "--select", "oracle_joint")
    assert r.returncode == 2 and "oracle_joint" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = madp("export", str(shipped_checkpoint("madp")), "--out", str(tmp_path / "v"), "--select", "value")
    assert r.returncode == 2 and "carries no map prior" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_robot_runtime_bench_runs_a_one_step_student_at_s_1_and_a_joint_rule_with_its_cost_round():
    """A policy file distilled into one sampler step (with a map prior: the kept expectile policy) is
    timed at S = 1, under ``value_joint`` with the sum of its neighbours' costs (structure, not speed)."""
    from pathlib import Path

    from madp.export.bench import bench_robot_runtime

    policy = Path(__file__).parents[2] / "docs/results/value-expectile-k8-2026-12-05/policy.safetensors"
    r = bench_robot_runtime(str(policy), num_robots=6, repeats=1, select="value_joint")
    assert (r["num_steps"], r["select"]) == (1, "value_joint") and r["onnxruntime_per_robot_s"] > 0


def test_robot_runtime_bench_runs_a_critic_rule_through_the_critics_graph():
    """A policy file carrying a critic (the kept one) is timed under ``critic_hood``: the critic's graph in
    each robot's choice, the PyTorch side with the same critic (structure, not speed)."""
    from pathlib import Path

    from madp.export.bench import bench_robot_runtime

    policy = Path(__file__).parents[2] / "docs/results/critic-2026-12-07/policy.safetensors"
    r = bench_robot_runtime(str(policy), num_robots=6, repeats=1, select="critic_hood")
    assert (r["candidates"], r["select"]) == (4, "critic_hood") and r["onnxruntime_per_robot_s"] > 0
    assert r["torch_per_robot_s"] > 0
