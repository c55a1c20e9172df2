"""Communication graph and attention masks of a batch of swarms.

Conventions: ``pos_m [B, N, 2]`` positions in metres, ``valid [B, N]`` bool marks real robots
(False = padding, so batches can mix teams of different sizes). A boolean mask is True where
attention is allowed (``mask[b, i, j]``: robot i may attend to robot j), which is the convention of
``torch.nn.functional.scaled_dot_product_attention``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "closer_than_squared",
    "pairwise_offsets",
    "radius_adjacency",
    "connected_components_mask",
    "attention_mask",
    "packed_neighbourhood_mask",
]


def _valid_or_default(pos_m: Tensor, valid: Tensor | None) -> Tensor:
    if valid is None:
        return torch.ones(pos_m.shape[:-1], dtype=torch.bool, device=pos_m.device)
    return valid.to(dtype=torch.bool, device=pos_m.device)


def pairwise_offsets(pos_m: Tensor) -> Tensor:
    """``pos_m [B, N, 2]`` -> ``offsets [B, N, N, 2]`` with ``offsets[b, i, j] = x_j - x_i``.

    Computed as explicit differences (not ``cdist``'s matmul trick) so the result is exactly
    antisymmetric and exactly shift invariant whenever the shift itself is exact.
    """
    return pos_m.unsqueeze(-3) - pos_m.unsqueeze(-2)


def closer_than_squared(offsets: Tensor, radius_m: float) -> Tensor:
    """``[...]`` bool: ``d·d < r·r`` for each offset ``d`` of ``offsets [..., 2]``, in the offsets' precision
    (torch compares a float32 sum with r·r rounded to float32): the torch twin of
    :func:`madp.sim.rules.closer_than_squared`, the rule the robot runtime computes in numpy."""
    return offsets.square().sum(-1) < radius_m * radius_m


def radius_adjacency(pos_m: Tensor, radius_m: float, valid: Tensor | None = None,
                     self_loops: bool = True) -> Tensor:
    """Communication graph: ``adj [B, N, N]`` bool, True where ``||x_i - x_j|| < radius_m``.

    Padding robots (``valid`` False) have no edges at all (not even a self loop); valid robots
    have a self loop iff ``self_loops``.
    """
    valid = _valid_or_default(pos_m, valid)
    adj = closer_than_squared(pairwise_offsets(pos_m), radius_m)
    adj = adj & valid.unsqueeze(-1) & valid.unsqueeze(-2)
    n = pos_m.shape[-2]
    eye = torch.eye(n, dtype=torch.bool, device=pos_m.device)
    if self_loops:
        adj = adj | (eye & valid.unsqueeze(-1))
    else:
        adj = adj & ~eye
    return adj


def connected_components_mask(adj: Tensor) -> Tensor:
    """``adj [B, N, N]`` bool (symmetric) -> ``same [B, N, N]`` bool, True iff i and j are in the same
    connected component.

    Transitive closure by repeated squaring of the reflexive adjacency: after t squarings R holds
    all pairs joined by a walk of length <= 2^t, so ceil(log2 N) boolean matmuls suffice
    (a fixed count: no data-dependent loop, no host sync). Isolated nodes are their own component.
    """
    n = adj.shape[-1]
    eye = torch.eye(n, dtype=torch.bool, device=adj.device)
    reach = adj | eye
    # float32 matmul counts walks; any count >= 1 means reachable. Counts are at most N, exact in fp32.
    r = reach.float()
    for _ in range(max(1, math.ceil(math.log2(max(n, 2))))):
        r = (torch.matmul(r, r) > 0).float()
    return r > 0


def attention_mask(pos_m: Tensor, radius_m: float, valid: Tensor | None = None, links: Tensor | None = None) -> Tensor:
    """MADP attention mask ``M_att = M_W AND M_C`` (paper §III-B): ``mask [B, N, N]`` bool.

    * ``M_W[i, j]``: ``||x_i - x_j|| < radius_m`` (includes i = j), and, with ``links [B, N, N]`` bool
      (symmetric: which robots hear each other, e.g. training's communication dropout,
      :mod:`madp.training.comm_dropout`), ``links[i, j]``; a robot always hears itself.
    * ``M_C[i, j]``: i and j lie in the same connected component of the communication graph
      (edges at distance < radius_m, and only over the links heard). With edges defined by the same
      radius and links, M_W already implies M_C; the conjunction is kept as the paper defines it
      (and stays right if the two radii are ever made to differ).
    * Padding robots never attend and are never attended to. To keep the softmax finite their
      row holds only the diagonal (a padding token attends to itself); their outputs are
      meaningless and are masked out by the callers.
    """
    valid = _valid_or_default(pos_m, valid)
    eye = torch.eye(pos_m.shape[-2], dtype=torch.bool, device=pos_m.device)
    window = radius_adjacency(pos_m, radius_m, valid, self_loops=True)
    if links is not None:
        window = window & (links.to(device=pos_m.device, dtype=torch.bool) | eye)
    comm = window  # the communication graph: the attention window's radius, the links heard
    component = connected_components_mask(comm)
    mask = window & component
    return mask | (eye & ~valid.unsqueeze(-1))


def packed_neighbourhood_mask(pos_m: Tensor, radius_m: float, valid: Tensor, group: Tensor) -> Tensor:
    """Attention mask of neighbourhoods packed side by side: ``[B, T, T]`` bool.

    ``pos_m [B, T, 2]`` the positions of the packed tokens, ``valid [B, T]``, ``group [B, T]`` long: the
    neighbourhood each token belongs to. Token a may attend to token c iff both are in the same
    neighbourhood and ``||x_a - x_c|| < radius_m`` -- the :func:`attention_mask` of that neighbourhood
    alone, because a neighbourhood is one robot's attention row: every member lies within the
    radius_m of that robot, so the neighbourhood is one connected component and the component term is
    all-true. Padding tokens attend only to themselves.
    """
    same = group.unsqueeze(-1) == group.unsqueeze(-2)
    adj = radius_adjacency(pos_m, radius_m, valid, self_loops=True) & same
    eye = torch.eye(pos_m.shape[-2], dtype=torch.bool, device=pos_m.device)
    return adj | (eye & ~valid.unsqueeze(-1))
