"""Samplers of the reverse diffusion: DDIM (paper Algorithm 1) and DPM-Solver++(2M).

Both walk the same subsequence of the training schedule, ``K = k_S > ... > k_1 > k_0 = 0``
(:meth:`DDPMSchedule.ddim_timesteps`: ``k_i = round(i K / S)``, diffusers' "trailing" spacing),
evaluate the noise model at ``k_S ... k_1`` and land exactly on clean data (``abar_0 = 1``).
Typical use, as diffusers' schedulers::

    sampler = make_sampler("dpm++", schedule, num_steps=10)
    for i, k in enumerate(sampler.timesteps):      # k_S, ..., k_1 (python ints)
        eps = model(x, k)
        x = sampler.step(eps, i, x)                # -> x at k_{S-1-i}; finally U_0

A sampler is a small stateful object (DPM-Solver++ keeps the previous data prediction): make a
new one per sampling call. Every coefficient is a python float computed in float64 once, so a step
is a handful of tensor ops whatever the dtype of ``x``.

* **DDIM** (``eta`` in [0, 1]): :meth:`DDPMSchedule.ddim_step`; ``eta = 0`` is the deterministic ODE
  solver of first order.
* **DPM-Solver++(2M)** (Lu et al. 2022, arXiv:2211.01095; ``eta`` must be 0): multistep
  second-order solver of the same ODE in data prediction, with half-log-SNR
  ``lambda = log(sqrt(abar) / sqrt(1 - abar))``. First step first order, the last step (to
  ``sigma = 0``) first order as diffusers does with ``final_sigmas_type="zero"``; in between the
  "midpoint" update::

      x0_i = (x - sigma_s eps) / alpha_s,   h = lambda_t - lambda_s,   r = h_prev / h
      x_t = (sigma_t / sigma_s) x - alpha_t (e^-h - 1) (x0_i + (x0_i - x0_{i-1}) / (2 r))

  Tested against diffusers' ``DPMSolverMultistepScheduler`` (and DDIM against ``DDIMScheduler``)
  on the same betas and timesteps to 1e-5.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from madp.errors import SettingError

from .diffusion import DDPMSchedule

__all__ = ["SAMPLERS", "DEFAULT_SAMPLER", "DEFAULT_SAMPLING_STEPS", "DDIMSampler", "DPMSolverMultistepSampler",
           "make_sampler", "check_sampler"]

#: Sampler names accepted by ``--sampler``.
SAMPLERS = ("ddim", "dpm++")
#: The evaluation default: the (sampler, S) measured by ``madp bench infer`` (docs/reports/2026-12-01-sampler-steps.md).
DEFAULT_SAMPLER = "dpm++"
DEFAULT_SAMPLING_STEPS = 3


def check_sampler(name: str, num_steps: int, eta: float) -> None:
    """A one-line :class:`madp.errors.SettingError` for an unknown sampler, S < 1, η outside [0, 1] or
    η > 0 with DPM-Solver++."""
    if name not in SAMPLERS:
        raise SettingError("sampler", f"expected one of {list(SAMPLERS)}, got {name!r}")
    if int(num_steps) < 1:
        raise SettingError("sampling_steps", f"expected >= 1, got {num_steps}")
    if not 0.0 <= float(eta) <= 1.0:
        raise SettingError("eta", f"expected a value in [0, 1], got {eta}")
    if name == "dpm++" and eta > 0:
        raise SettingError("eta", message=f"eta {eta}: DPM-Solver++(2M) is deterministic; η > 0 needs the ddim sampler")


class DDIMSampler:
    """DDIM over ``S`` steps (``eta = 0``: deterministic; ``eta = 1``: DDPM-like ancestral)."""

    name = "ddim"

    def __init__(self, schedule: DDPMSchedule, num_steps: int, eta: float = 0.0, clip_x0: float | None = None):
        check_sampler(self.name, num_steps, eta)
        self.schedule, self.eta, self.clip_x0 = schedule, float(eta), clip_x0
        self._seq = schedule.ddim_timesteps(num_steps).tolist()
        #: ``[k_S, ..., k_1]``: where the model is evaluated.
        self.timesteps: list[int] = self._seq[:-1]
        self.stochastic = self.eta > 0

    def step(self, eps_hat: Tensor, i: int, x: Tensor, noise: Tensor | None = None) -> Tensor:
        """``x`` at ``timesteps[i]`` -> ``x`` at the next lower step; ``noise`` is the fresh draw when η > 0."""
        return self.schedule.ddim_step(eps_hat, self._seq[i], self._seq[i + 1], x, eta=self.eta, noise=noise,
                                       clip_x0=self.clip_x0)


class DPMSolverMultistepSampler:
    """DPM-Solver++(2M), midpoint form (diffusers' defaults ``solver_order=2``,
    ``algorithm_type="dpmsolver++"``, ``solver_type="midpoint"``, ``final_sigmas_type="zero"``)."""

    name = "dpm++"
    stochastic = False

    def __init__(self, schedule: DDPMSchedule, num_steps: int, eta: float = 0.0, clip_x0: float | None = None):
        check_sampler(self.name, num_steps, eta)
        self.clip_x0 = clip_x0
        seq = schedule.ddim_timesteps(num_steps).tolist()
        self.timesteps: list[int] = seq[:-1]
        abar = [float(schedule.alphas_cumprod[k]) for k in seq]
        alpha = [math.sqrt(a) for a in abar]
        sigma = [math.sqrt(max(1.0 - a, 0.0)) for a in abar]
        lam = [math.log(a) - math.log(s) if s > 0 else math.inf for a, s in zip(alpha, sigma)]
        s = len(self.timesteps)
        #: Per step i: ``x_next = ca x + cb x0_i + cc x0_{i-1}`` and ``x0_i = (x - sig eps) / alp``.
        self._coef: list[tuple[float, float, float, float, float]] = []
        for i in range(s):
            alp, sig = alpha[i], sigma[i]
            alpha_t, sigma_t = alpha[i + 1], sigma[i + 1]
            if sigma_t == 0.0:  # last step, to clean data: first order, x_0 = x0_i
                self._coef.append((alp, sig, 0.0, 1.0, 0.0))
                continue
            h = lam[i + 1] - lam[i]
            phi = alpha_t * math.expm1(-h)  # alpha_t (e^-h - 1), negative
            if i == 0:  # first order (DDIM) until a previous data prediction exists
                self._coef.append((alp, sig, sigma_t / sig, -phi, 0.0))
                continue
            r = (lam[i] - lam[i - 1]) / h
            self._coef.append((alp, sig, sigma_t / sig, -phi * (1.0 + 0.5 / r), phi * 0.5 / r))
        self._prev_x0: Tensor | None = None

    def step(self, eps_hat: Tensor, i: int, x: Tensor, noise: Tensor | None = None) -> Tensor:
        """``x`` at ``timesteps[i]`` -> ``x`` at the next lower step (call with i = 0, 1, ... in order)."""
        alp, sig, ca, cb, cc = self._coef[i]
        x0 = (x - sig * eps_hat) / alp
        if self.clip_x0 is not None:
            x0 = x0.clamp(-self.clip_x0, self.clip_x0)
        out = cb * x0 if ca == 0.0 else ca * x + cb * x0
        if cc != 0.0:
            out = out + cc * self._prev_x0
        self._prev_x0 = x0
        return out


def make_sampler(name: str, schedule: DDPMSchedule, num_steps: int, eta: float = 0.0,
                 clip_x0: float | None = None) -> DDIMSampler | DPMSolverMultistepSampler:
    """A fresh sampler ``"ddim"`` or ``"dpm++"`` over ``num_steps`` steps of ``schedule``."""
    if name not in SAMPLERS:
        check_sampler(name, num_steps, eta)  # the one-line error; each class checks the rest
    cls = DDIMSampler if name == "ddim" else DPMSolverMultistepSampler
    return cls(schedule, num_steps, eta, clip_x0)


def sample_loop(sampler, denoise, x: Tensor, step_noise=None) -> Tensor:
    """Run ``sampler`` from ``x = U_{k_S}``: ``denoise(x, i, k) -> eps_hat``; ``step_noise(i)`` gives the
    fresh noise of step i (only called by a stochastic sampler)."""
    for i, k in enumerate(sampler.timesteps):
        eps = denoise(x, i, k)
        noise = step_noise(i) if (sampler.stochastic and step_noise is not None) else None
        x = sampler.step(eps, i, x, noise)
    return x

