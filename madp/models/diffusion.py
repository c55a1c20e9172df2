"""DDPM noise schedule and DDIM sampler step (paper §II and Algorithm 1).

Indexing follows the paper: diffusion steps ``k = 1 .. K``, ``alpha_k = 1 - beta_k`` with ``beta``
linear from ``beta_start`` to ``beta_end``, ``abar_k = prod_{j<=k} alpha_j`` and ``abar_0 = 1`` (clean
data). Training draws ``k ~ U{1, ..., K}``; DDIM sampling walks a subsequence
``K = k_S > ... > k_1 > k_0 = 0`` (evenly spaced, rounded, so it starts at the pure-noise end and
lands exactly on clean data).

The schedule is a plain object (not an ``nn.Module``): its constants are kept in float64 on the CPU,
cached per device on first use, and cast to the dtype of the tensor they scale. It is fully
determined by ``(K, beta_start, beta_end)``, which live in the model config.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["DDPMSchedule"]


class DDPMSchedule:
    """Linear-beta DDPM schedule with DDIM stepping: :meth:`ddim_timesteps` is the subsequence a sampler
    walks, :meth:`ddim_step` one step of it. The samplers (:mod:`.samplers`) drive both."""

    def __init__(self, num_train_steps: int = 1000, beta_start: float = 1e-4, beta_end: float = 0.02):
        if num_train_steps < 1:
            raise ValueError("num_train_steps must be >= 1")
        self.num_train_steps = int(num_train_steps)
        self.beta_start = float(beta_start)
        self.beta_end = float(beta_end)
        k = self.num_train_steps
        betas = torch.linspace(self.beta_start, self.beta_end, k, dtype=torch.float64)
        one = torch.ones(1, dtype=torch.float64)
        #: ``betas[k]``, ``alphas[k]`` for k = 0..K (index 0 is a placeholder: beta_0 = 0).
        self.betas = torch.cat([torch.zeros(1, dtype=torch.float64), betas])
        self.alphas = 1.0 - self.betas
        #: ``alphas_cumprod[k] = abar_k`` for k = 0..K, ``abar_0 = 1``.
        self.alphas_cumprod = torch.cat([one, torch.cumprod(1.0 - betas, 0)])
        self._cache: dict[tuple[str, str], Tensor] = {}

    # ----------------------------------------------------------------------------------- helpers
    def _on(self, name: str, device: torch.device) -> Tensor:
        key = (name, str(device))
        if key not in self._cache:
            t = getattr(self, name)
            if device.type == "mps" and t.is_floating_point():
                t = t.float()
            self._cache[key] = t.to(device)
        return self._cache[key]

    def _at(self, k: int | Tensor, like: Tensor) -> Tensor:
        """``abar_k`` (float64 where supported) broadcastable against ``like [B, ...]``: k is an int
        or a tensor ``[]`` / ``[B]``."""
        table = self._on("alphas_cumprod", like.device)
        if isinstance(k, Tensor):
            v = table[k.to(device=like.device, dtype=torch.long)]
            if v.dim() == 1:
                v = v.view(-1, *([1] * (like.dim() - 1)))
            return v
        return table[int(k)]

    @staticmethod
    def _cast(v: Tensor, like: Tensor) -> Tensor:
        return v.to(like.dtype)

    # ----------------------------------------------------------------------------------- training
    def sample_timesteps(self, batch: int, device: torch.device | str = "cpu",
                         generator: torch.Generator | None = None) -> Tensor:
        """``k ~ U{1, ..., K}``: ``[batch]`` long."""
        return torch.randint(1, self.num_train_steps + 1, (batch,), device=device, generator=generator)

    def add_noise(self, x0: Tensor, noise: Tensor, k: int | Tensor) -> Tensor:
        """Forward process ``q(x_k | x_0)``: ``x_k = sqrt(abar_k) x0 + sqrt(1 - abar_k) noise``.
        ``x0, noise [B, ...]``, ``k`` int or ``[B]``."""
        ab = self._at(k, x0)
        return self._cast(ab.sqrt(), x0) * x0 + self._cast((1 - ab).sqrt(), x0) * noise

    def predict_x0(self, x_k: Tensor, eps: Tensor, k: int | Tensor) -> Tensor:
        """``x0_hat = (x_k - sqrt(1 - abar_k) eps) / sqrt(abar_k)``."""
        ab = self._at(k, x_k)
        return (x_k - self._cast((1 - ab).sqrt(), x_k) * eps) / self._cast(ab.sqrt(), x_k)

    def predict_eps(self, x_k: Tensor, x0: Tensor, k: int | Tensor) -> Tensor:
        """The inverse of :meth:`predict_x0`: ``eps = (x_k - sqrt(abar_k) x0) / sqrt(1 - abar_k)`` (k >= 1)."""
        ab = self._at(k, x_k)
        return (x_k - self._cast(ab.sqrt(), x_k) * x0) / self._cast((1 - ab).sqrt(), x_k)

    # ----------------------------------------------------------------------------------- sampling
    def ddim_timesteps(self, num_steps: int) -> Tensor:
        """Subsequence ``[k_S, ..., k_1, k_0]`` (descending, long, length S + 1), ``k_i = round(i K / S)``,
        so ``k_S = K`` and ``k_0 = 0``."""
        s = int(num_steps)
        if not 1 <= s <= self.num_train_steps:
            raise ValueError(f"num_steps must be in [1, {self.num_train_steps}], got {num_steps}")
        i = torch.arange(s, -1, -1, dtype=torch.float64)
        return (i * self.num_train_steps / s).round().long()

    def ddim_step(self, eps_hat: Tensor, k: int | Tensor, prev_k: int | Tensor, x_k: Tensor, eta: float = 0.0,
                  generator: torch.Generator | None = None, noise: Tensor | None = None,
                  clip_x0: float | None = None) -> Tensor:
        """One DDIM step ``x_{k} -> x_{prev_k}`` (Algorithm 1 of the paper)::

            sigma = eta sqrt((1 - abar_prev)/(1 - abar_k)) sqrt(1 - abar_k / abar_prev)
            c0 = sqrt(abar_prev / abar_k),  c1 = sqrt(1 - abar_k),  c2 = sqrt(1 - abar_prev - sigma^2)
            x_prev = c0 x_k + (c2 - c0 c1) eps_hat + sigma noise

        ``eta = 0`` is deterministic DDIM, ``eta = 1`` DDPM-like ancestral sampling.

        Args:
            eps_hat: predicted noise, same shape as ``x_k``.
            k: current step (int, or ``[B]`` long tensor).
            prev_k: target step (the next of :meth:`ddim_timesteps`).
            x_k: current sample ``[B, ...]``.
            eta: noise scale in [0, 1].
            generator / noise: source of the fresh noise when ``eta > 0`` (``noise`` wins; it must
                have the shape of ``x_k``).
            clip_x0: if set, clamp the implied ``x0_hat`` to ``[-clip_x0, clip_x0]`` and re-derive
                eps from it (diffusers' ``clip_sample``). Off by default, as in the paper.
        """
        ab, ab_prev = self._at(k, x_k), self._at(prev_k, x_k)
        if clip_x0 is not None:
            x0 = self.predict_x0(x_k, eps_hat, k).clamp(-clip_x0, clip_x0)
            eps_hat = (x_k - self._cast(ab.sqrt(), x_k) * x0) / self._cast((1 - ab).sqrt(), x_k)
        sigma = eta * ((1 - ab_prev) / (1 - ab)).sqrt() * (1 - ab / ab_prev).clamp_min(0).sqrt()
        c0 = (ab_prev / ab).sqrt()
        c1 = (1 - ab).sqrt()
        c2 = (1 - ab_prev - sigma * sigma).clamp_min(0).sqrt()
        x_prev = self._cast(c0, x_k) * x_k + self._cast(c2 - c0 * c1, x_k) * eps_hat
        if eta > 0:
            if noise is None:
                noise = torch.randn(x_k.shape, generator=generator, device=x_k.device, dtype=x_k.dtype)
            x_prev = x_prev + self._cast(sigma, x_k) * noise
        return x_prev

    def __repr__(self) -> str:
        return (f"DDPMSchedule(num_train_steps={self.num_train_steps}, beta_start={self.beta_start}, "
                f"beta_end={self.beta_end})")
