import numpy as np
import torch
from scipy.sparse.csgraph import connected_components

from madp.models import attention_mask, connected_components_mask, packed_neighbourhood_mask, radius_adjacency


def test_mask_is_distance_below_radius_including_self(gen):
    pos = torch.rand(3, 20, 2, generator=gen) * 1024
    mask = attention_mask(pos, 256.0)
    d = torch.cdist(pos.double(), pos.double())
    assert torch.equal(mask, d < 256.0)
    assert mask.diagonal(dim1=-2, dim2=-1).all()
    assert torch.equal(mask, mask.transpose(-1, -2))


def test_components_match_scipy(gen):
    pos = torch.rand(4, 30, 2, generator=gen) * 1024
    adj = radius_adjacency(pos, 150.0)
    same = connected_components_mask(adj)
    for b in range(pos.shape[0]):
        _, labels = connected_components(adj[b].numpy().astype(np.int8), directed=False)
        expect = labels[:, None] == labels[None, :]
        assert np.array_equal(same[b].numpy(), expect)


def test_padding_never_attends_nor_is_attended():
    pos = torch.tensor([[[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [5.0, 5.0]]])
    valid = torch.tensor([[True, True, False, True]])
    mask = attention_mask(pos, 256.0, valid)
    assert not mask[0, 2, [0, 1, 3]].any()   # padding attends only to itself (finite softmax)
    assert mask[0, 2, 2]
    assert not mask[0, [0, 1, 3], 2].any()   # nobody attends to padding
    assert mask[0][np.ix_([0, 1, 3], [0, 1, 3])].all()


def test_packed_neighbourhood_mask_is_each_neighbourhoods_own_mask():
    """Packing two neighbourhoods side by side must not let them see each other (fails if the
    group term is dropped) and must equal attention_mask of each neighbourhood alone."""
    pos = torch.tensor([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [240.0, 0.0]])
    hoods = [[0, 1, 2], [1, 2, 3]]  # the rows of robots 1 and 2 for radius 150
    members = [j for h in hoods for j in h]
    group = torch.tensor([[g for g, h in enumerate(hoods) for _ in h] + [-1]])
    pos_p = torch.cat([pos[members], torch.zeros(1, 2)])[None]
    valid = group >= 0
    packed = packed_neighbourhood_mask(pos_p, 150.0, valid, group)[0]
    for g, h in enumerate(hoods):
        sl = slice(3 * g, 3 * g + 3)
        assert torch.equal(packed[sl, sl], attention_mask(pos[h][None], 150.0)[0])
    assert not packed[:3, 3:].any() and not packed[3:6, :3].any()
    assert packed[6].tolist() == [False] * 6 + [True]
