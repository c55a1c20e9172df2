"""Spatial transformer (paper §III-B): masked multi-head attention over robots, with 2-D rotary
position embedding (RoPE) on queries and keys of the first layer(s) only.

Shapes: ``x [B, N, d_model]`` robot tokens, ``mask [B, N, N]`` bool (True = may attend) or the
same as an additive float bias ``[B, 1, N, N]`` (:func:`attention_bias`), ``rope`` the rotations of
:class:`RotaryEmbedding2D` (D = head dim) in either of two forms: ``(cos, sin)`` each ``[B, 1, N, D/2]``
(what training and the ONNX export use, any dtype), or the same rotations as one complex table
``[B, N, 1, D/2]`` (:meth:`RotaryEmbedding2D.rotations`; float32/float64 activations only), which a
layer applies to the queries and keys of every head in one complex multiply (:func:`rotate_heads`),
the sampling path's form.

A linear layer may hold its weights in a lower precision than the residual stream (bfloat16 sampling,
:meth:`madp.models.MADP.with_bf16_linears`): it casts its input to its weights' dtype; the query, key
and value projections are cast back, so RoPE and attention run in the stream's dtype, and the output
projections join the residual stream by type promotion. With one dtype throughout nothing is cast.

All layers are pre-norm: ``x = x + Attn(LN(x))``, ``x = x + MLP(LN(x))`` with a LeakyReLU MLP.
(The paper's eq. 7 writes the non-linearity around the residual sum, but states the pre-norm
scheme; the standard pre-norm residual stream is used here.)
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = [
    "RotaryEmbedding2D",
    "apply_rope",
    "rotate_heads",
    "attention_bias",
    "MultiHeadAttention",
    "MLP",
    "EncoderLayer",
    "DecoderLayer",
    "SpatialTransformerEncoder",
    "SpatialTransformerDecoder",
]

Rope = tuple[Tensor, Tensor] | Tensor  # (cos, sin) [B, 1, N, D/2] or complex rotations [B, N, 1, D/2]


class RotaryEmbedding2D(nn.Module):
    """2-D RoPE angles for a head of dimension D (paper eq. 9).

    Frequencies ``omega_i = 2*pi * tau^(-4i/D)``, ``i = 1 .. D/4`` (the paper's 1-based index; the
    slowest wave has period tau, the fastest tau^(4/D)). Adjacent real pairs
    ``(q[2c], q[2c+1])`` form D/2 complex channels; channels ``c < D/4`` rotate by
    ``omega_{c+1} * x``, channels ``c >= D/4`` by ``omega_{c+1-D/4} * y``. So in real dims, the first
    D/2 are rotated by x and the last D/2 by y, and ``<R(x_n) q, R(x_m) k>`` depends on
    ``x_m - x_n`` only.

    Angles are computed in float64 (positions up to ~1000 m times omega up to ~2.6 rad/m would
    lose ~1e-4 rad in float32) and cos/sin are cast to the requested dtype.
    """

    def __init__(self, head_dim: int, tau: float = 1024.0):
        super().__init__()
        if head_dim % 4:
            raise ValueError("head_dim must be divisible by 4")
        self.head_dim = head_dim
        self.tau = float(tau)

    def frequencies(self, device: torch.device | None = None, dtype: torch.dtype = torch.float64) -> Tensor:
        """``omega [D/4]`` in rad/m."""
        i = torch.arange(1, self.head_dim // 4 + 1, device=device, dtype=dtype)
        return 2 * math.pi * self.tau ** (-4.0 * i / self.head_dim)

    def angles(self, pos_m: Tensor) -> Tensor:
        """``pos_m [B, N, 2]`` -> the rotation angles ``[B, N, D/2]`` in rad, float64 (float32 on MPS)."""
        work = torch.float32 if pos_m.device.type == "mps" else torch.float64
        omega = self.frequencies(pos_m.device, work)
        p = pos_m.to(work)
        return torch.cat([p[..., 0:1] * omega, p[..., 1:2] * omega], dim=-1)

    def forward(self, pos_m: Tensor, dtype: torch.dtype = torch.float32) -> tuple[Tensor, Tensor]:
        """``pos_m [B, N, 2]`` -> ``(cos, sin)`` each ``[B, 1, N, D/2]``."""
        ang = self.angles(pos_m).unsqueeze(1)
        return ang.cos().to(dtype), ang.sin().to(dtype)

    def rotations(self, pos_m: Tensor, dtype: torch.dtype = torch.float32) -> Tensor:
        """``pos_m [B, N, 2]`` -> the same rotations as :meth:`forward`, as one complex table
        ``[B, N, 1, D/2]`` (``cos + i sin``, each part rounded to ``dtype``: float32 or float64)."""
        ang = self.angles(pos_m).unsqueeze(-2)
        return torch.complex(ang.cos().to(dtype), ang.sin().to(dtype))


def attention_bias(mask: Tensor, dtype: torch.dtype) -> Tensor:
    """Bool ``mask [B, N, N]`` -> additive bias ``[B, 1, N, N]`` (0 where allowed, -inf elsewhere).

    Every layer accepts either form; sampling converts once per control step, since the CPU
    attention kernel is ~1.5x faster with a float bias than with a bool mask on small batches."""
    return torch.zeros(mask.shape, dtype=dtype, device=mask.device).masked_fill_(~mask, float("-inf")).unsqueeze(1)


def apply_rope(x: Tensor, rope: tuple[Tensor, Tensor]) -> Tensor:
    """Rotate ``x [B, H, N, D]`` pairwise by ``rope = (cos, sin) [B, 1, N, D/2]``."""
    cos, sin = rope
    xp = x.unflatten(-1, (-1, 2))
    x0, x1 = xp[..., 0], xp[..., 1]
    return torch.stack((x0 * cos - x1 * sin, x0 * sin + x1 * cos), dim=-1).flatten(-2)


def rotate_heads(t: Tensor, rotations: Tensor) -> Tensor:
    """Rotate ``t [B, N, M * D]`` (M heads of dimension D side by side, per token: the queries, or the
    queries and keys, of every head) pairwise by the complex ``rotations [B, N, 1, D/2]`` of each token:
    :func:`apply_rope`'s rotation as one complex multiply -> ``[B, N, M * D]``, contiguous. ``t`` may be
    a slice of a wider last dimension (``qkv[..., :2 * d]``)."""
    pairs = torch.view_as_complex(t.unflatten(-1, (-1, rotations.shape[-1], 2)))  # [B, N, M, D/2]
    return torch.view_as_real(pairs * rotations).flatten(-3)


def _linear(layer: nn.Linear, x: Tensor, back: bool = False) -> Tensor:
    """``layer(x)``; a layer whose weights are in another dtype than ``x`` (bfloat16 in a float32 stream)
    computes on ``x`` cast to it, and with ``back`` its result is cast back to ``x``'s dtype. Where the
    dtypes agree this is ``layer(x)`` itself (under autocast too)."""
    w = layer.weight.dtype
    if x.dtype == w:
        return layer(x)
    y = layer(x.to(w))
    return y.to(x.dtype) if back else y


def _rotations(rope: Rope | None) -> bool:
    """Whether ``rope`` is the complex table (token layout) rather than ``(cos, sin)``."""
    return isinstance(rope, Tensor)


class MultiHeadAttention(nn.Module):
    """Masked multi-head attention (self or cross) on ``scaled_dot_product_attention``.

    Self: ``forward(x, mask, rope)``. Cross: ``forward(x, mask, rope, kv=self.project_kv(context, rope))``
    where ``mask[b, i, j]`` lets query i attend to context token j. With ``rope`` given, queries and
    keys are rotated by the positions of their own robots.
    """

    def __init__(self, d_model: int, n_heads: int, dropout: float = 0.0, cross: bool = False):
        super().__init__()
        self.n_heads = n_heads
        self.head_dim = d_model // n_heads
        self.cross = cross
        self.dropout = dropout
        if cross:
            self.q = nn.Linear(d_model, d_model)
            self.kv = nn.Linear(d_model, 2 * d_model)
        else:
            self.qkv = nn.Linear(d_model, 3 * d_model)
        self.proj = nn.Linear(d_model, d_model)
        self.proj.is_residual_proj = True  # for the scaled init in MADP

    def _heads(self, t: Tensor) -> Tensor:
        """``[B, N, d] -> [B, H, N, D]``."""
        return t.unflatten(-1, (self.n_heads, self.head_dim)).transpose(1, 2)

    def project_kv(self, context: Tensor, rope: Rope | None = None) -> tuple[Tensor, Tensor]:
        """Keys/values of a cross-attention context ``[B, N, d]`` -> ``(k, v)`` each ``[B, H, N, D]``.
        Cacheable: the decoder's context (encoder memory) is fixed over the S denoising steps."""
        kv = _linear(self.kv, context, back=True)
        d = kv.shape[-1] // 2
        if _rotations(rope):
            return self._heads(rotate_heads(kv[..., :d], rope)), self._heads(kv[..., d:])
        k, v = self._heads(kv[..., :d]), self._heads(kv[..., d:])
        return (k if rope is None else apply_rope(k, rope)), v

    def forward(self, x: Tensor, mask: Tensor, rope: Rope | None = None,
                kv: tuple[Tensor, Tensor] | None = None) -> Tensor:
        if self.cross:
            if kv is None:
                raise ValueError("cross-attention needs kv=project_kv(context)")
            q, (k, v) = _linear(self.q, x, back=True), kv
            if _rotations(rope):
                q = self._heads(rotate_heads(q, rope))
            else:
                q = self._heads(q)
                q = q if rope is None else apply_rope(q, rope)
        else:
            qkv = _linear(self.qkv, x, back=True)
            d = qkv.shape[-1] // 3
            if _rotations(rope):  # queries and keys of every head in one multiply
                qk = rotate_heads(qkv[..., :2 * d], rope)
                q, k = self._heads(qk[..., :d]), self._heads(qk[..., d:])
            else:
                q, k = self._heads(qkv[..., :d]), self._heads(qkv[..., d:2 * d])
                if rope is not None:
                    q, k = apply_rope(q, rope), apply_rope(k, rope)
            v = self._heads(qkv[..., 2 * d:])
        y = F.scaled_dot_product_attention(
            q, k, v, attn_mask=mask.unsqueeze(1) if mask.dtype == torch.bool else mask,
            dropout_p=self.dropout if self.training else 0.0,
        )
        return _linear(self.proj, y.transpose(1, 2).flatten(-2))


