"""The DDPM schedule and its DDIM step (``madp.models.diffusion``): constants, the forward process,
every DDIM step against oracles written here from the papers and against diffusers, and the edge
cases the mutation campaign found unchecked (``predict_x0`` against ``add_noise``,
``clip_x0`` on both signs, the per-device cache, the noise source; each such test names the
mutations it guards)."""

from __future__ import annotations

import math
from fractions import Fraction

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
    assert seq[:2].tolist() == [1000, 980] and seq[-2:].tolist() == [20, 0]
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
        out = sched.ddim_step(eps, k, prev, xk, eta=0.0)
        assert torch.allclose(out, sched.add_noise(x0, eps, prev), atol=1e-12)
    # per-sample k tensors work too
    k = torch.tensor([1000, 500, 20])
    prev = torch.tensor([980, 480, 0])
    out = sched.ddim_step(eps, k, prev, sched.add_noise(x0, eps, k))
    assert torch.allclose(out, sched.add_noise(x0, eps, prev), atol=1e-12)


@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ddim_with_oracle_recovers_actions(sched, gen, eta, dtype):
    x0 = torch.randn(2, 32, 2, generator=gen).to(dtype)
    seq = sched.ddim_timesteps(50).tolist()
    x = torch.randn(x0.shape, generator=gen).to(dtype)
    for k, prev in zip(seq[:-1], seq[1:]):
        x = sched.ddim_step(oracle_eps(sched, x, x0, k), k, prev, x, eta=eta, generator=gen)
    atol = 1e-10 if dtype == torch.float64 else 2e-4
    assert torch.allclose(x, x0, atol=atol)


def test_eta_one_is_stochastic_and_eta_zero_deterministic(sched, gen):
    x = torch.randn(2, 4, 2, generator=gen)
    eps = torch.randn(2, 4, 2, generator=gen)
    a = sched.ddim_step(eps, 500, 480, x, eta=1.0, generator=torch.Generator().manual_seed(0))
    b = sched.ddim_step(eps, 500, 480, x, eta=1.0, generator=torch.Generator().manual_seed(1))
    assert not torch.allclose(a, b)
    c = sched.ddim_step(eps, 500, 480, x, eta=0.0, generator=torch.Generator().manual_seed(0))
    d = sched.ddim_step(eps, 500, 480, x, eta=0.0, generator=torch.Generator().manual_seed(1))
    assert torch.equal(c, d)
    # explicit noise: sigma * noise is added to the deterministic part (sigma of Algorithm 1, eta = 1)
    n = torch.randn(2, 4, 2, generator=gen)
    e = sched.ddim_step(eps, 500, 480, x, eta=1.0, noise=n)
    ab, abp = sched.alphas_cumprod[500], sched.alphas_cumprod[480]
    sigma = ((1 - abp) / (1 - ab)).sqrt() * (1 - ab / abp).sqrt()
    c2 = (1 - abp - sigma.double() ** 2).sqrt()
    expect = (abp / ab).sqrt() * x.double() + (c2 - (abp / ab).sqrt() * (1 - ab).sqrt()) * eps.double()
    assert torch.allclose(e.double(), expect + sigma.double() * n.double(), atol=1e-6)


def test_ddpm_sigma_at_eta_one_is_posterior_std(sched):
    """With consecutive steps and eta = 1, sigma^2 is DDPM's posterior variance beta_tilde (at x = eps = 0
    the step is sigma times the noise)."""
    x = torch.zeros(1, dtype=torch.float64)
    for k in [2, 100, 1000]:
        s = sched.ddim_step(x, k, k - 1, x, eta=1.0, noise=torch.ones(1, dtype=torch.float64))
        ab, abp = sched.alphas_cumprod[k], sched.alphas_cumprod[k - 1]
        beta_tilde = (1 - abp) / (1 - ab) * sched.betas[k]
        assert torch.isclose(s * s, beta_tilde)


def test_clip_x0(sched):
    x = torch.full((1, 2), 5.0)
    eps = torch.zeros(1, 2)
    out = sched.ddim_step(eps, 20, 0, x, clip_x0=1.0)
    assert torch.allclose(out, torch.ones(1, 2))


def test_sample_timesteps_range(sched, gen):
    k = sched.sample_timesteps(10000, generator=gen)
    assert k.min() >= 1 and k.max() <= 1000 and k.dtype == torch.long


