"""LPAC-K3 behind the simulator's controller interface: one forward pass on the observation tensors
and positions, ``policy(env) -> actions [N, 2]`` m/s."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from .swarm import clip_speed, swarm_tensors

if TYPE_CHECKING:
    from madp.sim import CoverageEnv


class LPACPolicy:
    """LPAC-K3 (:class:`madp.models.lpac.LPAC`) acting on the simulator; it draws no noise."""

    def __init__(self, model, device: str = "cpu"):
        self.model, self.device = model.eval(), torch.device(device)

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        return self.act_batch([env])[0]

    @torch.no_grad()
    def act_batch(self, envs: list[CoverageEnv], generators: list[torch.Generator] | None = None) -> np.ndarray:
        """Actions ``[B, N, 2]`` (m/s) for B environments with the same N, in one forward pass
        (``generators`` is accepted for the common interface; LPAC-K3 draws no noise)."""
        obs, pos = swarm_tensors(envs, self.device)
        u = self.model.denormalize_actions(self.model(obs, pos)).double().cpu().numpy()
        return np.stack([clip_speed(x, e.params.max_speed_mps) for x, e in zip(u, envs)])
