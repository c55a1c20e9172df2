"""MADP's sampling precision (``SamplingSettings.precision``, ``madp eval --precision``): bf16 keeps the
actions close to fp32's (and is not fp32), leaves the caller's model as it was, is refused in one line
for a bad value or with the ONNX runtime, and is a setting of the suite (config.json, results.parquet,
refused on resume with another)."""

import json
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from madp.errors import SettingError
from madp.eval.runner import EvalConfig, run_suite
from madp.policies import MADPPolicy, SamplingSettings, load, noise_generator, shipped_checkpoint
from madp.sim import CoverageEnv, Scenario, SimParams
from tests.conftest import one_torch_thread
from tests.test_reliability_errors import assert_one_line, cli


@pytest.fixture(scope="module")
def shipped():
    with one_torch_thread():
        model, _ = load(shipped_checkpoint("madp"), "madp")
        yield model


def test_bf16_samples_within_bfloat16_rounding_of_fp32(shipped):
    """The shipped policy on two random 32-robot swarms, K = 4 copies, the same noise: the bf16 copy's
    normalised actions differ from fp32's by about 1% of their size on average (measured: mean 0.004
    and 99th percentile 0.016 against a mean |action| of 0.47), inside the tolerance; a lost RoPE
    (0.28, 1.0) fails it, and so does the whole model in bfloat16 (0.016: 3.5%). They are float32 and
    not fp32's."""
    g = torch.Generator().manual_seed(3)
    obs = torch.rand(2, 32, 4, 32, 32, generator=g)
    pos = torch.rand(2, 32, 2, generator=g) * 1024
    noise = torch.randn(8, 32, 2, generator=g)
    low = shipped.with_bf16_linears()
    with one_torch_thread(), torch.no_grad():
        ref = shipped.sample_decentralized(obs, pos, 3, sampler="dpm++", noise=noise, copies=4)
        got = low.sample_decentralized(obs, pos, 3, sampler="dpm++", noise=noise, copies=4)
    diff = (got - ref).abs()
    assert got.dtype == torch.float32
    assert 0 < float(diff.mean()) < 0.025 * float(ref.abs().mean()), (float(diff.mean()), float(ref.abs().mean()))
    assert float(diff.quantile(0.99)) < 0.08


def test_only_a_copys_transformer_linears_are_bfloat16(shipped):
    low = shipped.with_bf16_linears()
    linears = [m for m in (*low.encoder.modules(), *low.decoder.modules()) if isinstance(m, torch.nn.Linear)]
    assert linears and all(m.weight.dtype == m.bias.dtype == torch.bfloat16 for m in linears)
    rest = [p for n, p in low.named_parameters() if not n.startswith(("encoder.", "decoder.")) or "ln" in n]
    assert rest and all(p.dtype == torch.float32 for p in rest)
    assert low.action_std.dtype == torch.float32 and torch.equal(low.action_std, shipped.action_std)
    assert all(p.dtype == torch.float32 for p in shipped.parameters())  # the caller's model is untouched


def test_a_bf16_policy_acts_close_to_the_fp32_one(shipped):
    """Through MADPPolicy (m/s, one sample per robot, the same seed): close, not equal."""
    params = SimParams(num_robots=12, num_features=32)
    envs = [CoverageEnv(Scenario.random(5, params)) for _ in range(2)]
    actions = []
    for precision in ("fp32", "bf16"):
        sampling = SamplingSettings(select="none", candidates=1, frame="world", precision=precision)
        with one_torch_thread():
            actions.append(MADPPolicy(shipped, sampling=sampling).act_batch(envs, [noise_generator(7)] * 2))
    diff = np.abs(actions[1] - actions[0])
    assert 0 < diff.mean() < 0.05 * np.abs(actions[0]).mean()


def test_a_bad_precision_is_refused_in_one_line(tmp_path):
    with pytest.raises(SettingError) as e:
        SamplingSettings(precision="fp16")
    assert e.value.setting == "precision" and "\n" not in str(e.value)
    line = assert_one_line(*cli("eval", "--precision", "fp16", "--out", tmp_path / "o"))
    assert line == "madp: error: --precision: expected one of fp32, bf16, got 'fp16'"


def test_the_onnx_runtime_refuses_bf16():
    with pytest.raises(SettingError) as e:
        EvalConfig(suite="uniform", runtime="onnx", sampling=SamplingSettings(precision="bf16"))
    assert e.value.setting == "precision" and "--runtime torch" in str(e.value)


def test_precision_is_a_setting_of_the_suite(tmp_path):
    cfg = EvalConfig(suite="uniform", out=str(tmp_path), num_envs=1, steps=1, controllers=("dcvt",),
                     sampling=SamplingSettings(precision="bf16"), workers=1)
    run_suite(cfg, "uniform", progress=False)
    d = tmp_path / "uniform"
    assert json.loads((d / "config.json").read_text())["precision"] == "bf16"
    assert pq.read_table(d / "results.parquet").column("precision").to_pylist() == [""]  # dcvt does not sample
    with pytest.raises(ValueError, match=r"other settings \(precision\)"):
        run_suite(replace(cfg, sampling=replace(cfg.sampling, precision="fp32")), "uniform", progress=False)
