"""Torch modules of madp: perception CNN, spatial transformer (2-D RoPE, masks), DDPM/DDIM
schedule with DDIM and DPM-Solver++ samplers, MADP, LPAC-K3, EMA. Knows nothing of files or the simulator.

LPAC-K3 (:mod:`madp.models.lpac`: ``LPAC``, ``batch_graph``, ``sparse_adjacency``) imports
torch_geometric, several seconds, so it is imported from its module, not re-exported here.

Shapes used throughout: ``obs [B, N, 4, 32, 32]``, ``pos_m [B, N, 2]`` (metres),
``valid [B, N]`` bool (False = padding robot), ``actions_norm [B, N, 2]`` (normalised actions).
"""

from .attention_mask import (
    attention_mask,
    connected_components_mask,
    packed_neighbourhood_mask,
    pairwise_offsets,
    radius_adjacency,
)
from .config import PRESETS, LPACConfig, MADPConfig, lpac_config, madp_config
from .diffusion import DDPMSchedule
from .ema import EMA
from .samplers import (
    DEFAULT_SAMPLER,
    DEFAULT_SAMPLING_STEPS,
    SAMPLERS,
    DDIMSampler,
    DPMSolverMultistepSampler,
    make_sampler,
)
from .madp import MADP, TimestepEmbedding
from .perception import PerceptionCNN, apply_per_robot
from .transformer import (
    DecoderLayer,
    EncoderLayer,
    MultiHeadAttention,
    RotaryEmbedding2D,
    SpatialTransformerDecoder,
    SpatialTransformerEncoder,
    apply_rope,
)

__all__ = [
    "MADP",
    "MADPConfig",
    "madp_config",
    "LPACConfig",
    "lpac_config",
    "PRESETS",
    "DDPMSchedule",
    "EMA",
    "PerceptionCNN",
    "apply_per_robot",
    "attention_mask",
    "connected_components_mask",
    "radius_adjacency",
    "pairwise_offsets",
    "packed_neighbourhood_mask",
    "SAMPLERS",
    "DEFAULT_SAMPLER",
    "DEFAULT_SAMPLING_STEPS",
    "DDIMSampler",
    "DPMSolverMultistepSampler",
    "make_sampler",
    "RotaryEmbedding2D",
    "apply_rope",
    "MultiHeadAttention",
    "EncoderLayer",
    "DecoderLayer",
    "SpatialTransformerEncoder",
    "SpatialTransformerDecoder",
    "TimestepEmbedding",
]
