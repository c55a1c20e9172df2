"""Attention-mask contract details: the default self loops of the communication graph, ``valid``
given as a 0/1 tensor of another dtype, and padding tokens that share a neighbourhood id.

Written against the mutants mutmut left alive in ``madp/models/attention_mask.py`` (issue 17); each
test names the mutants it kills. The distance rule itself (< r_c) is pinned in
``test_attention_mask.py`` and ``test_comm_radius.py``.
"""

import torch

from madp.models import attention_mask, packed_neighbourhood_mask, radius_adjacency

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
