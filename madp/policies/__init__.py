"""Learned policies behind the simulator's controller interface: ``policy(env) -> actions [N, 2] m/s``.

- :class:`LPACPolicy`: LPAC-K3 on the observation tensors and positions (one forward pass).
- :class:`MADPPolicy`: MADP with a sampler (DDIM or DPM-Solver++, S steps, η for DDIM).
  ``mode="decentralized"``: each robot samples
  from the tokens of its own neighbourhood and keeps its own action (what the robots would run);
  ``mode="centralized"``: one masked pass over the whole swarm (a faster approximation).

Checkpoints are ``policy.safetensors`` files (weights + metadata); the ones shipped with madp live
in ``madp/checkpoints/``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import torch

from madp.models.samplers import DEFAULT_SAMPLER, DEFAULT_SAMPLING_STEPS, check_sampler
from madp.sim import CoverageEnv

SHIPPED = {"madp": "madp-cpu.safetensors", "lpac": "lpac-cpu.safetensors"}


def shipped_checkpoint(kind: str) -> Path | None:
    """Path of the checkpoint that ships with the package, or None if this install has none."""
    p = Path(str(resources.files("madp") / "checkpoints" / SHIPPED[kind]))
    return p if p.is_file() else None


def load(path: str | Path, expect: str, device: str = "cpu"):
    """Load a policy checkpoint and check its kind; one-line errors for missing/incompatible files."""
    from madp.training.checkpoint import load_policy

    model, meta = load_policy(path, device)
    torch.set_flush_denormal(True)  # subnormal weights (see madp.training.trainer) would slow every step
    if meta["kind"] != expect:
        raise ValueError(f"{path}: is a {meta['kind']} checkpoint, expected {expect}")
    return model, meta


def noise_generator(seed: int) -> torch.Generator:
    """The sampling-noise generator of one episode, seeded by its scenario seed. It lives on the CPU
    whatever device the policy runs on: the noise is drawn there and moved to the device, so a seed
    gives the same noise on every device (results differ only by the device's float rounding)."""
    g = torch.Generator()
    g.manual_seed(int(seed) & ((1 << 63) - 1))
    return g


def _swarm_tensors(envs: list[CoverageEnv], device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """``obs [B, N, 4, 32, 32]`` and ``pos_m [B, N, 2]`` (float32) of B environments with the same N."""
    obs = torch.from_numpy(np.stack([e.observations() for e in envs])).to(device)
    pos = torch.from_numpy(np.stack([e.positions_m for e in envs]).astype(np.float32)).to(device)
    return obs, pos


def _clip_speed(u: np.ndarray, u_max: float) -> np.ndarray:
    speed = np.linalg.norm(u, axis=1, keepdims=True)
    return np.where(speed > u_max, u * (u_max / np.maximum(speed, 1e-12)), u)


class LPACPolicy:
    name = "lpac"

    def __init__(self, model, device: str = "cpu"):
        self.model, self.device = model.eval(), torch.device(device)

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        return self.act_batch([env])[0]

    @torch.no_grad()
    def act_batch(self, envs: list[CoverageEnv], generators: list[torch.Generator] | None = None) -> np.ndarray:
        """Actions ``[B, N, 2]`` (m/s) for B environments with the same N, in one forward pass
        (``generators`` is accepted for the common interface; LPAC-K3 draws no noise)."""
        obs, pos = _swarm_tensors(envs, self.device)
        u = self.model.denormalize_actions(self.model(obs, pos)).double().cpu().numpy()
        return np.stack([_clip_speed(x, e.params.max_speed_mps) for x, e in zip(u, envs)])


class MADPPolicy:
    """``seed`` fixes the sampling noise (a generator reset per episode by :meth:`reset`);
    ``sampler`` / ``num_steps`` / ``eta`` choose the reverse diffusion (see :mod:`madp.models.samplers`).

    ``fixed_noise``: each robot draws its initial noise ``U_K`` once per episode and reuses it at
    every control step (with a deterministic sampler the policy is then a function of the state),
    instead of a fresh draw per step; per-step noise of DDIM with η > 0 stays fresh."""

    def __init__(self, model, mode: str = "decentralized", num_steps: int = DEFAULT_SAMPLING_STEPS, eta: float = 0.0,
                 seed: int = 0, device: str = "cpu", sampler: str = DEFAULT_SAMPLER, fixed_noise: bool = False):
        if mode not in ("decentralized", "centralized"):
            raise ValueError(f"--madp-mode: expected decentralized or centralized, got {mode!r}")
        check_sampler(sampler, num_steps, eta)
        self.model, self.mode, self.num_steps, self.eta = model.eval(), mode, int(num_steps), float(eta)
        self.sampler, self.fixed_noise = sampler, bool(fixed_noise)
        self._fixed: dict[int, torch.Tensor] = {}
        self.stochastic = sampler == "ddim" and self.eta > 0  # fresh noise at every sampler step
        self.device = torch.device(device)
        self.name = "madp" if mode == "decentralized" else "madp_central"
        self.reset(seed)

    @property
    def settings(self) -> dict:
        """What names the sampling in tables and recordings."""
        return {"sampler": self.sampler, "sampling_steps": self.num_steps, "eta": self.eta,
                "fixed_noise": self.fixed_noise}

    def reset(self, seed: int) -> None:
        self.generator = noise_generator(seed)
        self._fixed = {}

    def _noise(self, g: torch.Generator, shape: tuple[int, ...], fixed: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The noise of one sampling call from the CPU generator ``g``, on the policy's device:
        ``U_K`` of ``shape`` (with ``fixed``: the episode's first draw, kept per generator: one
        generator per environment and episode), then, when the sampler is stochastic (DDIM with
        η > 0), one fresh draw per sampler step ``[S, *shape]``; in the order the model would draw them."""
        if not fixed:
            first = torch.randn(shape, generator=g)
        else:
            if id(g) not in self._fixed:
                self._fixed[id(g)] = torch.randn(shape, generator=g)
            first = self._fixed[id(g)]
        steps = torch.stack([torch.randn(shape, generator=g) for _ in range(self.num_steps)]) if self.stochastic else None
        return first.to(self.device), None if steps is None else steps.to(self.device)

    def _sample(self, obs: torch.Tensor, pos: torch.Tensor, noise: torch.Tensor, step_noise: torch.Tensor | None) -> torch.Tensor:
        fn = self.model.sample_decentralized if self.mode == "decentralized" else self.model.sample
        return fn(obs, pos, self.num_steps, self.eta, sampler=self.sampler, noise=noise, step_noise=step_noise)

    @torch.no_grad()
    def sample(self, env: CoverageEnv, num_samples: int = 1, generator: torch.Generator | None = None) -> np.ndarray:
        """``num_samples`` independent swarm actions [M, N, 2] (m/s) for the current state.

        ``generator`` (a CPU generator; default: the policy's own) lets a caller draw extra samples,
        e.g. for visualisation, without changing the noise the rollout itself uses."""
        own = generator is None
        generator = generator or self.generator
        obs = torch.from_numpy(env.observations()).to(self.device)
        pos = torch.from_numpy(env.positions_m.astype(np.float32)).to(self.device)
        obs = obs[None].expand(num_samples, *obs.shape)
        pos = pos[None].expand(num_samples, *pos.shape)
        shape = (num_samples, env.num_robots, self.model.config.action_dim)
        noise, steps = self._noise(generator, shape, own and self.fixed_noise and num_samples == 1)
        u = self.model.denormalize_actions(self._sample(obs, pos, noise, steps)).double().cpu().numpy()
        return np.stack([_clip_speed(x, env.params.max_speed_mps) for x in u])

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        return self.sample(env, 1)[0]

    @torch.no_grad()
    def act_batch(self, envs: list[CoverageEnv], generators: list[torch.Generator]) -> np.ndarray:
        """Actions ``[B, N, 2]`` (m/s) for B environments with the same N, sampled as one batch.

        Environment b's noise comes from ``generators[b]`` (CPU generators) in the order a lone
        :meth:`sample` would draw it (U_K, then one draw per step when the sampler is stochastic:
        DDIM with η > 0), so batching changes only float rounding."""
        obs, pos = _swarm_tensors(envs, self.device)
        shape = (1, pos.shape[1], self.model.config.action_dim)
        noise = [self._noise(g, shape, self.fixed_noise) for g in generators]
        first = torch.cat([n[0] for n in noise])
        steps = torch.cat([n[1] for n in noise], dim=1) if self.stochastic else None
        u = self.model.denormalize_actions(self._sample(obs, pos, first, steps)).double().cpu().numpy()
        return np.stack([_clip_speed(x, e.params.max_speed_mps) for x, e in zip(u, envs)])
