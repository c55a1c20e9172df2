"""What both learned policies do around their model: the swarm's tensors in, speed-clipped actions out."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from madp.sim import CoverageEnv


def swarm_tensors(envs: list[CoverageEnv], device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """``obs [B, N, 4, 32, 32]`` and ``pos_m [B, N, 2]`` (float32: each robot's own position estimate,
    the true one without position noise) of B environments with the same N."""
    obs = torch.from_numpy(np.stack([e.observations() for e in envs])).to(device)
    pos = torch.from_numpy(np.stack([e.estimates_m() for e in envs]).astype(np.float32)).to(device)
    return obs, pos

