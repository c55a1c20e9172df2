"""The critic of MADP's joint copies (:class:`madp.models.critic.Critic`) as an ONNX graph, for the robot
runtime: ``windows [R, 5, H, H]`` and ``neighbours [R, M, 3]`` float32 (:func:`madp.robot.critic.critic_inputs`)
-> ``mass [R]`` and
``offset [R, 2]`` (in units of :data:`madp.robot.critic.OFFSET_SCALE_M`), run torch-free by
:func:`madp.robot.critic.onnx_predictor`."""

from __future__ import annotations

from pathlib import Path

import torch

from madp.export.onnx import _write_graph
from madp.models.critic import Critic
from madp.robot.critic import MAX_NEIGHBOURS

__all__ = ["CRITIC_GRAPH", "export_critic"]

#: The graph's file name in an export directory.
CRITIC_GRAPH = "critic.onnx"


def export_critic(net: Critic, out: Path) -> Path:
    """Write ``net`` (eval mode) as one ONNX graph to ``out`` atomically, the robots axis dynamic; returns ``out``."""
    cells = net.config.cells
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    near = torch.rand(2, MAX_NEIGHBOURS, 3).round()
    return _write_graph(net.eval(), (torch.rand(2, 5, cells, cells), near), ("windows", "neighbours"),
                        ("mass", "offset"), {"windows": {0: "robots"}, "neighbours": {0: "robots"}, "mass": {0: "robots"},
                                             "offset": {0: "robots"}}, out)
