"""DDPMSchedule against diffusers' DDIMScheduler step by step, and its edge cases (issue 17).

These close the gaps the mutation campaign found in ``models/diffusion.py``: ``predict_x0`` was never
checked against ``add_noise``, ``clip_x0`` only on positive values, the per-device cache and the
subsequence table never re-set, and the sampler's noise source never pinned. Each test names the
mutations it guards.
"""

from __future__ import annotations

from fractions import Fraction

import pytest
import torch

from madp.models import DDPMSchedule


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
    noise (its t = our k - 1). Guards ``step``: the clipped x0 (``clamp(-c, c)``, both bounds), eps
    re-derived from it (diffusers' ``use_clipped_model_output``), sigma, and the noise term."""
    ours, ref = DDPMSchedule(1000, 1e-4, 0.02), _diffusers_ddim(clip)
    ours.set_timesteps(10)
    ref.set_timesteps(10)
    assert (ours.timesteps - 1).tolist() == ref.timesteps.tolist()
    x = 3.0 * torch.randn(8, 2, generator=gen)  # wide enough that clipping bites on both sides
    for k, t in zip(ours.timesteps.tolist(), ref.timesteps.tolist()):
        eps = torch.randn(8, 2, generator=gen)
        z = torch.randn(8, 2, generator=gen)
        want = ref.step(eps, t, x, eta=eta, use_clipped_model_output=True, variance_noise=z).prev_sample
        got = ours.step(eps, k, x, eta=eta, noise=z, clip_x0=clip)
        assert torch.allclose(got, want, rtol=1e-4, atol=1e-4), (k, eta, clip)
        x = want


def test_clip_x0_clamps_both_sides():
    """x0_hat = x / sqrt(abar) at eps = 0; landing on k = 0 returns the clamped x0 exactly."""
    sched = DDPMSchedule(1000)
    x = torch.tensor([[5.0, -5.0, 0.25]], dtype=torch.float64)
    out = sched.step(torch.zeros_like(x), 20, x, prev_k=0, clip_x0=1.0)
    ab = sched.alphas_cumprod[20]
    assert torch.allclose(out, torch.tensor([[1.0, -1.0, 0.25 / ab.sqrt().item()]], dtype=torch.float64))


def test_eta_noise_comes_from_the_generator():
    """Guards ``generator=`` / ``dtype=`` of the fresh noise and ``if eta > 0`` (eta = 0 must not draw:
    a sampler's random stream would shift)."""
    sched = DDPMSchedule(1000)
    sched.set_timesteps(5)
    x = torch.randn(3, 2, dtype=torch.float64)
    eps = torch.randn(3, 2, dtype=torch.float64)
    g = torch.Generator().manual_seed(7)
    got = sched.step(eps, 600, x, eta=1.0, generator=g)
    z = torch.randn(3, 2, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    assert torch.equal(got, sched.step(eps, 600, x, eta=1.0, noise=z))
    g = torch.Generator().manual_seed(7)
    sched.step(eps, 600, x, eta=0.0, generator=g)
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


def test_set_timesteps_resets_the_successor_table():
    """Guards the cache purge in ``set_timesteps`` and the cache key (a stale table after a second
    ``set_timesteps`` or a table shared between names)."""
    sched = DDPMSchedule(1000)
    sched.set_timesteps(10)
    x = torch.zeros(1, 2)
    sched.add_noise(x, x, torch.tensor([5]))  # fills the cache with abar on this device
    assert sched.previous_timestep(torch.tensor([1000, 100])).tolist() == [900, 0]
    sched.set_timesteps(50)
    assert sched.previous_timestep(torch.tensor([1000, 20])).tolist() == [980, 0]
    assert sched.previous_timestep(1000) == 980


def test_defaults():
    """The paper's K = 1000 by default, and no subsequence before ``set_timesteps``."""
    sched = DDPMSchedule()
    assert (sched.num_train_steps, sched.beta_start, sched.beta_end) == (1000, 1e-4, 0.02)
    assert sched.timesteps is None


def test_errors_say_what_was_expected():
    """Guards the messages and conditions of every refusal; K = 1 and k_0 = 0 are valid."""
    with pytest.raises(ValueError, match=r"^num_train_steps must be >= 1$"):
        DDPMSchedule(0)
    assert DDPMSchedule(1).ddim_timesteps(1).tolist() == [1, 0]
    sched = DDPMSchedule(1000)
    with pytest.raises(ValueError, match=r"^num_steps must be in \[1, 1000\], got 0$"):
        sched.ddim_timesteps(0)
    with pytest.raises(RuntimeError, match=r"^call set_timesteps\(num_steps\) first, or pass prev_k$"):
        sched.previous_timestep(1000)
    sched.set_timesteps(50)
    with pytest.raises(ValueError, match=r"^timestep 5 not in the DDIM subsequence$"):
        sched.previous_timestep(5)
    with pytest.raises(ValueError, match=r"^timestep not in the DDIM subsequence$"):
        sched.previous_timestep(torch.tensor([1000, 5]))


@pytest.mark.parametrize("k_train, steps", [(1000, 7), (1000, 1000), (5000, 2947), (10000, 2687)])
def test_ddim_timesteps_are_exactly_rounded_for_any_k(k_train, steps):
    """ddim_timesteps__mutmut_12 / _16 (the index ``arange`` in int64: ``i * K / S`` is then a float32
    quotient, whose rounding error exceeds the distance to the next .5 once K·S > 2^23; K is any
    num_train_steps >= 1). ``k_i = round(i K / S)`` exactly (half to even, as ``torch.round``):
    e.g. K = 5000, S = 2947, i = 2441 gives 4141.4998..., so 4141, not 4142."""
    want = [round(Fraction(i * k_train, steps)) for i in range(steps, -1, -1)]
    got = DDPMSchedule(k_train).ddim_timesteps(steps)
    assert got.dtype == torch.long and got.tolist() == want
