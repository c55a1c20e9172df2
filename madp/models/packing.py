"""Token packing of decentralized MADP: every robot's neighbourhood laid out whole, side by side, in
rows of a fixed number of tokens, so all neighbourhoods of all swarms run through the transformer as
one batch (:meth:`madp.models.MADP.sample_decentralized`).

A *unit* is one neighbourhood: an ego robot with the robots in its row of the attention mask (with
``dedupe``, egos whose neighbourhoods are the same set of robots share one unit). Token t is robot
``robot[t]`` as a member of unit ``unit[t]``; tokens are grouped by unit, robots ascending. Units are
packed best-fit decreasing into rows of ``row_len`` tokens (:func:`pack_rows`; a row may mix swarms:
units never see each other, :func:`madp.models.attention_mask.packed_neighbourhood_mask`). Nothing loops
over robots.

Shapes: ``mask [B, N, N]`` and ``valid [B, N]`` bool; packed tensors ``[R, row_len, ...]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["PackedNeighbourhoods", "pack_neighbourhoods", "pack_rows"]


def pack_rows(sizes: Tensor, row_len: int) -> tuple[Tensor, Tensor]:
    """Best-fit decreasing packing of items of ``sizes [U]`` (each <= row_len) into rows of ``row_len``:
    the items, largest first (equal sizes in their given order), each go into the fullest row they fit
    in, else into a new row -> ``(row [U], offset [U])`` long, rows numbered as they are opened, each
    item after those placed in its row before it. Rows come out nearly full (the padding the
    transformer computes on is what they leave free). One pass over U python ints, with the rows kept
    by free slots (U <= robots in the batch, once per control step)."""
    sizes_l = sizes.tolist()
    by_free: list[list[int]] = [[] for _ in range(row_len + 1)]  # by_free[f]: the rows with f free slots
    fill: list[int] = []  # tokens in each row
    row, off = [0] * len(sizes_l), [0] * len(sizes_l)
    for u in sorted(range(len(sizes_l)), key=lambda i: -sizes_l[i]):
        s = sizes_l[u]
        r = next((by_free[f].pop() for f in range(s, row_len + 1) if by_free[f]), None)
        if r is None:
            r = len(fill)
            fill.append(0)
        row[u], off[u] = r, fill[r]
        fill[r] += s
        by_free[row_len - fill[r]].append(r)
    dev = sizes.device
    return torch.tensor(row, dtype=torch.long, device=dev), torch.tensor(off, dtype=torch.long, device=dev)


@dataclass
class PackedNeighbourhoods:
    """Where every token of every neighbourhood sits: token t is robot ``robot[t]`` of swarm ``batch[t]``,
    a member of unit ``unit[t]``, at slot ``slot[t]`` of row ``row[t]``. ``valid [R, row_len]`` marks
    real tokens, ``group [R, row_len]`` their unit (-1 at padding); ``unit_rows [U, N]`` the members of
    each unit, ``unit_of_ego [B * N]`` each ego's unit."""

    row_len: int
    rows: int
    batch: Tensor
    robot: Tensor
    unit: Tensor
    row: Tensor
    slot: Tensor
    unit_rows: Tensor
    unit_of_ego: Tensor
    valid: Tensor
    group: Tensor
    unit_ego: Tensor

    def pack(self, t: Tensor) -> Tensor:
        """``[B, N, *F] -> [R, row_len, *F]``: every token's copy of its robot's data (0 at padding)."""
        out = t.new_zeros(self.rows, self.row_len, *t.shape[2:])
        out[self.row, self.slot] = t[self.batch, self.robot]
        return out

    def pack_view(self, t: Tensor) -> Tensor:
        """``[B, N, N, *F] -> [R, row_len, *F]``: every token's data as its unit's ego holds it,
        ``t[b, i, j]`` being what ego i of swarm b holds of robot j (0 at padding)."""
        n = t.shape[1]
        out = t.new_zeros(self.rows, self.row_len, *t.shape[3:])
        out[self.row, self.slot] = t[self.batch, self.unit_ego[self.unit] % n, self.robot]
        return out

    def own(self, x: Tensor) -> Tensor:
        """``[R, row_len, *F] -> [B * N, *F]``: each ego's own token, the token of (its unit, itself)
        (0 for every ego when no robot is valid)."""
        dev = x.device
        b_n, n = self.unit_of_ego.numel(), self.unit_rows.shape[1]
        tok_of = torch.zeros(self.unit_rows.shape, dtype=torch.long, device=dev)
        tok_of[self.unit, self.robot] = torch.arange(self.unit.numel(), device=dev)
        ego_tok = tok_of[self.unit_of_ego, torch.arange(n, device=dev).repeat(b_n // max(n, 1))]
        if self.unit.numel():
            return x[self.row[ego_tok], self.slot[ego_tok]]
        return x.new_zeros(b_n, *x.shape[2:])  # no valid robot at all


def pack_neighbourhoods(mask: Tensor, valid: Tensor, row_tokens: int, dedupe: bool,
                        key: Tensor | None = None) -> PackedNeighbourhoods:
    """The packed layout of the neighbourhoods of ``mask [B, N, N]`` among the ``valid [B, N]`` robots
    (padding egos have an empty one), in rows of ``row_tokens`` tokens, or of the smallest multiple of it
    that holds the largest neighbourhood (MADP's is 16: CPU attention is several times slower on rows
    whose length is not a multiple of 16). ``dedupe``: egos with the same neighbourhood share one unit; with ``key [B, N, N]``
    long (> 0 at members, 0 elsewhere), egos share one only where their rows of ``key`` are equal
    (what each ego holds of each member is then the same: :meth:`PackedNeighbourhoods.pack_view`)."""
    b, n = valid.shape
    dev = mask.device
    # Neighbourhood ("unit") membership per ego; padding egos have an empty one.
    rows = (mask & valid.unsqueeze(-1)).reshape(b * n, n)
    ego_batch = torch.arange(b, device=dev).repeat_interleave(n)
    if dedupe:
        ident = rows.long() if key is None else torch.where(rows, key.reshape(b * n, n), 0)
        uniq, unit_of_ego = torch.unique(torch.cat([ego_batch.unsqueeze(1), ident], dim=1), dim=0,
                                         return_inverse=True)  # sorted: swarm first
        unit_batch, unit_rows = uniq[:, 0], uniq[:, 1:] > 0
        unit_ego = torch.full((len(uniq),), b * n, dtype=torch.long, device=dev)
        unit_ego.scatter_reduce_(0, unit_of_ego, torch.arange(b * n, device=dev), "amin")
    else:
        unit_of_ego = torch.arange(b * n, device=dev)
        unit_batch, unit_rows, unit_ego = ego_batch, rows, unit_of_ego
    # Pack: token t is robot tok_robot[t] as a member of unit tok_unit[t] (tokens grouped by unit,
    # robots ascending). Units are laid out whole, side by side, in rows of row_len tokens
    # (best-fit decreasing); a row may mix swarms since units never see each other.
    tok_unit, tok_robot = unit_rows.nonzero(as_tuple=True)
    tok_batch = unit_batch[tok_unit]
    sizes = unit_rows.sum(1)
    row_tokens = max(row_tokens, 1)
    row_len = row_tokens * max(1, -(-(int(sizes.max()) if sizes.numel() else 1) // row_tokens))
    row_of_unit, off_of_unit = pack_rows(sizes, row_len)
    first_tok = sizes.cumsum(0) - sizes
    tok_row = row_of_unit[tok_unit]
    tok_slot = off_of_unit[tok_unit] + torch.arange(tok_unit.numel(), device=dev) - first_tok[tok_unit]
    rows_n = int(row_of_unit.max()) + 1 if row_of_unit.numel() else 1

    valid_p = torch.zeros(rows_n, row_len, dtype=torch.bool, device=dev)
    valid_p[tok_row, tok_slot] = True
    group_p = torch.full((rows_n, row_len), -1, dtype=torch.long, device=dev)
    group_p[tok_row, tok_slot] = tok_unit
    return PackedNeighbourhoods(row_len, rows_n, tok_batch, tok_robot, tok_unit, tok_row, tok_slot, unit_rows,
                                unit_of_ego, valid_p, group_p, unit_ego)
