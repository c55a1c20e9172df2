"""TorchRL: the environments guide's PettingZooWrapper lines run as they stand, and TorchRL's own check_env_specs passes."""

import re
from pathlib import Path

import pytest
import torch
from torchrl.envs import PettingZooWrapper, check_env_specs

from madp.envs import coverage_v0
from madp.sim import SimParams

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "environments.md"
# TorchRL warns that it tests PettingZoo 1.24.3 only; this file is what tests it on madp's version
pytestmark = pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning")


def readme_snippet() -> str:
    """The guide's Python block that wraps coverage_v0 in TorchRL (exactly one)."""
    blocks = [b for b in re.findall(r"```python\n(.*?)```", GUIDE.read_text(), re.S) if "PettingZooWrapper" in b]
    assert len(blocks) == 1, f"expected one TorchRL snippet in the guide, found {len(blocks)}"
    return blocks[0]


def test_readme_snippet(capsys):
    ns: dict = {}
    exec(compile(readme_snippet(), "docs/guides/environments.md (TorchRL)", "exec"), ns)  # runs check_env_specs itself
    env, rollout = ns["env"], ns["rollout"]
    assert rollout.batch_size == torch.Size([10])
    obs = rollout["robot", "observation"]
    assert obs["maps"].shape == (10, 32, 4, 32, 32) and obs["maps"].dtype == torch.float32
    assert obs["neighbours"].shape == (10, 32, 31, 2) and obs["neighbour_mask"].dtype == torch.int8
    assert rollout["robot", "action"].shape == (10, 32, 2)
    # truncated after max_steps, never terminated; one shared reward that sums to 1 − J(T)/J(0)
    done = rollout["next", "robot", "truncated"][..., 0]
    assert done[-1].all() and not done[:-1].any() and not rollout["next", "robot", "terminated"].any()
    reward = rollout["next", "robot", "reward"][..., 0].double()
    assert (reward == reward[:, :1]).all()
    final = rollout["next", "robot", "info", "normalized_cost"][-1, 0].item()
    assert reward[:, 0].sum().item() == pytest.approx(1 - final, abs=1e-5)
    assert float(capsys.readouterr().out.splitlines()[-1]) == final
    # every step's observation in the spec (check_env_specs tests the last step's only)
    spec = env.full_observation_spec["robot"]
    for t in range(10):
        assert spec.is_in(rollout["next", "robot"][t].select(*spec.keys(True, True)))


def test_check_env_specs_small_world_both_done_modes():
    """A scenario of another size (N = 4), rollouts that stop at done and that reset through it."""
    params = SimParams(world_size=128, local_map_size=64, sensor_size=16, num_robots=4, num_features=3,
                       sigma_range_m=(10.0, 20.0), comm_radius_m=48.0)
    env = PettingZooWrapper(coverage_v0.parallel_env(params=params, max_steps=2, seed=1))
    check_env_specs(env, seed=0, break_when_any_done="both")
    assert env.full_action_spec["robot", "action"].shape == (4, 2)
    assert env.full_observation_spec["robot", "observation", "neighbours"].shape == (4, 3, 2)
