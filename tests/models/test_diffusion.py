import pytest
import torch

from madp.models import DDPMSchedule


@pytest.fixture
def sched():
    return DDPMSchedule(1000, 1e-4, 0.02)


def oracle_eps(sched, x_k, x0, k):
    """The exact noise that takes x0 to x_k (what a perfect denoiser returns)."""
    ab = sched.alphas_cumprod[k].to(x_k.dtype)
    return (x_k - ab.sqrt() * x0) / (1 - ab).sqrt()


def test_schedule_constants(sched):
    assert sched.alphas_cumprod.dtype == torch.float64
    assert sched.alphas_cumprod[0] == 1.0
    assert torch.isclose(sched.alphas[1], torch.tensor(0.9999, dtype=torch.float64))
    assert torch.isclose(sched.alphas[1000], torch.tensor(0.98, dtype=torch.float64))
    assert (sched.alphas[2:] < sched.alphas[1:-1]).all()
    assert torch.allclose(sched.alphas_cumprod[1:], torch.cumprod(sched.alphas[1:], 0))
    assert sched.alphas_cumprod[1000] < 1e-4  # essentially pure noise at k = K


def test_ddim_subsequence(sched):
    seq = sched.ddim_timesteps(50)
    assert seq[0] == 1000 and seq[-1] == 0 and len(seq) == 51
    assert (seq[:-1] > seq[1:]).all()
    ts = sched.set_timesteps(50)
    assert ts.tolist() == seq[:-1].tolist()
    assert sched.previous_timestep(1000) == 980 and sched.previous_timestep(20) == 0
    assert sched.ddim_timesteps(1000).tolist() == list(range(1000, -1, -1))


def test_add_noise_matches_closed_form(sched, gen):
    x0 = torch.randn(4, 5, 2, generator=gen, dtype=torch.float64)
    eps = torch.randn(4, 5, 2, generator=gen, dtype=torch.float64)
    k = torch.tensor([1, 10, 500, 1000])
    xk = sched.add_noise(x0, eps, k)
    for b in range(4):
        ab = sched.alphas_cumprod[k[b]]
        assert torch.allclose(xk[b], ab.sqrt() * x0[b] + (1 - ab).sqrt() * eps[b])
    assert torch.equal(sched.add_noise(x0, eps, 0), x0)


def test_step_with_true_noise_lands_on_forward_marginal(sched, gen):
    """eta = 0 with the true eps maps add_noise(x0, eps, k) exactly to add_noise(x0, eps, prev)."""
    x0 = torch.randn(3, 7, 2, generator=gen, dtype=torch.float64)
    eps = torch.randn(3, 7, 2, generator=gen, dtype=torch.float64)
    for k, prev in [(1000, 980), (500, 480), (20, 0), (7, 3)]:
        xk = sched.add_noise(x0, eps, k)
        out = sched.step(eps, k, xk, eta=0.0, prev_k=prev)
        assert torch.allclose(out, sched.add_noise(x0, eps, prev), atol=1e-12)
    # per-sample k tensors work too
    k = torch.tensor([1000, 500, 20])
    prev = torch.tensor([980, 480, 0])
    out = sched.step(eps, k, sched.add_noise(x0, eps, k), prev_k=prev)
    assert torch.allclose(out, sched.add_noise(x0, eps, prev), atol=1e-12)


@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ddim_with_oracle_recovers_actions(sched, gen, eta, dtype):
    x0 = torch.randn(2, 32, 2, generator=gen).to(dtype)
    sched.set_timesteps(50)
    x = torch.randn(x0.shape, generator=gen).to(dtype)
    for k in sched.timesteps.tolist():
        x = sched.step(oracle_eps(sched, x, x0, k), k, x, eta=eta, generator=gen)
    atol = 1e-10 if dtype == torch.float64 else 2e-4
    assert torch.allclose(x, x0, atol=atol)


def test_eta_one_is_stochastic_and_eta_zero_deterministic(sched, gen):
    x = torch.randn(2, 4, 2, generator=gen)
    eps = torch.randn(2, 4, 2, generator=gen)
    a = sched.step(eps, 500, x, eta=1.0, prev_k=480, generator=torch.Generator().manual_seed(0))
    b = sched.step(eps, 500, x, eta=1.0, prev_k=480, generator=torch.Generator().manual_seed(1))
    assert not torch.allclose(a, b)
    c = sched.step(eps, 500, x, eta=0.0, prev_k=480, generator=torch.Generator().manual_seed(0))
    d = sched.step(eps, 500, x, eta=0.0, prev_k=480, generator=torch.Generator().manual_seed(1))
    assert torch.equal(c, d)
    # explicit noise: sigma * noise is added to the deterministic part
    n = torch.randn(2, 4, 2, generator=gen)
    e = sched.step(eps, 500, x, eta=1.0, prev_k=480, noise=n)
    sigma = sched.ddim_sigma(500, 480, 1.0, x).float()
    ab, abp = sched.alphas_cumprod[500], sched.alphas_cumprod[480]
    c2 = (1 - abp - sigma.double() ** 2).sqrt()
    expect = (abp / ab).sqrt() * x.double() + (c2 - (abp / ab).sqrt() * (1 - ab).sqrt()) * eps.double()
    assert torch.allclose(e.double(), expect + sigma.double() * n.double(), atol=1e-6)


def test_ddpm_sigma_at_eta_one_is_posterior_std(sched):
    """With consecutive steps and eta = 1, sigma^2 is DDPM's posterior variance beta_tilde."""
    x = torch.zeros(1, dtype=torch.float64)
    for k in [2, 100, 1000]:
        s = sched.ddim_sigma(k, k - 1, 1.0, x)
        ab, abp = sched.alphas_cumprod[k], sched.alphas_cumprod[k - 1]
        beta_tilde = (1 - abp) / (1 - ab) * sched.betas[k]
        assert torch.isclose(s * s, beta_tilde)


def test_clip_x0(sched):
    x = torch.full((1, 2), 5.0)
    eps = torch.zeros(1, 2)
    out = sched.step(eps, 20, x, prev_k=0, clip_x0=1.0)
    assert torch.allclose(out, torch.ones(1, 2))


def test_sample_timesteps_range(sched, gen):
    k = sched.sample_timesteps(10000, generator=gen)
    assert k.min() >= 1 and k.max() <= 1000 and k.dtype == torch.long