class MLP(nn.Module):
    def __init__(self, d_model: int, ratio: int = 4, dropout: float = 0.0, leaky_slope: float = 0.01):
        super().__init__()
        self.fc = nn.Linear(d_model, ratio * d_model)
        self.act = nn.LeakyReLU(leaky_slope)
        self.proj = nn.Linear(ratio * d_model, d_model)
        self.proj.is_residual_proj = True
        self.drop = nn.Dropout(dropout)

    def forward(self, x: Tensor) -> Tensor:
        h = _linear(self.fc, x)
        # Without autograd the activation overwrites fc's output: one [.., ratio * d] buffer less per call.
        h = self.act(h) if torch.is_grad_enabled() else F.leaky_relu_(h, self.act.negative_slope)
        return self.drop(_linear(self.proj, h))


def _residual(x: Tensor, branch: Tensor) -> Tensor:
    """``x + branch``; without autograd in place, for an ``x`` the layer itself created (one
    allocation less per residual)."""
    return x + branch if torch.is_grad_enabled() else x.add_(branch)


class EncoderLayer(nn.Module):
    """Pre-norm self-attention + MLP."""

    def __init__(self, d_model: int, n_heads: int, mlp_ratio: int = 4, dropout: float = 0.0,
                 leaky_slope: float = 0.01, use_rope: bool = False):
        super().__init__()
        self.use_rope = use_rope
        self.ln1 = nn.LayerNorm(d_model)
        self.attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ln2 = nn.LayerNorm(d_model)
        self.mlp = MLP(d_model, mlp_ratio, dropout, leaky_slope)

    def forward(self, x: Tensor, mask: Tensor, rope: Rope) -> Tensor:
        x = x + self.attn(self.ln1(x), mask, rope if self.use_rope else None)
        return _residual(x, self.mlp(self.ln2(x)))


