"""Model configurations for MADP and LPAC-K3, with named presets.

Two presets exist for each model:

``paper``
    The architecture of the MADP paper (§III) and of the Coverage Control Library's LPAC-K3, as
    the configurations below pin them down. Meant for a GPU.

``cpu``
    A smaller MADP that keeps every architectural idea (per-robot CNN, spatial transformer with
    first-layer 2-D RoPE, distance/component attention mask, encoder-once / decoder-S-times DDIM)
    but is sized for a 2-core CPU: a training step on 32 samples x 32 robots takes a fraction of a
    second, and decentralized inference (32 robots, each denoising its own neighbourhood, S = 50
    DDIM steps) stays within the paper's 0.36 s per control step. LPAC-K3's ``cpu`` preset keeps
    its graph network and swaps in the same cheap perception CNN (see :func:`lpac_config`).

Configs are plain dataclasses; ``to_dict``/``from_dict`` give a JSON-safe form for checkpoints.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

__all__ = ["MADPConfig", "LPACConfig", "madp_config", "lpac_config", "PRESETS"]

PRESETS = ("paper", "cpu")


def _to_dict(cfg: Any) -> dict[str, Any]:
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


#: Config keys of earlier checkpoints and their names now (checkpoints written before keep loading).
RENAMED_KEYS = {"comm_radius": "comm_radius_m"}


def _from_dict(cls: type, d: dict[str, Any]) -> Any:
    d = {RENAMED_KEYS.get(k, k): v for k, v in d.items()}
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(d) - set(names)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} keys: {sorted(unknown)}")
    kwargs = {}
    for k, v in d.items():
        if isinstance(v, list):  # JSON has no tuples
            v = tuple(v)
        kwargs[k] = v
    return cls(**kwargs)


@dataclass
class MADPConfig:
    """Hyper-parameters of :class:`madp.models.MADP`.

    Geometry is in metres. Defaults are the ``paper`` preset.
    """

    preset: str = "paper"

    # --- geometry -------------------------------------------------------------------------------
    world_size: float = 1024.0
    """World side length (m)."""
    comm_radius_m: float = 256.0
    """Attention radius r_att = communication radius r_c (m): robots attend to robots closer than this."""

    # --- perception: O_i [C, S, S] -> z_i [z_dim] -----------------------------------------------
    obs_channels: int = 4
    obs_size: int = 32
    cnn_channels: tuple[int, ...] = (32, 32, 32)
    """Output channels of the conv layers (the paper: three layers)."""
    cnn_kernel: int = 3
    cnn_stride: int = 1
    cnn_padding: int = 0
    cnn_norm: str = "batch"
    """``"batch"`` (BatchNorm2d after each conv, as the library's CNN backbone) or ``"none"``."""
    z_dim: int = 32
    pos_token: str = "neighbourhood_offset"
    """What stands in for x_i in the token [z_i, x_i]:

    ``"neighbourhood_offset"``: (x_i - mean of x_j over i's attention neighbourhood incl. i) / r_c.
    ``"none"``: zeros (positions enter only through RoPE).

    The paper concatenates the absolute position, which would break the shift invariance it
    claims for the spatial transformer. Both options here are shift invariant and local (robot i
    computes its feature from the positions of its neighbours, which it receives anyway).
    """

    # --- spatial transformer ----------------------------------------------------------------------
    d_model: int = 256
    n_heads: int = 8
    n_enc_layers: int = 8
    n_dec_layers: int = 8
    mlp_ratio: int = 4
    dropout: float = 0.0
    leaky_slope: float = 0.01
    rope_tau: float = 1024.0
    """RoPE period tau (m): omega_i = 2*pi*tau^(-4i/D), i = 1..D/4; the slowest wave has period tau."""
    rope_layers: int = 1
    """Number of leading layers (of encoder and of decoder) whose attention uses RoPE (paper: 1)."""

    # --- diffusion --------------------------------------------------------------------------------
    num_train_steps: int = 1000
    beta_start: float = 1e-4
    beta_end: float = 0.02
    action_dim: int = 2
    time_embed_dim: int = 0
    """Width of the sinusoidal diffusion-step embedding; 0 means d_model."""
    prediction: str = "epsilon"
    """What the head predicts: ``"epsilon"`` (the DDPM noise, as the paper trains it) or ``"sample"``
    (the clean normalised actions U_0; the samplers get the noise derived from it). A model distilled
    into one sampler step (``madp train --distill``) predicts the sample."""

    def __post_init__(self) -> None:
        if self.d_model % self.n_heads:
            raise ValueError("d_model must be divisible by n_heads")
        if self.head_dim % 4:
            raise ValueError("head_dim must be divisible by 4 (2-D RoPE uses D/4 frequencies per axis)")
        if self.cnn_norm not in ("batch", "none"):
            raise ValueError(f"cnn_norm must be 'batch' or 'none', got {self.cnn_norm!r}")
        if self.prediction not in ("epsilon", "sample"):
            raise ValueError(f"prediction must be 'epsilon' or 'sample', got {self.prediction!r}")
        if self.pos_token not in ("neighbourhood_offset", "none"):
            raise ValueError(f"pos_token must be 'neighbourhood_offset' or 'none', got {self.pos_token!r}")
        self.cnn_channels = tuple(int(c) for c in self.cnn_channels)

    @property
    def head_dim(self) -> int:
        return self.d_model // self.n_heads

    @property
    def token_dim(self) -> int:
        """Width of the raw token [z_i, pos feature] (34 in the paper)."""
        return self.z_dim + 2

    def to_dict(self) -> dict[str, Any]:
        return _to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MADPConfig":
        return _from_dict(cls, d)


@dataclass
class LPACConfig:
    """Hyper-parameters of :class:`madp.models.lpac.LPAC` (LPAC-K3 of the Coverage Control Library)."""

    preset: str = "paper"
    world_size: float = 1024.0
    comm_radius_m: float = 256.0
    obs_channels: int = 4
    obs_size: int = 32
    cnn_channels: tuple[int, ...] = (32, 32, 32)
    """Conv layers of the perception CNN (each Conv -> BatchNorm -> LeakyReLU), then Linear -> z_dim."""
    cnn_kernel: int = 3
    cnn_stride: int = 1
    cnn_padding: int = 0
    z_dim: int = 32
    gnn_layers: int = 5
    gnn_hops: int = 3
    gnn_hidden: int = 256
    mlp_hidden: tuple[int, ...] = (32, 32)
    action_dim: int = 2
    edge_weight: str = "binary"
    """``"binary"``: w_ij = 1 for d_ij < r_c, the unweighted graph the library trains LPAC-K3 on
    (default; docs/reports/2026-12-03-relabelling.md has the measured ablation); ``"gaussian"``:
    w_ij = exp(-d_ij^2 / r_c^2) (``CoverageEnvUtils.get_weights``; the checkpoints shipped before
    2026-12 carry it in their config). No self loops; TAGConv normalises symmetrically
    (D^-1/2 A D^-1/2)."""
    pos_norm: str = "library"
    """``"library"``: (x + W/2) / W as the library's ``get_torch_geometric_data`` does
    (in [0.5, 1.5]); ``"unit"``: x / W (in [0, 1])."""
    leaky_slope: float = 0.01

    def __post_init__(self) -> None:
        if self.edge_weight not in ("gaussian", "binary"):
            raise ValueError(f"edge_weight must be 'gaussian' or 'binary', got {self.edge_weight!r}")
        if self.pos_norm not in ("library", "unit"):
            raise ValueError(f"pos_norm must be 'library' or 'unit', got {self.pos_norm!r}")
        self.mlp_hidden = tuple(int(c) for c in self.mlp_hidden)
        self.cnn_channels = tuple(int(c) for c in self.cnn_channels)

    def to_dict(self) -> dict[str, Any]:
        return _to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "LPACConfig":
        return _from_dict(cls, d)


def madp_config(preset: str = "paper", **overrides: Any) -> MADPConfig:
    """MADP config for a named preset, with optional field overrides.

    ``paper`` (paper §III): d_model = 8 heads x 32 = 256, 8 encoder + 8 decoder layers,
    pre-norm, LeakyReLU MLP (4x), RoPE (tau = 1024 m) in the first layer, r_att = 256 m. The paper
    only says "a three-layer CNN produces z_i in R^32"; the paper's authors built on the Coverage
    Control Library, so the perception reuses that library's CNN backbone: 3 x (Conv 3x3 without
    padding, 32 channels, BatchNorm, LeakyReLU), flatten (32 x 26 x 26), Linear -> 32. ~30 MFLOP
    per robot forward, about as much as the whole 16-layer transformer per token.

    ``cpu``: sized for 2 CPU cores (measured with :mod:`madp.models.bench`):

    * CNN with stride-2 convs (16, 32, 32 channels; 32 -> 16 -> 8 -> 4 pixels) and BatchNorm:
      ~1.2 MFLOP per robot instead of ~30, because in training the CNN runs on every robot of
      every sample (B x 32 images per step) and would otherwise dominate the step.
    * d_model 64 = 4 heads x 16 (head dim 16 gives 4 RoPE frequencies per axis, periods
      1024^(i/4) = 5.7, 32, 181, 1024 m; the paper's head dim 32 gives 8, from 2.4 m to 1024 m),
      2 encoder + 2 decoder layers (two layers still let information travel two hops in the
      centralized-masked pass). Decentralized inference runs the decoder 50 times on N
      ego-neighbourhoods of up to M tokens each (N*M tokens, up to 1024 for a fully connected
      swarm), so the decoder cost per token has to stay ~0.2 MFLOP.

    Measured on this 2-core machine (``madp.models.bench``; other jobs were sharing the cores, so
    expect +-30%): training ~170-240 samples/s at batch 32 x 32 robots (~5 GFLOP per step);
    decentralized control step for 32 robots with S = 50: ~0.17 s for a uniform launch
    (neighbourhoods of <= 9), ~0.34 s in the worst case of a fully connected swarm computed per robot,
    ~0.075 s for that case with neighbourhood de-duplication; centralized-masked ~0.07 s. The paper
    preset on the same machine: ~6 samples/s at batch 196 (1.13 TFLOP per step), ~2 s per
    decentralized control step.
    """
    if preset == "paper":
        cfg = MADPConfig(preset="paper")
    elif preset == "cpu":
        cfg = MADPConfig(
            preset="cpu",
            cnn_channels=(16, 32, 32),
            cnn_stride=2,
            cnn_padding=1,
            d_model=64,
            n_heads=4,
            n_enc_layers=2,
            n_dec_layers=2,
        )
    else:
        raise ValueError(f"unknown preset {preset!r}; choose from {PRESETS}")
    return dataclasses.replace(cfg, **overrides) if overrides else cfg


def lpac_config(preset: str = "paper", **overrides: Any) -> LPACConfig:
    """LPAC-K3 config for a named preset, with optional field overrides.

    ``paper``: the library's LPAC-K3: CNN 3 x (Conv 3x3 no padding, 32 ch, BatchNorm,
    LeakyReLU), flatten (32 x 26 x 26), Linear -> 32 (+ LeakyReLU as in the library); concat
    normalised position -> 34; 5 x TAGConv(K=3, 256) with ReLU; torch_geometric MLP [256, 32, 32]
    (BatchNorm, ReLU, plain last) and Linear 32 -> 2.

    ``cpu``: the same graph network (5 x TAGConv K=3, 256 hidden, the MLP head), but the perception
    CNN of MADP's ``cpu`` preset (stride-2 convs 16/32/32 with padding, BatchNorm, LeakyReLU,
    Linear -> 32). LPAC-K3 has few parameters (1.8 M) but its unpadded 32-channel convs cost
    ~30 MFLOP per robot image, and training runs them on every robot of every sample: measured on
    this 2-core machine, the paper architecture trains at ~18 samples/s (batch 32 x 32 robots; a
    70k-sample epoch would take over an hour), ~10x slower than the ``cpu`` MADP. Giving both
    models the same perception CNN in each preset keeps the comparison about what the paper
    compares (diffusion transformer vs. graph network), and the TAGConv part, which defines
    LPAC-K3, is unchanged.
    """
    if preset == "paper":
        cfg = LPACConfig(preset="paper")
    elif preset == "cpu":
        cfg = LPACConfig(preset="cpu", cnn_channels=(16, 32, 32), cnn_stride=2, cnn_padding=1)
    else:
        raise ValueError(f"unknown preset {preset!r}; choose from {PRESETS}")
    return dataclasses.replace(cfg, **overrides) if overrides else cfg
