import torch

from madp.models import RotaryEmbedding2D, apply_rope
from madp.models.transformer import SpatialTransformerDecoder, SpatialTransformerEncoder, rotate_heads


def test_rope_frequencies_follow_paper():
    rope = RotaryEmbedding2D(head_dim=32, tau=1024.0)
    w = rope.frequencies()
    i = torch.arange(1, 9, dtype=torch.float64)
    assert torch.allclose(w, 2 * torch.pi * 1024.0 ** (-4 * i / 32))
    assert torch.isclose(2 * torch.pi / w[-1], torch.tensor(1024.0, dtype=torch.float64))  # slowest period = tau


def test_rope_scores_depend_on_relative_position_only(gen):
    d = 16
    rope = RotaryEmbedding2D(d, 1024.0)
    q = torch.randn(1, 1, 2, d, generator=gen, dtype=torch.float64)
    k = torch.randn(1, 1, 2, d, generator=gen, dtype=torch.float64)
    pos = torch.tensor([[[100.0, 300.0], [250.0, 120.0]]], dtype=torch.float64)

    def score(p):
        cs = rope(p, torch.float64)
        return (apply_rope(q, cs)[..., 0, :] * apply_rope(k, cs)[..., 1, :]).sum()

    s0 = score(pos)
    s1 = score(pos + torch.tensor([417.25, -93.5], dtype=torch.float64))
    assert torch.allclose(s0, s1, atol=1e-10)
    assert not torch.allclose(s0, score(pos * torch.tensor([1.0, 1.5], dtype=torch.float64)))
    # rotation preserves norms
    cs = rope(pos, torch.float64)
    assert torch.allclose(apply_rope(q, cs).norm(dim=-1), q.norm(dim=-1))


def test_rope_first_half_uses_x_second_half_uses_y():
    d = 8
    rope = RotaryEmbedding2D(d, 1024.0)
    cos, sin = rope(torch.tensor([[[0.0, 50.0]]]))  # x = 0: the x half is the identity
    assert torch.allclose(cos[..., : d // 4], torch.ones(d // 4))
    assert torch.allclose(sin[..., : d // 4], torch.zeros(d // 4))
    assert not torch.allclose(sin[..., d // 4:], torch.zeros(d // 4))


def test_rotations_are_the_cos_sin_tables_as_one_complex_table(gen):
    """``rotations`` holds exactly ``forward``'s cos and sin (each rounded to the dtype from float64
    angles), laid out per token ``[B, N, 1, D/2]``."""
    rope = RotaryEmbedding2D(16, 1024.0)
    pos = torch.rand(2, 5, 2, generator=gen) * 900
    for dtype in (torch.float32, torch.float64):
        cos, sin = rope(pos, dtype)
        rot = rope.rotations(pos, dtype)
        assert rot.shape == (2, 5, 1, 8) and rot.real.dtype == dtype
        assert torch.equal(rot.real.squeeze(2), cos.squeeze(1)) and torch.equal(rot.imag.squeeze(2), sin.squeeze(1))


def test_rotate_heads_is_apply_rope_on_every_head(gen):
    """The sampling path's complex multiply in token layout (queries and keys of 4 heads side by side, a
    slice of a wider projection) rotates exactly as ``apply_rope`` does per head."""
    rope = RotaryEmbedding2D(16, 1024.0)
    pos = torch.rand(3, 7, 2, generator=gen) * 900
    qkv = torch.randn(3, 7, 3 * 64, generator=gen)
    got = rotate_heads(qkv[..., :128], rope.rotations(pos))  # [B, N, 2 * 4 * 16]
    heads = qkv[..., :128].unflatten(-1, (8, 16)).transpose(1, 2)  # [B, 8, N, 16]
    want = apply_rope(heads, rope(pos)).transpose(1, 2).flatten(-2)
    assert got.is_contiguous() and torch.allclose(got, want, atol=1e-6, rtol=0)


def test_layers_give_the_same_output_with_either_rope_form_and_bf16_linears_stay_close(gen):
    """An encoder and a decoder layer with RoPE: the complex table and ``(cos, sin)`` give the same
    output (float32); with their linear layers in bfloat16 (the stream float32) the output stays
    float32 and within bfloat16 rounding of it, but is not the float32 output."""
    torch.manual_seed(0)
    enc = SpatialTransformerEncoder(64, 4, 2, rope_layers=1).eval()
    dec = SpatialTransformerDecoder(64, 4, 2, rope_layers=1).eval()
    rope = RotaryEmbedding2D(16, 1024.0)
    pos = torch.rand(2, 6, 2, generator=gen) * 300
    x, h = torch.randn(2, 6, 64, generator=gen), torch.randn(2, 6, 64, generator=gen)
    mask = torch.rand(2, 6, 6, generator=gen) < 0.7
    mask |= torch.eye(6, dtype=torch.bool)

    def run(r):
        memory = enc(x, mask, r)
        return dec(h, mask, r, dec.memory_kv(memory, r))

    with torch.no_grad():
        ref = run(rope(pos))
        assert torch.allclose(run(rope.rotations(pos)), ref, atol=1e-5, rtol=0)
        for layer in (*enc.modules(), *dec.modules()):
            if isinstance(layer, torch.nn.Linear):
                layer.to(torch.bfloat16)
        low = run(rope.rotations(pos))
    assert low.dtype == torch.float32
    err = (low - ref).abs().max()
    assert 0 < err < 0.05, err  # measured 0.007 (the outputs are layer-normed: ~1)
