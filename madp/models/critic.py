"""The critic of MADP's joint copies: a small network that predicts, from one robot's window, the mass
and the centroid of its true Voronoi cell, the two quantities a copy's change of the coverage cost J
depends on to second order (:mod:`madp.robot.critic`, which turns them into each copy's score).

Inputs ``windows [R, 5, H, H]`` and ``neighbours [R, MAX_NEIGHBOURS, 3]``
(:func:`madp.robot.critic.critic_inputs`; the neighbours through a small set network, summed and
maxed over them); output the cell's mass in units of
the training data's mean mass (``[R]``, ≥ 0) and its centroid's offset from the robot in units of
:data:`madp.robot.critic.OFFSET_SCALE_M` (``[R, 2]``, the window's axes). The offset is a spatial
softmax over the coarse cells (a weighted mean of their centres) plus a small residual, so a centroid
within the window is what the network finds easiest to express. Trained with the world's 8
symmetries as augmentation (:mod:`madp.training.critic_fit`); stored in a safetensors file with its
config in the metadata (:func:`save_critic`, :func:`load_critic`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from madp.errors import InputError
from madp.io.atomic import atomic_path
from madp.robot.critic import CRITIC_CHANNELS, OFFSET_SCALE_M
from madp.robot.prior import COARSE_M

__all__ = ["Critic", "CriticConfig", "critic_env_select", "critic_predictor", "load_critic", "save_critic"]


@dataclass(frozen=True)
class CriticConfig:
    """The network's width, its dilations (one 3 × 3 residual layer each), the window's coarse cells per
    side and the mass unit (the training data's mean cell mass)."""

    channels: int = 16
    dilations: tuple[int, ...] = (1, 2, 4, 8, 1)
    cells: int = 16
    mass_unit: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "CriticConfig":
        return cls(int(d["channels"]), tuple(int(x) for x in d["dilations"]), int(d["cells"]), float(d["mass_unit"]))


class Critic(nn.Module):
    """``(windows [R, 5, H, H], neighbours [R, M, 3])`` -> ``(mass [R] ≥ 0, offset [R, 2])`` in the units
    of the module docstring."""

    def __init__(self, config: CriticConfig | None = None):
        super().__init__()
        self.config = cfg = config or CriticConfig()
        c = cfg.channels
        self.stem = nn.Conv2d(CRITIC_CHANNELS, c, 3, padding=1)
        self.blocks = nn.ModuleList(nn.Conv2d(c, c, 3, padding=d, dilation=d) for d in cfg.dilations)
        self.where = nn.Conv2d(c, 1, 1)  # the spatial softmax's logits
        self.near = nn.Sequential(nn.Linear(3, 2 * c), nn.LeakyReLU(0.01), nn.Linear(2 * c, 2 * c))
        self.pooled = nn.Sequential(nn.Linear(6 * c, 2 * c), nn.LeakyReLU(0.01), nn.Linear(2 * c, 3))
        self.act = nn.LeakyReLU(0.01)
        centre = (torch.arange(cfg.cells, dtype=torch.float32) + 0.5 - cfg.cells / 2) * COARSE_M / OFFSET_SCALE_M
        self.register_buffer("centre", centre, persistent=False)

    def forward(self, x: Tensor, near: Tensor) -> tuple[Tensor, Tensor]:
        h = self.act(self.stem(x))
        for conv in self.blocks:
            h = h + self.act(conv(h))
        p = torch.softmax(self.where(h).flatten(1), 1).reshape(-1, *h.shape[2:])  # [R, H, W]
        where = torch.stack([(p.sum(2) * self.centre).sum(1), (p.sum(1) * self.centre).sum(1)], 1)
        valid = near[:, :, 2:]
        e = self.near(near) * valid  # [R, M, 2c]: padding rows count 0 in the sum, -1e4 in the max
        e_max = (e - 1e4 * (1.0 - valid)).amax(1).clamp(min=-1.0)
        out = self.pooled(torch.cat([h.mean((2, 3)), h.amax((2, 3)), e.sum(1) / 4.0, e_max], 1))
        return nn.functional.softplus(out[:, 0]), where + 0.25 * torch.tanh(out[:, 1:])


def critic_predictor(net: Critic):
    """``net`` as :func:`madp.robot.critic.critic_select`'s ``predict``: ``(windows [R, 5, H, H],
    neighbours [R, M, 3])`` numpy -> ``(mass [R], offset_m [R, 2])`` float64 numpy (the mass in the
    data's unit, the offset in metres)."""
    p = next(net.parameters())

    def tensor(a: np.ndarray) -> Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, np.float32)).to(p.device, p.dtype)

    @torch.inference_mode()
    def predict(windows: np.ndarray, near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mass, offset = net(tensor(windows), tensor(near))
        return mass.double().cpu().numpy(), offset.double().cpu().numpy() * OFFSET_SCALE_M

    return predict


def save_critic(net: Critic, out: Path, record: dict) -> None:
    """``net``'s weights, config and ``record`` (how it was trained) to ``out`` (.safetensors), atomically."""
    from safetensors.torch import save_file

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().contiguous() for k, v in net.state_dict().items()}
    with atomic_path(out, ".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata={"critic": json.dumps(net.config.to_dict()),
                                               "critic_training": json.dumps(record)})


def load_critic(path: Path) -> Critic:
    """The critic in ``path`` (eval mode, how it was trained in ``.record``); one-line errors for a
    missing or foreign file."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: not found; make it with madp critic train")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
        net = Critic(CriticConfig.from_dict(json.loads(meta["critic"])))
        net.load_state_dict(tensors)
        net.record = json.loads(meta.get("critic_training", "{}"))
    except Exception as e:
        raise InputError(f"{path}: not a critic file ({type(e).__name__})") from None
    return net.eval()


def critic_env_select(env, candidates_mps: np.ndarray, net: Critic, scope: str = "team") -> np.ndarray:
    """The swarm's kept actions ``[N, 2]`` among the joint copies ``candidates_mps [K, N, 2]`` of the
    simulator's ``env`` (:class:`madp.sim.CoverageEnv`), as the robots would keep them with the critic
    ``net`` (:func:`madp.robot.critic.critic_select` on every robot's :func:`madp.robot.choice.local_views`
    row, ``scope`` one of :data:`madp.robot.critic.CRITIC_SCOPES`). A robot that holds no neighbour takes
    its bounded Lloyd step instead, as under the other rules that read a robot's map
    (:func:`madp.robot.choice.lone_steps`, on ``explore``'s map)."""
    from madp.robot.choice import explore_prior, local_views, lone_steps
    from madp.robot.critic import critic_inputs, critic_select

    views = local_views(env)
    chosen = critic_select(candidates_mps, views, critic_inputs(env.maps, views, env.params.comm_radius_m),
                           critic_predictor(net), env.neighbour_view()[0], env.params, scope)
    lone, steps = lone_steps(explore_prior(env, views), env.params)
    return np.where(lone[:, None], steps, chosen)