# --- Expectations built without the code under test --------------------------------------------

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
    assert sched.ddim_timesteps(steps).tolist() == seq
    x0 = torch.randn(3, 8, 2, generator=gen, dtype=torch.float64)
    e = torch.randn(3, 8, 2, generator=gen, dtype=torch.float64)
    x = math.sqrt(abar[1000]) * x0 + math.sqrt(1 - abar[1000]) * e
    for k, prev in zip(seq[:-1], seq[1:]):
        eps = (x - math.sqrt(abar[k]) * x0) / math.sqrt(1 - abar[k])  # the oracle
        n = torch.randn(x.shape, generator=gen, dtype=torch.float64)
        x = sched.ddim_step(eps, k, prev, x, eta=eta, noise=n)
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
    got = sched.ddim_step(eps, k, k - 1, x, eta=1.0, noise=z)
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
        got = sched.ddim_step(eps, k, p, x, eta=1.0, noise=z)
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


# --- Edge cases the mutation campaign found ----------------------------------------------------

@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_predict_x0_inverts_add_noise(gen, dtype):
    """Guards the formula of ``predict_x0`` (sign, ``1 - abar``, division by ``sqrt(abar)``) for an int
    k and for a per-sample ``[B]`` k."""
    sched = DDPMSchedule(1000)
    x0 = torch.randn(4, 6, 2, generator=gen, dtype=dtype)
    eps = torch.randn(4, 6, 2, generator=gen, dtype=dtype)
    tol = 1e-4 if dtype == torch.float32 else 1e-10
    k = torch.tensor([1, 37, 400, 900])
    assert torch.allclose(sched.predict_x0(sched.add_noise(x0, eps, k), eps, k), x0, atol=tol)
    assert torch.allclose(sched.predict_x0(sched.add_noise(x0, eps, 250), eps, 250), x0, atol=tol)


def _diffusers_ddim(clip: float | None):
    from diffusers import DDIMScheduler

    # "trailing" spacing with set_alpha_to_one walks t = k - 1 for our k = K, K - K/S, ..., K/S, then abar = 1
    return DDIMScheduler(num_train_timesteps=1000, beta_start=1e-4, beta_end=0.02, beta_schedule="linear",
                         timestep_spacing="trailing", set_alpha_to_one=True, clip_sample=clip is not None,
                         clip_sample_range=clip or 1.0)


@pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("clip", [None, 1.5])
def test_ddim_step_matches_diffusers(gen, eta, clip):
    """Every step of a 10-step DDIM walk equals diffusers' ``DDIMScheduler.step`` given the same eps and
    noise (its t = our k - 1). Guards ``ddim_step``: the clipped x0 (``clamp(-c, c)``, both bounds), eps
    re-derived from it (diffusers' ``use_clipped_model_output``), sigma, and the noise term."""
    ours, ref = DDPMSchedule(1000, 1e-4, 0.02), _diffusers_ddim(clip)
    seq = ours.ddim_timesteps(10).tolist()
    ref.set_timesteps(10)
    assert [k - 1 for k in seq[:-1]] == ref.timesteps.tolist()
    x = 3.0 * torch.randn(8, 2, generator=gen)  # wide enough that clipping bites on both sides
    for k, prev, t in zip(seq[:-1], seq[1:], ref.timesteps.tolist()):
        eps = torch.randn(8, 2, generator=gen)
        z = torch.randn(8, 2, generator=gen)
        want = ref.step(eps, t, x, eta=eta, use_clipped_model_output=True, variance_noise=z).prev_sample
        got = ours.ddim_step(eps, k, prev, x, eta=eta, noise=z, clip_x0=clip)
        assert torch.allclose(got, want, rtol=1e-4, atol=1e-4), (k, eta, clip)
        x = want


def test_clip_x0_clamps_both_sides():
    """x0_hat = x / sqrt(abar) at eps = 0; landing on k = 0 returns the clamped x0 exactly."""
    sched = DDPMSchedule(1000)
    x = torch.tensor([[5.0, -5.0, 0.25]], dtype=torch.float64)
    out = sched.ddim_step(torch.zeros_like(x), 20, 0, x, clip_x0=1.0)
    ab = sched.alphas_cumprod[20]
    assert torch.allclose(out, torch.tensor([[1.0, -1.0, 0.25 / ab.sqrt().item()]], dtype=torch.float64))


