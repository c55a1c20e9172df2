import torch

from madp.models import RotaryEmbedding2D, apply_rope


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
