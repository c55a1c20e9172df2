"""The attention masks (``madp.models.attention_mask``): distance below r_c and the same communication
component, checked against scipy; and their contract details: the default self loops of the
communication graph, ``valid`` given as a 0/1 tensor of another dtype, and padding tokens that share a
neighbourhood id (written against the mutants mutmut left alive in the module; each such test
names the mutants it kills). The distance rule itself (< r_c) is pinned here and in
``test_comm_radius.py``."""

from __future__ import annotations

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


# --- contract details (mutation survivors) --------------------------------------------------------

POS = torch.tensor([[[0.0, 0.0], [100.0, 0.0], [400.0, 0.0], [130.0, 40.0]]])


# distances < 150: 0-1, 1-3 (and 0-3? |(130, 40)| = 136 < 150: yes); robot 2 is alone
WITHIN_150 = [[1, 1, 0, 1], [1, 1, 0, 1], [0, 0, 1, 0], [1, 1, 0, 1]]


def test_radius_adjacency_has_self_loops_by_default():
    """``self_loops`` defaults to True: every valid robot is its own neighbour, even an isolated one.
    Guards radius_adjacency__mutmut_1 (default False)."""
    adj = radius_adjacency(POS, 150.0)
    assert adj.dtype == torch.bool
    assert adj[0].int().tolist() == WITHIN_150
    assert not radius_adjacency(POS, 150.0, self_loops=False)[0].diagonal().any()


def test_valid_of_any_dtype_is_read_as_bool():
    """``valid`` given as 0/1 integers (long or uint8) is taken as a bool mask: the same bool masks
    as with a bool ``valid``. Guards _valid_or_default__mutmut_10/_12 (the dtype conversion dropped:
    integer masks come back, and ``~valid`` of an integer is -1/-2, not a logical not)."""
    flags = [1, 1, 0, 1]
    expect = attention_mask(POS, 150.0, torch.tensor([flags], dtype=torch.bool))
    assert expect[0].int().tolist() == [[1, 1, 0, 1], [1, 1, 0, 1], [0, 0, 1, 0], [1, 1, 0, 1]]
    for dtype in (torch.long, torch.uint8):
        valid = torch.tensor([flags], dtype=dtype)
        mask = attention_mask(POS, 150.0, valid)
        assert mask.dtype == torch.bool and torch.equal(mask, expect)
        adj = radius_adjacency(POS, 150.0, valid)
        assert adj.dtype == torch.bool and adj[0, 2].tolist() == [False] * 4


def test_padding_tokens_in_one_group_do_not_attend_each_other():
    """The decentralized sampler pads every packed row with tokens of group -1 at the origin; those
    share a group and a position, yet each attends only to itself. Guards
    packed_neighbourhood_mask__mutmut_13/_17 (``valid`` not passed to the radius graph: the
    padding tokens become each other's neighbours)."""
    pos = torch.tensor([[[5.0, 5.0], [50.0, 5.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]])
    group = torch.tensor([[0, 0, -1, -1, -1]])
    mask = packed_neighbourhood_mask(pos, 150.0, group >= 0, group)[0]
    assert mask.int().tolist() == [[1, 1, 0, 0, 0], [1, 1, 0, 0, 0], [0, 0, 1, 0, 0], [0, 0, 0, 1, 0],
                                   [0, 0, 0, 0, 1]]
