"""Helpers shared by the model tests (imported by basename; tests/models is on sys.path)."""

import torch

from madp.models import madp_config


def tiny_madp_config(**overrides):
    """A small MADP: head dim 8 (2 RoPE frequencies per axis), 2 + 2 layers, stride-2 CNN."""
    kw = dict(cnn_channels=(4, 8, 8), d_model=32, n_heads=4, n_enc_layers=2, n_dec_layers=2)
    kw.update(overrides)
    return madp_config("cpu", **kw)


def grid_positions(n, low, high, generator):
    """``[n, 2]`` positions on a 1/64 m grid in [low, high]^2, so integer shifts are exact in float32."""
    return torch.round((low + (high - low) * torch.rand(n, 2, generator=generator)) * 64) / 64


def random_obs(*shape, generator):
    """``[*shape, 4, 32, 32]`` observations in [0, 1)."""
    return torch.rand(*shape, 4, 32, 32, generator=generator)