def test_eta_noise_comes_from_the_generator():
    """Guards ``generator=`` / ``dtype=`` of the fresh noise and ``if eta > 0`` (eta = 0 must not draw:
    a sampler's random stream would shift)."""
    sched = DDPMSchedule(1000)
    x = torch.randn(3, 2, dtype=torch.float64)
    eps = torch.randn(3, 2, dtype=torch.float64)
    g = torch.Generator().manual_seed(7)
    got = sched.ddim_step(eps, 600, 400, x, eta=1.0, generator=g)
    z = torch.randn(3, 2, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    assert torch.equal(got, sched.ddim_step(eps, 600, 400, x, eta=1.0, noise=z))
    g = torch.Generator().manual_seed(7)
    sched.ddim_step(eps, 600, 400, x, eta=0.0, generator=g)
    assert torch.equal(g.get_state(), torch.Generator().manual_seed(7).get_state())


def test_sample_timesteps_covers_one_to_k_and_follows_the_generator():
    """Guards the bounds of ``randint`` (k = 1 and k = K are both drawn) and ``generator=``."""
    sched = DDPMSchedule(5)
    k = sched.sample_timesteps(2000, generator=torch.Generator().manual_seed(0))
    assert set(k.tolist()) == {1, 2, 3, 4, 5}
    again = sched.sample_timesteps(2000, generator=torch.Generator().manual_seed(0))
    assert torch.equal(k, again)


def test_meta_device_follows_the_input():
    """Tensors land on the device asked for (the ``meta`` device stands in for CUDA): guards
    ``device=`` in ``sample_timesteps``, the per-device cache key and ``.to(device)`` in ``_on``."""
    sched = DDPMSchedule(100)
    assert sched.sample_timesteps(3, device="meta").device.type == "meta"
    like = torch.zeros(2, 1, device="meta")
    assert sched._at(torch.tensor([3, 5]), like).device.type == "meta"
    cpu = sched._at(torch.tensor([3, 5]), torch.zeros(2, 1))
    assert cpu.device.type == "cpu" and torch.equal(cpu.view(-1), sched.alphas_cumprod[[3, 5]])


def test_at_accepts_any_integer_tensor():
    """Guards ``dtype=torch.long`` in ``_at``: a uint8 k is an index, not a mask."""
    sched = DDPMSchedule(100)
    got = sched._at(torch.tensor([3, 5], dtype=torch.uint8), torch.zeros(2, 1, dtype=torch.float64))
    assert torch.equal(got.view(-1), sched.alphas_cumprod[[3, 5]])


def test_defaults():
    """The paper's K = 1000 by default."""
    sched = DDPMSchedule()
    assert (sched.num_train_steps, sched.beta_start, sched.beta_end) == (1000, 1e-4, 0.02)


def test_errors_say_what_was_expected():
    """Guards the messages and conditions of every refusal; K = 1 and k_0 = 0 are valid."""
    with pytest.raises(ValueError, match=r"^num_train_steps must be >= 1$"):
        DDPMSchedule(0)
    assert DDPMSchedule(1).ddim_timesteps(1).tolist() == [1, 0]
    sched = DDPMSchedule(1000)
    with pytest.raises(ValueError, match=r"^num_steps must be in \[1, 1000\], got 0$"):
        sched.ddim_timesteps(0)


@pytest.mark.parametrize("k_train, steps", [(1000, 7), (1000, 1000), (5000, 2947), (10000, 2687)])
def test_ddim_timesteps_are_exactly_rounded_for_any_k(k_train, steps):
    """ddim_timesteps__mutmut_12 / _16 (the index ``arange`` in int64: ``i * K / S`` is then a float32
    quotient, whose rounding error exceeds the distance to the next .5 once K·S > 2^23; K is any
    num_train_steps >= 1). ``k_i = round(i K / S)`` exactly (half to even, as ``torch.round``):
    e.g. K = 5000, S = 2947, i = 2441 gives 4141.4998..., so 4141, not 4142."""
    want = [round(Fraction(i * k_train, steps)) for i in range(steps, -1, -1)]
    got = DDPMSchedule(k_train).ddim_timesteps(steps)
    assert got.dtype == torch.long and got.tolist() == want
