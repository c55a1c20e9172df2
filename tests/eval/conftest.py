import pytest
import torch

from madp.models import MADP, lpac_config, madp_config
from madp.models.lpac import LPAC
from madp.training.checkpoint import save_policy

META = {"action_stats": {"count": 1, "mean": [0.0, 0.0], "std": [2.0, 2.0]}}


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """Untrained but well-formed policy files (the plumbing, not the skill, is under test here)."""
    d = tmp_path_factory.mktemp("ckpt")
    torch.manual_seed(0)
    for kind, model in (("madp", MADP(madp_config("cpu"))), ("lpac", LPAC(lpac_config("cpu")))):
        model.set_action_stats(torch.zeros(2), torch.full((2,), 2.0))
        save_policy(d / f"{kind}.safetensors", model, kind, META)
    return d