class DecoderLayer(nn.Module):
    """Pre-norm self-attention, cross-attention to the encoder memory (same mask), MLP.

    In a RoPE layer both attentions are rotated: self-attention by the robots' positions, and
    cross-attention with decoder queries and memory keys each at their own robot's position,
    so both depend on relative positions only.
    """

    def __init__(self, d_model: int, n_heads: int, mlp_ratio: int = 4, dropout: float = 0.0,
                 leaky_slope: float = 0.01, use_rope: bool = False):
        super().__init__()
        self.use_rope = use_rope
        self.ln1 = nn.LayerNorm(d_model)
        self.self_attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ln2 = nn.LayerNorm(d_model)
        self.cross_attn = MultiHeadAttention(d_model, n_heads, dropout, cross=True)
        self.ln3 = nn.LayerNorm(d_model)
        self.mlp = MLP(d_model, mlp_ratio, dropout, leaky_slope)

    def memory_kv(self, memory: Tensor, rope: Rope) -> tuple[Tensor, Tensor]:
        return self.cross_attn.project_kv(memory, rope if self.use_rope else None)

    def forward(self, x: Tensor, mask: Tensor, rope: Rope, memory_kv: tuple[Tensor, Tensor]) -> Tensor:
        r = rope if self.use_rope else None
        x = x + self.self_attn(self.ln1(x), mask, r)
        x = _residual(x, self.cross_attn(self.ln2(x), mask, r, kv=memory_kv))
        return _residual(x, self.mlp(self.ln3(x)))


