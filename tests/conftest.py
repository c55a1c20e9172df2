"""Shared test fixtures: where the reference data beside the repository lives."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI does: small products, no BLAS threads
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MADP_SHARED", REPO.parent / "shared"))
VECTORS = SHARED / "vectors"
CITIES = SHARED / "cities"


@pytest.fixture(scope="session")
def vectors_dir() -> Path:
    if not VECTORS.is_dir():
        pytest.skip(f"reference vectors not found at {VECTORS} (set MADP_SHARED)")
    return VECTORS
