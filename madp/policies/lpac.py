"""LPAC-K3 behind the simulator's controller interface: one forward pass on the observation tensors
and positions, ``policy(env) -> actions [N, 2]`` m/s.

On environments with a network (:mod:`madp.sim.network`) it runs as the robots would: each robot's
graph is the neighbours whose positions it holds (:meth:`CoverageEnv.neighbour_view`), and each hop of
each graph layer is a round of messages (channel ``lpac/R``, R = layer · K + hop − 1): robot i sums the
features it holds from each neighbour, the normalised edge weights of its own graph applied, whatever
arrived (a kept message brings the features of the step it was sent)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import warnings

import numpy as np
import torch
from torch_geometric.nn.conv.gcn_conv import gcn_norm

from madp.models.lpac import sparse_adjacency

from madp.models.attention_mask import closer_than_squared
from madp.sim.rules import clip_speed

from .swarm import swarm_tensors

if TYPE_CHECKING:
    from madp.sim import CoverageEnv


class LPACPolicy:
    """LPAC-K3 (:class:`madp.models.lpac.LPAC`) acting on the simulator; it draws no noise."""

    def __init__(self, model, device: str = "cpu"):
        self.model, self.device = model.eval(), torch.device(device)

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        return self.act_batch([env])[0]

    @torch.no_grad()
    def act_batch(self, envs: list[CoverageEnv], generators: list[torch.Generator] | None = None) -> np.ndarray:
        """Actions ``[B, N, 2]`` (m/s) for B environments with the same N, in one forward pass
        (``generators`` is accepted for the common interface; LPAC-K3 draws no noise)."""
        obs, pos = swarm_tensors(envs, self.device)
        u = self._forward_inboxes(obs, pos, envs) if envs[0].network is not None else self.model(obs, pos)
        u = self.model.denormalize_actions(u).double().cpu().numpy()
        return np.stack([clip_speed(x, e.params.max_speed_mps) for x, e in zip(u, envs)])

    def _forward_inboxes(self, obs: torch.Tensor, own: torch.Tensor, envs: list[CoverageEnv]) -> torch.Tensor:
        """:meth:`madp.models.lpac.LPAC.forward` with every hop a round of messages through the robots'
        inboxes (module docstring): ``obs [B, N, 4, S, S]``, ``own [B, N, 2]`` -> ``actions_norm [B, N, 2]``.
        When every robot holds every neighbour's current features the sums are the model's own sparse
        products, bit for bit."""
        model, cfg, dev = self.model, self.model.config, self.device
        b, n = own.shape[:2]
        views = [e.neighbour_view() for e in envs]  # each robot's (known [N, N], held positions [N, N, 2])
        held = torch.from_numpy(np.stack([v[1] for v in views]).astype(np.float32)).to(dev)
        known = torch.from_numpy(np.stack([v[0] for v in views])).to(dev)
        r2 = cfg.comm_radius_m * cfg.comm_radius_m
        adj = known & closer_than_squared(held - own[:, :, None], cfg.comm_radius_m)  # [B, N, N]: i's graph, j -> i
        bb, ii, jj = adj.nonzero(as_tuple=True)
        if cfg.edge_weight == "gaussian":  # the weights of madp.models.lpac.batch_graph
            weight = torch.exp(-(own[bb, ii] - held[bb, ii, jj]).square().sum(-1) / r2)
        else:
            weight = torch.ones(len(bb), device=dev, dtype=own.dtype)
        edge_index = torch.stack([bb * n + jj, bb * n + ii])
        z = model.cnn(obs.reshape(b * n, *obs.shape[2:]).to(model.dtype))
        h = torch.cat([z, model.normalize_positions(own.reshape(b * n, 2)).to(z.dtype)], dim=-1)
        adj_t = sparse_adjacency(edge_index, weight.to(h.dtype), b * n)
        # gcn_norm weighs edge j -> i by w_ij / sqrt(deg_i deg_j), deg_i the weight sum of i's own graph.
        # deg_j is known to j alone, so j sends its features already scaled by deg_j^-1/2 and i applies
        # w_ij deg_i^-1/2: nothing of j's current state reaches i but what j sent.
        w_own = torch.zeros(b, n, n, device=dev, dtype=h.dtype)
        w_own[bb, ii, jj] = weight.to(h.dtype)
        deg = w_own.sum(-1)
        dinv = torch.where(deg > 0, deg.pow(-0.5), torch.zeros_like(deg))  # [B, N]: each robot's deg^-1/2
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Sparse invariant checks are implicitly disabled")
            norm, _ = gcn_norm(adj_t, None, b * n, add_self_loops=False, flow=model.gnn[0].flow, dtype=h.dtype)
            for layer, conv in enumerate(model.gnn):
                out = conv.lins[0](h)
                x = h
                for hop, lin in enumerate(conv.lins[1:]):
                    x = self._hop(conv, norm, w_own, dinv, adj, x, envs, f"lpac/{layer * cfg.gnn_hops + hop}")
                    out = out + lin.forward(x)
                if conv.bias is not None:
                    out = out + conv.bias
                h = torch.relu(out)
        return model.out(model.mlp(h)).reshape(b, n, -1)

    @staticmethod
    def _hop(conv, norm: torch.Tensor, w_own: torch.Tensor, dinv: torch.Tensor, adj: torch.Tensor, x: torch.Tensor,
             envs: list[CoverageEnv], channel: str) -> torch.Tensor:
        """One round of messages: every robot j sends its features ``x [B·N, F]`` scaled by its own
        ``dinv [B, N]`` (deg_j^-1/2); robot i sums what it holds with its own weights ``w_own [B, N, N]``
        (w_ij) times its own deg_i^-1/2."""
        b, n = adj.shape[:2]
        xs = x.reshape(b, n, -1) * dinv[:, :, None]
        got = [e.network.exchange(channel, e.steps, xs[k].double().cpu().numpy()) for k, e in enumerate(envs)]
        edges = adj.cpu().numpy()  # [B, N, N]: i's graph
        fresh = all(bool(np.all(r.valid[a] & (r.sent_step[a] == e.steps))) for r, e, a in zip(got, envs, edges))
        if fresh:  # every robot holds every neighbour's features of this step: the model's own product
            return conv.propagate(norm, x=x, edge_weight=None)
        weights = (w_own * dinv[:, :, None]).double().cpu().numpy()  # [B, N, N]: i's w_ij deg_i^-1/2
        sums = np.stack([r.weighted_sum(np.where(a, w, 0.0)) for r, a, w in zip(got, edges, weights)])
        return torch.from_numpy(sums).to(x.device, x.dtype).reshape(b * n, -1)
