"""Action normalisation shared by the policies: the dataset's statistics live in the model's buffers
``action_mean [2]`` and ``action_std [2]`` (m/s), so they travel inside every checkpoint."""

from __future__ import annotations

import torch
from torch import Tensor, nn


class ActionStatsMixin(nn.Module):
    """Adds ``action_mean``/``action_std`` buffers and (de)normalisation to a policy module."""

    def _init_action_stats(self, action_dim: int) -> None:
        self.register_buffer("action_mean", torch.zeros(action_dim))
        self.register_buffer("action_std", torch.ones(action_dim))

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def set_action_stats(self, mean: Tensor, std: Tensor) -> None:
        """Store the dataset's action statistics ``mean [2]``, ``std [2]`` (m/s) in the buffers."""
        self.action_mean.copy_(torch.as_tensor(mean, dtype=self.action_mean.dtype))
        self.action_std.copy_(torch.as_tensor(std, dtype=self.action_std.dtype))

    def normalize_actions(self, u: Tensor) -> Tensor:
        """``u [..., 2]`` m/s -> normalised ``(u - mean) / std``."""
        return (u - self.action_mean) / self.action_std

    def denormalize_actions(self, u_norm: Tensor) -> Tensor:
        """normalised ``[..., 2]`` -> m/s."""
        return u_norm * self.action_std + self.action_mean
