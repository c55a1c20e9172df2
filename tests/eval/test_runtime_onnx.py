"""madp eval --runtime onnx: MADP robot by robot through the exported files, paired with the PyTorch run
on the same environments and noise (a short suite: the final costs agree to float rounding)."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest

from madp.errors import SettingError
from madp.eval.runner import EvalConfig, run_suite


def test_onnx_runtime_suite_pairs_with_torch(tmp_path):
    final = {}
    for runtime in ("torch", "onnx"):
        cfg = EvalConfig(suite="uniform", out=str(tmp_path / runtime), num_envs=2, steps=3, controllers=("madp",),
                         workers=1, runtime=runtime)
        run_suite(cfg, "uniform", progress=False)
        final[runtime] = pq.read_table(tmp_path / runtime / "uniform" / "results.parquet").to_pandas()
    a, b = (final[r].sort_values("env")["final_cost"].to_numpy() for r in ("torch", "onnx"))
    assert len(a) == 2 and np.abs(a - b).max() < 1e-6


def test_an_unknown_runtime_is_refused():
    with pytest.raises(SettingError):
        EvalConfig(suite="uniform", runtime="tensorrt")
