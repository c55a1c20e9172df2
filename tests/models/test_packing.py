"""The token packing of decentralized MADP (``madp.models.packing``): next-fit rows, and every ego
reading back its own token."""

from __future__ import annotations

import pytest
import torch

from madp.models import attention_mask
from madp.models.packing import pack_neighbourhoods, pack_rows


@pytest.mark.parametrize(
    "sizes, row_len, rows, offsets",
    [
        ([3, 2, 4, 1, 5], 5, [0, 0, 1, 1, 2], [0, 3, 0, 4, 0]),  # exact fill (3 + 2 = 5) stays in the row
        ([5, 5], 5, [0, 1], [0, 0]),
        ([1, 1, 1], 8, [0, 0, 0], [0, 1, 2]),
        ([2, 7, 1], 8, [0, 1, 1], [0, 0, 7]),
    ],
)
def test_pack_rows_is_next_fit(sizes, row_len, rows, offsets):
    """Guards ``pack_rows``: next fit, a row filled exactly is not split, offsets restart at 0."""
    row, off = pack_rows(torch.tensor(sizes), row_len)
    assert row.tolist() == rows and off.tolist() == offsets
    assert row.dtype == torch.long and off.dtype == torch.long


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

