"""Per-robot perception CNN: observation ``O_i [C, S, S]`` -> embedding ``z_i [z_dim]``."""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["PerceptionCNN", "apply_per_robot"]


class PerceptionCNN(nn.Module):
    """Three (or ``len(channels)``) conv layers, each Conv -> [BatchNorm] -> LeakyReLU, then
    flatten -> Linear -> LeakyReLU to ``z_dim``.

    ``forward(obs [R, C, S, S]) -> z [R, z_dim]`` over a flat batch of R robot images; use
    :func:`apply_per_robot` for ``[B, N, C, S, S]`` with padding.
    """

    def __init__(self, in_channels: int = 4, image_size: int = 32, channels: tuple[int, ...] = (32, 32, 32),
                 kernel: int = 3, stride: int = 1, padding: int = 0, norm: str = "batch",
                 z_dim: int = 32, leaky_slope: float = 0.01):
        super().__init__()
        layers: list[nn.Module] = []
        c_in, size = in_channels, image_size
        for c_out in channels:
            layers.append(nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=padding, bias=norm != "batch"))
            if norm == "batch":
                layers.append(nn.BatchNorm2d(c_out))
            layers.append(nn.LeakyReLU(leaky_slope))
            c_in = c_out
            size = (size + 2 * padding - kernel) // stride + 1
        if size < 1:
            raise ValueError("CNN reduces the image to nothing; check kernel/stride/padding")
        self.convs = nn.Sequential(*layers)
        self.flat_dim = c_in * size * size
        self.linear = nn.Linear(self.flat_dim, z_dim)
        self.act = nn.LeakyReLU(leaky_slope)

    def forward(self, obs: Tensor) -> Tensor:
        """``obs [R, C, S, S]`` -> ``z [R, z_dim]``.

        The images are fed in channels-last layout (oneDNN's preferred one: ~30% faster training
        steps on CPU); this changes only the memory layout, not the values or the flatten order."""
        h = self.convs(obs.contiguous(memory_format=torch.channels_last))
        return self.act(self.linear(h.flatten(1)))


def apply_per_robot(net: nn.Module, obs: Tensor, valid: Tensor | None, out_dim: int) -> Tensor:
    """Run a per-robot image network over ``obs [B, N, C, S, S]`` -> ``[B, N, out_dim]``.

    Only valid robots are processed (so padding never enters BatchNorm statistics and costs no
    compute); padding rows of the result are zero.
    """
    b, n = obs.shape[:2]
    flat = obs.reshape(b * n, *obs.shape[2:])
    if valid is None:
        return net(flat).reshape(b, n, out_dim)
    keep = valid.reshape(b * n).to(torch.bool)
    z = net(flat[keep])
    out = z.new_zeros(b * n, out_dim)
    out[keep] = z
    return out.reshape(b, n, out_dim)
