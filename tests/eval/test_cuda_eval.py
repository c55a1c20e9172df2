"""Learned controllers and ``madp eval`` / ``madp bench infer`` on a CUDA GPU (marked ``cuda``:
skipped without one). The sampling noise comes from CPU generators on every device, so the same seed
gives the GPU and the CPU the same noise and their actions differ only by float rounding."""

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from madp.controllers import make_controller
from madp.eval.runner import EvalConfig, run_suite
from madp.models.bench import bench_infer
from madp.policies import SamplingSettings, noise_generator
from madp.sim import CoverageEnv, Scenario

pytestmark = pytest.mark.cuda


@pytest.mark.parametrize("name,sampler,steps,eta", [("madp", "dpm++", 3, 0.0), ("madp", "ddim", 10, 0.5),
                                                    ("madp_central", "dpm++", 3, 0.0), ("lpac", "dpm++", 3, 0.0)])
def test_controller_on_the_gpu_acts_as_on_the_cpu(checkpoints, name, sampler, steps, eta):
    path = str(checkpoints / ("lpac.safetensors" if name == "lpac" else "madp.safetensors"))
    # one sample per robot: the model's sampling is what the device changes (a rule's choice among
    # close candidates could flip on float rounding)
    kw = dict(seed=5, sampling=SamplingSettings(sampler, steps, eta, select="none", candidates=1))
    gpu, cpu = make_controller(name, path, device="cuda", **kw), make_controller(name, path, device="cpu", **kw)
    assert next(gpu.model.parameters()).is_cuda and not next(cpu.model.parameters()).is_cuda
    env = CoverageEnv(Scenario.random(3))
    for _ in range(3):  # the generator advances alike on both
        u_gpu, u_cpu = gpu(env), cpu(env)
        assert np.abs(u_gpu - u_cpu).max() < 5e-2, np.abs(u_gpu - u_cpu).max()  # m/s, u_max = 5
        env.step(u_cpu)
    if name != "lpac":  # batched, one CPU generator per environment
        envs = [CoverageEnv(Scenario.random(s)) for s in (1, 2)]
        a = gpu.act_batch(envs, [noise_generator(s) for s in (1, 2)])
        b = cpu.act_batch(envs, [noise_generator(s) for s in (1, 2)])
        assert np.abs(a - b).max() < 5e-2


def test_eval_suite_on_the_gpu(checkpoints, tmp_path):
    """``madp eval --device cuda`` with worker processes: each worker's models live on the GPU and the
    final costs of a short rollout match the CPU run's."""
    kw = dict(suite="uniform", num_envs=2, steps=4, controllers=("lpac", "madp"), lpac=str(checkpoints / "lpac.safetensors"),
              madp=str(checkpoints / "madp.safetensors"), workers=2)
    costs = {}
    for device in ("cuda", "cpu"):
        cfg = EvalConfig(out=str(tmp_path / device), device=device, **kw)
        run_suite(cfg, "uniform", progress=False)
        assert json.loads((tmp_path / device / "uniform" / "config.json").read_text())["device"] == device
        t = pq.read_table(tmp_path / device / "uniform" / "results.parquet").to_pydict()
        costs[device] = np.array(t["final_cost"])
    assert np.abs(costs["cuda"] - costs["cpu"]).max() < 1e-2


def test_latency_is_measured_on_the_gpu():
    r = bench_infer("paper", "decentralized", num_steps=3, sampler="dpm++", repeats=2, device="cuda")
    assert r["device"] == "cuda" and 0 < r["latency_s"] < 5
    assert torch.cuda.is_initialized()
