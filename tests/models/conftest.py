"""Fixtures for the model tests (CPU, tiny configs)."""

import pytest
import torch

from madp.models import MADP
from .models_testutils import tiny_madp_config


@pytest.fixture
def tiny_madp():
    torch.manual_seed(0)
    return MADP(tiny_madp_config()).eval()


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(1234)
