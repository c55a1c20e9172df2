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
symmetries as augmentation (:mod:`madp.training.critic_fit`); carried in a policy file beside the
policy, its config in the metadata (:func:`madp.policies.checkpoint.attach`, :func:`load_critic`), where
the ``critic`` selection rules read it (:data:`madp.selection.RULES`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from madp.errors import InputError
from madp.robot.critic import CRITIC_CHANNELS, OFFSET_SCALE_M
from madp.robot.prior import COARSE_M

__all__ = ["Critic", "CriticConfig", "critic_predictor", "load_critic"]


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
    of the module docstring. H is ``config.cells`` for the simulator's default window; another H (a
    smaller world's window) runs too, outside what the critic was trained on."""

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

    @staticmethod
    def centres(cells: int) -> Tensor:
        """``[cells]``: the coarse cells' centres along a window's side, in units of OFFSET_SCALE_M from its middle."""
        return (torch.arange(cells, dtype=torch.float32) + 0.5 - cells / 2) * COARSE_M / OFFSET_SCALE_M

    def forward(self, x: Tensor, near: Tensor) -> tuple[Tensor, Tensor]:
        h = self.act(self.stem(x))
        for conv in self.blocks:
            h = h + self.act(conv(h))
        p = torch.softmax(self.where(h).flatten(1), 1).reshape(-1, *h.shape[2:])  # [R, H, W]
        centre = self.centres(h.shape[-1]).to(h)  # any window size (other simulator constants), in the graph too
        where = torch.stack([(p.sum(2) * centre).sum(1), (p.sum(1) * centre).sum(1)], 1)
        valid = near[:, :, 2:]
        e = self.near(near) * valid  # [R, M, 2c]: padding rows count 0 in the sum, -1e4 in the max
        e_max = (e - 1e4 * (1.0 - valid)).amax(1).clamp(min=-1.0)
        out = self.pooled(torch.cat([h.mean((2, 3)), h.amax((2, 3)), e.sum(1) / 4.0, e_max], 1))
        return nn.functional.softplus(out[:, 0]), where + 0.25 * torch.tanh(out[:, 1:])


def critic_predictor(net: Critic):
    """``net`` as :func:`madp.robot.critic.critic_costs`' ``predict``: ``(windows [R, 5, H, H],
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


def load_critic(path: Path, required: bool = True) -> Critic | None:
    """The critic in ``path`` (eval mode, how it was trained in ``.record``): a policy file that carries
    one (``madp critic train``: weights ``critic.*``, config in the metadata key ``critic``) or a file of
    the critic alone (its weights unprefixed). None when ``path`` carries none and not ``required``;
    one-line errors for a missing, damaged or foreign file."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: not found; make it with madp critic train")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            keys = list(f.keys())
            if "critic" not in meta and not required:
                return None
            prefixed = any(k.startswith("critic.") for k in keys)
            tensors = {k.removeprefix("critic."): f.get_tensor(k) for k in keys
                       if k.startswith("critic.") or not prefixed}
        net = Critic(CriticConfig.from_dict(json.loads(meta["critic"])))
        if not all(torch.isfinite(v).all() for v in tensors.values()):
            raise InputError(f"{path}: the critic's weights hold NaN or infinity")
        net.load_state_dict(tensors)
        net.record = json.loads(meta.get("critic_training", "{}"))
    except InputError:
        raise
    except Exception as e:
        raise InputError(f"{path}: not a critic file ({type(e).__name__})") from None
    return net.eval()
