"""The teacher of a distillation (``madp train --distill``; :mod:`madp.training.config`): a frozen MADP
policy whose DPM-Solver++(2M) samples a one-step student learns to predict from the same noise."""

from __future__ import annotations

from pathlib import Path

import torch

from madp.io.checksum import sha256_file
from madp.errors import InputError
from madp.models import MADP
from madp.models.samplers import DEFAULT_SAMPLER


def load_teacher(path: Path, student: MADP, steps: int, device: torch.device) -> tuple[MADP, dict]:
    """The frozen teacher (eval mode, on ``device``) for ``student`` and its record for the checkpoint
    metadata (path, sha256, sampler, S = ``steps``). One-line error unless it is an MADP policy of the
    student's config that predicts the noise."""
    from madp.policies.checkpoint import load_policy

    model, meta = load_policy(path, device)
    want = {**student.config.to_dict(), "prediction": "epsilon"}
    if meta["kind"] != "madp" or meta["config"] != want:
        raise InputError(f"{path}: distill needs an MADP checkpoint of the {student.config.preset} preset that predicts "
                         f"the noise (it is a {meta['kind']} with another config)")
    model.requires_grad_(False)
    return model.eval(), {"path": str(path), "sha256": sha256_file(path), "sampler": DEFAULT_SAMPLER,
                          "sampling_steps": steps}


def teacher_action_stats(teacher: MADP) -> dict:
    """The action statistics a student keeps (its teacher's), as the checkpoint metadata records them."""
    return {"mean": teacher.action_mean.tolist(), "std": teacher.action_std.tolist(), "source": "the teacher"}
