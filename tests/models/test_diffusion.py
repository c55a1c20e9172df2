import math

import numpy as np
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


# --- Expectations built without the code under test (issue 17) ------------------------------------

def textbook_abar(k_max=1000, beta_start=1e-4, beta_end=0.02):
    """``abar[k]`` for k = 0..K from Ho et al. (2020) in numpy: linear betas, abar_0 = 1."""
    betas = np.linspace(beta_start, beta_end, k_max, dtype=np.float64)
    return np.concatenate([[1.0], np.cumprod(1.0 - betas)]), np.concatenate([[0.0], betas])


@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("steps", [10, 50])
def test_ddim_oracle_trajectory_stays_on_the_forward_marginals(sched, gen, eta, steps):
    """With the exact noise of a fixed x0, every DDIM step (not just the last, which maps any x to x0)
    lands on ``sqrt(abar_prev) x0 + sqrt(1 - abar_prev) e`` with ``e`` tracked from the DDIM paper's
    eq. 12 (``e' = (sqrt(1 - abar_prev - sigma^2) e + sigma n) / sqrt(1 - abar_prev)``), the schedule
    and sigma computed here in numpy. Fails at the first step on a wrong coefficient, sign or sigma,
    and on a wrong timestep subsequence (k_i = round(i K / S))."""
    abar, _ = textbook_abar()
    seq = [round(i * 1000 / steps) for i in range(steps, -1, -1)]
    sched.set_timesteps(steps)
    assert sched.timesteps.tolist() == seq[:-1]
    x0 = torch.randn(3, 8, 2, generator=gen, dtype=torch.float64)
    e = torch.randn(3, 8, 2, generator=gen, dtype=torch.float64)
    x = math.sqrt(abar[1000]) * x0 + math.sqrt(1 - abar[1000]) * e
    for k, prev in zip(seq[:-1], seq[1:]):
        eps = (x - math.sqrt(abar[k]) * x0) / math.sqrt(1 - abar[k])  # the oracle
        n = torch.randn(x.shape, generator=gen, dtype=torch.float64)
        x = sched.step(eps, k, x, eta=eta, noise=n)
        sigma = eta * math.sqrt((1 - abar[prev]) / (1 - abar[k])) * math.sqrt(1 - abar[k] / abar[prev])
        if prev > 0:
            e = (math.sqrt(1 - abar[prev] - sigma**2) * e + sigma * n) / math.sqrt(1 - abar[prev])
        expect = math.sqrt(abar[prev]) * x0 + math.sqrt(1 - abar[prev]) * e
        assert torch.allclose(x, expect, rtol=0, atol=1e-9), (k, prev)
    assert torch.allclose(x, x0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("k", [1000, 501, 2, 1])
def test_eta_one_consecutive_step_is_ddpm_ancestral_sampling(sched, gen, k):
    """DDIM with eta = 1 from k to k - 1 is DDPM's Algorithm 2 (Ho et al. 2020):
    ``x_{k-1} = (x_k - beta_k / sqrt(1 - abar_k) eps) / sqrt(alpha_k) + sqrt(beta_tilde_k) z`` with
    ``beta_tilde_k = (1 - abar_{k-1}) / (1 - abar_k) beta_k``, written here from the paper, for an
    arbitrary (not oracle) eps. Fails on a wrong sigma, noise scale or mean coefficient."""
    abar, betas = textbook_abar()
    x = torch.randn(4, 6, 2, generator=gen, dtype=torch.float64)
    eps = torch.randn(4, 6, 2, generator=gen, dtype=torch.float64)
    z = torch.randn(4, 6, 2, generator=gen, dtype=torch.float64)
    beta_tilde = (1 - abar[k - 1]) / (1 - abar[k]) * betas[k]
    expect = (x - betas[k] / math.sqrt(1 - abar[k]) * eps) / math.sqrt(1 - betas[k]) + math.sqrt(beta_tilde) * z
    got = sched.step(eps, k, x, eta=1.0, prev_k=k - 1, noise=z)
    assert torch.allclose(got, expect, rtol=1e-10, atol=1e-10)


def test_eta_one_skip_step_samples_the_forward_posterior(sched, gen):
    """Over a skip k -> p (as in S < K sampling), eta = 1 samples q(x_p | x_k, x0_hat) of the forward
    process restricted to the subsequence: mean ``sqrt(abar_p) b / (1 - abar_k) x0_hat +
    sqrt(a) (1 - abar_p) / (1 - abar_k) x_k`` and variance ``(1 - abar_p) / (1 - abar_k) b`` with
    ``a = abar_k / abar_p``, ``b = 1 - a`` (Bishop-style Gaussian conditioning, written here)."""
    abar, _ = textbook_abar()
    x = torch.randn(4, 6, 2, generator=gen, dtype=torch.float64)
    eps = torch.randn(4, 6, 2, generator=gen, dtype=torch.float64)
    z = torch.randn(4, 6, 2, generator=gen, dtype=torch.float64)
    for k, p in [(1000, 900), (300, 280), (40, 20)]:
        a = abar[k] / abar[p]
        b = 1 - a
        x0_hat = (x - math.sqrt(1 - abar[k]) * eps) / math.sqrt(abar[k])
        mean = (math.sqrt(abar[p]) * b / (1 - abar[k])) * x0_hat + (math.sqrt(a) * (1 - abar[p]) / (1 - abar[k])) * x
        var = (1 - abar[p]) / (1 - abar[k]) * b
        got = sched.step(eps, k, x, eta=1.0, prev_k=p, noise=z)
        assert torch.allclose(got, mean + math.sqrt(var) * z, rtol=1e-10, atol=1e-10), (k, p)


def test_schedule_and_forward_process_match_diffusers(gen):
    """Same betas as diffusers' linear schedule (its t = our k - 1) and the same q(x_k | x_0): fails on
    an off-by-one between k and t, on abar_0 != 1 or a wrong beta range."""
    from diffusers import DDPMScheduler

    ref = DDPMScheduler(num_train_timesteps=1000, beta_start=1e-4, beta_end=0.02, beta_schedule="linear")
    ours = DDPMSchedule(1000, 1e-4, 0.02)
    assert torch.allclose(ours.alphas_cumprod[1:].float(), ref.alphas_cumprod, rtol=1e-5, atol=1e-7)
    assert torch.allclose(ours.betas[1:].float(), ref.betas, rtol=1e-6)
    x0 = torch.randn(5, 7, 2, generator=gen)
    noise = torch.randn(5, 7, 2, generator=gen)
    k = torch.tensor([1, 2, 250, 999, 1000])
    got = ours.add_noise(x0, noise, k)
    assert torch.allclose(got, ref.add_noise(x0, noise, k - 1), rtol=1e-5, atol=1e-5)
