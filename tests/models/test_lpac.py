import pytest
import torch

from madp.models import lpac_config
from madp.models.lpac import LPAC, batch_graph
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


@pytest.mark.parametrize("edge_weight", ["binary", "gaussian"])
def test_sparse_graph_path_equals_tagconv_on_edge_index_and_the_dense_formula(gen, edge_weight):
    """LPAC-K3 runs its TAGConv layers on a CSR adjacency built by ``sparse_adjacency``. The same
    graph given to torch_geometric's ``TAGConv`` as ``edge_index`` + weights, and the layer written
    out densely (``sum_k (D^-1/2 A D^-1/2)^k X W_k + b``, D the weighted degree, no self loops), must
    give the same actions. Two swarms, padding, an isolated robot. Fails if the CSR rows/columns or
    weights are misaligned with the edges, or the graph differs from ``batch_graph``'s."""
    model = small_lpac(edge_weight=edge_weight).eval()
    obs = random_obs(2, 9, generator=gen)
    pos = torch.rand(2, 9, 2, generator=gen) * 600
    pos[0, -1] = torch.tensor([1000.0, 1000.0])  # isolated: degree 0
    valid = torch.ones(2, 9, dtype=torch.bool)
    valid[1, -2:] = False
    with torch.no_grad():
        got = model(obs, pos, valid)
        node, edge_index, weight = batch_graph(pos, model.config.comm_radius_m, valid, edge_weight)
        assert edge_index.shape[1] > 10  # a real graph
        h0 = torch.cat([model.cnn(obs[valid]), model.normalize_positions(pos[valid])], dim=-1)
        # (1) torch_geometric's own edge_index path
        h = h0
        for conv in model.gnn:
            h = torch.relu(conv(h, edge_index, weight))
        ref_pyg = model.out(model.mlp(h))
        # (2) the dense formula
        r = h0.shape[0]
        adj = torch.zeros(r, r)
        adj[edge_index[1], edge_index[0]] = weight
        deg = adj.sum(1)
        dinv = torch.where(deg > 0, deg.rsqrt(), torch.zeros_like(deg))
        norm = dinv[:, None] * adj * dinv[None, :]
        h = h0
        for conv in model.gnn:
            out, x = conv.lins[0](h), h
            for lin in conv.lins[1:]:
                x = norm @ x
                out = out + lin(x)
            h = torch.relu(out + conv.bias)
        ref_dense = model.out(model.mlp(h))
    assert torch.allclose(got[valid], ref_pyg, atol=1e-5)
    assert torch.allclose(got[valid], ref_dense, atol=1e-5)
    assert torch.equal(got[~valid], torch.zeros(2, 2))
