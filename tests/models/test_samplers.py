"""The samplers against diffusers' schedulers (same betas, same timesteps) and an exact ODE solution."""

import math

import pytest
import torch

from madp.errors import SettingError
from madp.models import DDPMSchedule, make_sampler
from madp.models.samplers import check_sampler, sample_loop

import diffusers  # noqa: F401  (a dev dependency: the reference must be there, not skipped)


_ABAR = DDPMSchedule(1000).alphas_cumprod


def fake_eps(x: torch.Tensor, k: int) -> torch.Tensor:
    """A smooth, step-dependent stand-in for the noise model (k in 1..K): the exact noise of data
    N(0.5, 1) plus a nonlinear term, so that samples stay O(1) as real actions do."""
    a = float(_ABAR[k])
    return math.sqrt(1 - a) * (x - math.sqrt(a) * 0.5) + 0.05 * torch.tanh(x) * math.sin(k / 97.0)


def run_ours(name: str, steps: int, x: torch.Tensor, eta: float = 0.0, noise=None) -> torch.Tensor:
    sampler = make_sampler(name, DDPMSchedule(1000), steps, eta)
    return sample_loop(sampler, lambda x_k, i, k: fake_eps(x_k, k), x, (lambda i: noise[i]) if noise is not None else None)


@pytest.mark.parametrize("steps", [1, 2, 3, 5, 10, 20, 50])
def test_dpm_solver_matches_diffusers(steps):
    """Fails on a wrong multistep coefficient (e.g. r or the 0.5 of the midpoint rule), on a second
    order first or last step, or on another timestep spacing."""
    from diffusers import DPMSolverMultistepScheduler

    sched = DPMSolverMultistepScheduler(num_train_timesteps=1000, beta_start=1e-4, beta_end=0.02,
                                        beta_schedule="linear", solver_order=2, prediction_type="epsilon",
                                        algorithm_type="dpmsolver++", solver_type="midpoint",
                                        final_sigmas_type="zero", lower_order_final=True)
    ours = make_sampler("dpm++", DDPMSchedule(1000), steps)
    sched.set_timesteps(timesteps=[k - 1 for k in ours.timesteps])  # diffusers' t = our k - 1
    x0 = torch.randn(64, 2, generator=torch.Generator().manual_seed(steps))
    x = x0.clone()
    for t in sched.timesteps:
        x = sched.step(fake_eps(x, int(t) + 1), t, x).prev_sample
    ref = x
    got = run_ours("dpm++", steps, x0.double()).float()
    assert torch.allclose(got, ref, rtol=1e-5, atol=1e-5)  # diffusers keeps its schedule in float32


@pytest.mark.parametrize("steps", [10, 20, 50])
@pytest.mark.parametrize("eta", [0.0, 1.0])
def test_ddim_matches_diffusers(steps, eta):
    """Our k_i = round(i K / S) walk to abar = 1 is diffusers' "trailing" spacing with
    set_alpha_to_one (for S dividing K); fails on a wrong DDIM coefficient or noise scale."""
    from diffusers import DDIMScheduler

    sched = DDIMScheduler(num_train_timesteps=1000, beta_start=1e-4, beta_end=0.02, beta_schedule="linear",
                          clip_sample=False, set_alpha_to_one=True, steps_offset=0, timestep_spacing="trailing",
                          prediction_type="epsilon")
    sched.set_timesteps(steps)
    ours = make_sampler("ddim", DDPMSchedule(1000), steps, eta)
    assert [int(t) + 1 for t in sched.timesteps] == ours.timesteps
    g = torch.Generator().manual_seed(steps)
    x0 = torch.randn(64, 2, generator=g)
    noise = torch.randn(steps, 64, 2, generator=g)
    x = x0.clone()
    for i, t in enumerate(sched.timesteps):
        x = sched.step(fake_eps(x, int(t) + 1), t, x, eta=eta, variance_noise=noise[i]).prev_sample
    got = run_ours("ddim", steps, x0.double(), eta, noise.double()).float()
    assert torch.allclose(got, x, rtol=1e-5, atol=1e-5)


def test_dpm_solver_is_closer_to_the_exact_ode_solution_than_ddim():
    """Gaussian data x0 ~ N(mu, s^2) has an exact noise model, and the probability-flow ODE maps
    U_K to mu + s (U_K - sqrt(abar_K) mu) / sqrt(abar_K s^2 + 1 - abar_K). A second-order solver
    must beat first-order DDIM at the same S (fails if the solver degrades to first order)."""
    sched = DDPMSchedule(1000)
    mu, s = 0.5, 1.0  # normalised actions have unit variance
    ab = sched.alphas_cumprod

    def eps(x, k):
        a = float(ab[k])
        return math.sqrt(1 - a) * (x - math.sqrt(a) * mu) / (a * s * s + 1 - a)

    x_k = torch.randn(256, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    a_k = float(ab[1000])
    exact = mu + s * (x_k - math.sqrt(a_k) * mu) / math.sqrt(a_k * s * s + 1 - a_k)
    for steps in (10, 20):
        err = {}
        for name in ("ddim", "dpm++"):
            out = sample_loop(make_sampler(name, sched, steps), lambda x, i, k: eps(x, k), x_k.clone())
            err[name] = float((out - exact).abs().max())
        assert err["dpm++"] < err["ddim"] / 3, (steps, err)


def test_sampler_settings_are_checked():
    """Each refusal describes the value by the setting's name (the command line names the flag)."""
    with pytest.raises(SettingError, match="^sampler: expected one of") as e:
        check_sampler("euler", 10, 0.0)
    assert e.value.setting == "sampler"
    with pytest.raises(SettingError, match="^sampling_steps: expected >= 1, got 0"):
        check_sampler("ddim", 0, 0.0)
    with pytest.raises(SettingError, match=r"^eta 0.5: DPM-Solver\+\+\(2M\) is deterministic"):
        check_sampler("dpm++", 10, 0.5)
    with pytest.raises(SettingError, match="^eta: expected a value in"):
        check_sampler("ddim", 10, 1.5)
