import torch

from madp.models import LPAC, batch_graph, lpac_config
from .models_testutils import grid_positions, random_obs


def small_lpac(**kw):
    torch.manual_seed(0)
    return LPAC(lpac_config("cpu", gnn_hidden=32, **kw))


def test_forward_shapes_and_gradients(gen):
    model = small_lpac().train()
    obs = random_obs(3, 10, generator=gen)
    pos = torch.rand(3, 10, 2, generator=gen) * 1024
    out = model(obs, pos)
    assert out.shape == (3, 10, 2) and torch.isfinite(out).all()
    loss = model.loss(obs, pos, torch.randn(3, 10, 2, generator=gen))
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == []


def test_paper_architecture():
    model = LPAC(lpac_config("paper"))
    assert len(model.gnn) == 5 and all(c.K == 3 for c in model.gnn)
    assert model.gnn[0].in_channels == 34 and model.gnn[-1].out_channels == 256
    assert model.cnn.linear.in_features == 32 * 26 * 26
    assert model.out.in_features == 32 and model.out.out_features == 2


def test_permutation_equivariance(gen):
    model = small_lpac().eval()
    obs = random_obs(2, 12, generator=gen)
    pos = torch.rand(2, 12, 2, generator=gen) * 600
    out = model(obs, pos)
    perm = torch.randperm(12, generator=gen)
    assert torch.allclose(model(obs[:, perm], pos[:, perm]), out[:, perm], atol=1e-5)


def test_padding_and_mixed_team_sizes(gen):
    model = small_lpac().eval()
    obs = random_obs(2, 6, generator=gen)
    pos = torch.stack([grid_positions(6, 0.0, 500.0, gen) for _ in range(2)])
    valid = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    out = model(obs, pos, valid)
    assert torch.allclose(out[0], model(obs[:1], pos[:1])[0], atol=1e-5)
    assert torch.allclose(out[1, :4], model(obs[1:, :4], pos[1:, :4])[0], atol=1e-5)
    assert torch.equal(out[1, 4:], torch.zeros(2, 2))


def test_batch_graph_edges():
    pos = torch.tensor([[[0.0, 0.0], [100.0, 0.0], [400.0, 0.0]],
                        [[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]]])
    valid = torch.tensor([[True, True, True], [True, False, True]])
    node, edge_index, w = batch_graph(pos, 256.0, valid)
    assert node.tolist() == [[0, 1, 2], [3, -1, 4]]
    edges = sorted(map(tuple, edge_index.t().tolist()))
    assert edges == [(0, 1), (1, 0), (3, 4), (4, 3)]
    k = edge_index.t().tolist().index([0, 1])
    assert torch.isclose(w[k], torch.exp(torch.tensor(-(100.0 / 256.0) ** 2)))
