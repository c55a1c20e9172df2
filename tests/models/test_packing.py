"""The token packing of decentralized MADP (``madp.models.packing``): best-fit decreasing rows, and
every ego reading back its own token."""

from __future__ import annotations

import pytest
import torch

from madp.models import attention_mask
from madp.models.packing import pack_neighbourhoods, pack_rows


@pytest.mark.parametrize(
    "sizes, row_len, rows, offsets",
    [
        ([3, 2, 4, 1, 5], 5, [2, 2, 1, 1, 0], [0, 3, 0, 4, 0]),  # 5 alone; 4 + 1 and 3 + 2 fill their rows exactly
        ([5, 5], 5, [0, 1], [0, 0]),
        ([1, 1, 1], 8, [0, 0, 0], [0, 1, 2]),  # equal sizes keep their order
        ([2, 7, 1], 8, [1, 0, 0], [0, 0, 7]),
        ([4, 3, 3, 2], 6, [0, 1, 1, 0], [0, 0, 3, 4]),  # the 2 goes back to row 0 (next fit: a third row)
        ([3, 0, 2], 4, [0, 0, 1], [0, 3, 0]),  # an empty unit goes where it fits and takes no slot
    ],
)
def test_pack_rows_is_best_fit_decreasing(sizes, row_len, rows, offsets):
    """Guards ``pack_rows``: largest first, each into the fullest row it fits in, a row filled exactly
    is not split, offsets restart at 0 in every row."""
    row, off = pack_rows(torch.tensor(sizes, dtype=torch.long), row_len)
    assert row.tolist() == rows and off.tolist() == offsets
    assert row.dtype == torch.long and off.dtype == torch.long


def test_pack_rows_never_overlaps_and_needs_no_more_rows_than_next_fit():
    """On many random unit sizes (as decentralized MADP's, 1..13 in rows of 16 and 32): every item lies
    inside its row, no two items share a slot, and the rows are as few as next fit's or fewer."""
    g = torch.Generator().manual_seed(0)
    for trial in range(50):
        row_len = (16, 32)[trial % 2]
        sizes = torch.randint(1, 14, (int(torch.randint(1, 300, (1,), generator=g)),), generator=g)
        row, off = pack_rows(sizes, row_len)
        assert bool((off + sizes <= row_len).all())
        slots = torch.cat([r * row_len + o + torch.arange(s) for r, o, s in zip(row, off, sizes)])
        assert slots.unique().numel() == slots.numel() == int(sizes.sum())
        next_fit, fill = 1, 0
        for s in sizes.tolist():
            next_fit, fill = (next_fit + 1, s) if fill + s > row_len else (next_fit, fill + s)
        assert int(row.max()) + 1 <= next_fit


def test_pack_rows_of_no_items_is_two_empty_long_tensors():
    """pack_rows_16 / _19 / _22 / _25 (``dtype=torch.long`` dropped or None: ``torch.tensor([])`` is
    float32). ``(row [U], offset [U])`` are long for every U, U = 0 included, so they can index."""
    row, off = pack_rows(torch.zeros(0, dtype=torch.long), 4)
    assert row.dtype == torch.long and off.dtype == torch.long and row.shape == off.shape == (0,)
    assert torch.arange(3)[row].shape == (0,)


@pytest.mark.parametrize("dedupe", [True, False])
def test_every_ego_reads_back_its_own_token(gen, dedupe):
    """Packing a swarm tensor and reading each ego's own token returns it unchanged: every robot's
    neighbourhood holds it, whole, in one row (neighbourhoods of 2 swarms, some shared with dedupe)."""
    pos = torch.rand(2, 9, 2, generator=gen) * 600
    valid = torch.ones(2, 9, dtype=torch.bool)
    packed = pack_neighbourhoods(attention_mask(pos, 256.0, valid), valid, 4, dedupe)
    data = torch.randn(2, 9, 3, generator=gen)
    assert torch.equal(packed.own(packed.pack(data)), data.reshape(18, 3))
    assert packed.row_len >= 4 and int(packed.valid.sum()) == packed.unit.numel()
    units = packed.unit_rows.shape[0]
    assert units == 18 or (dedupe and units < 18)



def test_rows_are_a_multiple_of_the_row_tokens_and_carry_extra_dimensions(gen):
    """A neighbourhood longer than ``row_tokens`` makes the rows the next multiple of it (12 robots all in
    range, rows of 5 -> 15), not its own length; data with more dimensions per robot (the C copies of
    sampling, ``[B, N, C, A]``) packs and reads back whole."""
    pos = torch.rand(1, 12, 2, generator=gen) * 100
    valid = torch.ones(1, 12, dtype=torch.bool)
    packed = pack_neighbourhoods(attention_mask(pos, 256.0, valid), valid, 5, dedupe=False)
    assert packed.row_len == 15 and packed.rows == 12  # one neighbourhood of 12 per row
    data = torch.randn(1, 12, 4, 2, generator=gen)
    assert packed.pack(data).shape == (12, 15, 4, 2)
    assert torch.equal(packed.own(packed.pack(data)), data.reshape(12, 4, 2))
