"""MADP and LPAC-K3 inference on a CUDA GPU against the CPU (marked ``cuda``: skipped without one).

Same weights, same inputs, same noise: the GPU's float32 result equals the CPU's within a bf16-sized
tolerance (cuDNN's convolutions may use TF32). Inputs are real swarms of the simulator, so the
attention neighbourhoods have the sizes a rollout meets."""

import numpy as np
import pytest
import torch

from madp.models import MADP, lpac_config, madp_config
from madp.models.lpac import LPAC
from madp.sim import CoverageEnv, Scenario

pytestmark = pytest.mark.cuda
TOL = 2e-2  # normalised actions are O(1); bf16 resolves 2^-8 = 4e-3 relative


def swarms(count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``obs [B, 32, 4, 32, 32]``, ``pos_m [B, 32, 2]`` of B random scenarios (uniform launch)."""
    envs = [CoverageEnv(Scenario.random(seed)) for seed in range(count)]
    obs = torch.from_numpy(np.stack([e.observations() for e in envs]))
    pos = torch.from_numpy(np.stack([e.positions_m for e in envs]).astype(np.float32))
    return obs, pos


def madp_model(preset: str) -> MADP:
    torch.manual_seed(1)
    return MADP(madp_config(preset)).eval()


def close(a: torch.Tensor, b: torch.Tensor) -> None:
    assert a.shape == b.shape
    diff = float((a.cpu() - b.cpu()).abs().max())
    assert diff < TOL * (1 + float(b.abs().max())), f"max |gpu - cpu| = {diff}"


@pytest.mark.parametrize("preset", ["cpu", "paper"])
@pytest.mark.parametrize("sampler,steps,eta", [("dpm++", 3, 0.0), ("ddim", 10, 0.5)])
def test_decentralized_sampling_on_the_gpu_equals_the_cpu(preset, sampler, steps, eta):
    obs, pos = swarms(2)
    g = torch.Generator().manual_seed(7)
    noise = torch.randn(2, 32, 2, generator=g)
    step_noise = torch.randn(steps, 2, 32, 2, generator=g)
    model = madp_model(preset)
    with torch.no_grad():
        want = model.sample_decentralized(obs, pos, steps, eta, noise=noise, step_noise=step_noise, sampler=sampler)
        model.cuda()
        got = model.sample_decentralized(obs.cuda(), pos.cuda(), steps, eta, noise=noise.cuda(),
                                         step_noise=step_noise.cuda(), sampler=sampler)
    assert got.is_cuda
    close(got, want)
    with torch.no_grad():  # the centralized-masked pass too
        central = model.sample(obs.cuda(), pos.cuda(), steps, eta, noise=noise.cuda(), step_noise=step_noise.cuda(),
                               sampler=sampler)
        model.cpu()
        close(central, model.sample(obs, pos, steps, eta, noise=noise, step_noise=step_noise, sampler=sampler))


def test_lpac_forward_on_the_gpu_equals_the_cpu():
    obs, pos = swarms(2)
    torch.manual_seed(1)
    model = LPAC(lpac_config("cpu")).eval()
    with torch.no_grad():
        want = model(obs, pos)
        got = model.cuda()(obs.cuda(), pos.cuda())
    assert got.is_cuda
    close(got, want)


def test_training_loss_under_autocast_matches_float32():
    """One MADP loss on the GPU under bf16 autocast against the same loss in float32 on the CPU (same
    diffusion steps and noise), and its gradients are finite float32 tensors."""
    obs, pos = swarms(2)
    g = torch.Generator().manual_seed(3)
    act = torch.randn(2, 32, 2, generator=g)
    k = torch.randint(1, 1001, (2,), generator=g)
    noise = torch.randn(2, 32, 2, generator=g)
    model = madp_model("paper").train()
    want = model.loss(obs, pos, act, k=k, noise=noise)
    model.cuda()
    with torch.autocast("cuda", dtype=torch.bfloat16):
        got = model.loss(obs.cuda(), pos.cuda(), act.cuda(), k=k.cuda(), noise=noise.cuda())
    got.backward()
    assert got.dtype == torch.float32 and torch.isfinite(got)
    assert float(got.detach()) == pytest.approx(float(want.detach()), rel=5e-2)
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    assert grads and all(x.dtype == torch.float32 and bool(torch.isfinite(x).all()) for x in grads)