class SpatialTransformerEncoder(nn.Module):
    """Psi_E: ``forward(x [B, N, d], mask [B, N, N], rope) -> memory [B, N, d]`` (final LayerNorm)."""

    def __init__(self, d_model: int, n_heads: int, n_layers: int, mlp_ratio: int = 4, dropout: float = 0.0,
                 leaky_slope: float = 0.01, rope_layers: int = 1):
        super().__init__()
        self.layers = nn.ModuleList(
            EncoderLayer(d_model, n_heads, mlp_ratio, dropout, leaky_slope, use_rope=i < rope_layers)
            for i in range(n_layers)
        )
        self.ln_f = nn.LayerNorm(d_model)

    def forward(self, x: Tensor, mask: Tensor, rope: Rope) -> Tensor:
        for layer in self.layers:
            x = layer(x, mask, rope)
        return self.ln_f(x)


class SpatialTransformerDecoder(nn.Module):
    """Psi_D: ``forward(x [B, N, d], mask, rope, memory_kv) -> [B, N, d]`` (final LayerNorm).

    ``memory_kv = decoder.memory_kv(memory, rope)`` holds every layer's cross-attention keys and
    values; compute it once per sample and reuse it for all S denoising steps.
    """

    def __init__(self, d_model: int, n_heads: int, n_layers: int, mlp_ratio: int = 4, dropout: float = 0.0,
                 leaky_slope: float = 0.01, rope_layers: int = 1):
        super().__init__()
        self.layers = nn.ModuleList(
            DecoderLayer(d_model, n_heads, mlp_ratio, dropout, leaky_slope, use_rope=i < rope_layers)
            for i in range(n_layers)
        )
        self.ln_f = nn.LayerNorm(d_model)

    def memory_kv(self, memory: Tensor, rope: Rope) -> list[tuple[Tensor, Tensor]]:
        return [layer.memory_kv(memory, rope) for layer in self.layers]

    def forward(self, x: Tensor, mask: Tensor, rope: Rope, memory_kv: list[tuple[Tensor, Tensor]]) -> Tensor:
        for layer, kv in zip(self.layers, memory_kv):
            x = layer(x, mask, rope, kv)
        return self.ln_f(x)
