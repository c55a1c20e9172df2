"""Fixtures for the model tests (CPU, tiny configs)."""

import pytest
import torch

from madp.models import MADP
from tests.conftest import one_torch_thread
from .models_testutils import tiny_madp_config


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """The tiny models gain nothing from intra-op threads, and with the 2 cores shared by other jobs
    OpenMP's thread hand-offs can make small ops 50x slower; one thread keeps the tests fast."""
    with one_torch_thread():
        yield


@pytest.fixture
def tiny_madp():
    torch.manual_seed(0)
    return MADP(tiny_madp_config()).eval()


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(1234)
