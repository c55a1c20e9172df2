"""What the robot-runtime tests share: a tiny MADP exported as ``madp export`` would write it."""

from __future__ import annotations

from pathlib import Path

import torch

from madp.export.onnx import export_graphs, runtime_spec, write_runtime
from madp.models import MADP
from madp.policies import SamplingSettings
from madp.sim import SimParams
from tests.models.models_testutils import tiny_madp_config


def export_tiny(out: Path, sampling: SamplingSettings | None = None) -> MADP:
    """A tiny random MADP (action statistics set) exported to ``out``; returns the model."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).eval()
    model.set_action_stats(torch.tensor([0.1, -0.2]), torch.tensor([2.0, 1.5]))
    out.mkdir(parents=True, exist_ok=True)
    write_runtime(out, runtime_spec(model, {}, "0" * 64, (sampling or SamplingSettings()).fitted(()), SimParams()), export_graphs(model, out))
    return model
