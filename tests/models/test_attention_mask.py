import numpy as np
import torch
from scipy.sparse.csgraph import connected_components

from madp.models import attention_mask, connected_components_mask, neighbourhood_index, radius_adjacency


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


def test_neighbourhood_index_lists_members_in_order():
    pos = torch.tensor([[[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [900.0, 900.0]]])
    rows = attention_mask(pos, 150.0)[0]
    idx, sub_valid = neighbourhood_index(rows)
    assert idx.shape == (4, 3)
    assert idx[1].tolist() == [0, 1, 2]
    assert idx[0, :2].tolist() == [0, 1] and idx[3, :1].tolist() == [3]
    assert sub_valid.tolist() == [[True, True, False], [True, True, True], [True, True, False],
                                  [True, False, False]]
