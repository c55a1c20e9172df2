"""LPAC-K3: the learned baseline of the Coverage Control Library (Agarwal et al., T-RO 2025).

Per robot: CNN ``O_i [4, 32, 32] -> z_i [32]`` (the library's ``CNNBackBone``: 3 x (Conv 3x3 without
padding, 32 ch, BatchNorm, LeakyReLU), flatten, Linear, LeakyReLU; :class:`PerceptionCNN` with the
``paper`` preset); ``[z_i, pos_i] [34]`` with the library's position
normalisation; 5 x TAGConv(K = 3 hops, 256) + ReLU over the communication graph (robots closer than
r_c); torch_geometric ``MLP([256, 32, 32])`` (Linear, BatchNorm, ReLU, Linear); Linear 32 -> 2. It
regresses normalised actions directly (one forward pass per control step).

A batch of swarms ``[B, N]`` (with optional padding ``valid [B, N]``) becomes one disjoint graph of
the valid robots only (so padding never enters BatchNorm statistics or message passing); the
result is scattered back to ``[B, N, 2]`` with zeros at padding.
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor, nn
from torch_geometric.nn import MLP, TAGConv

from .action_stats import ActionStatsMixin
from .attention_mask import radius_adjacency
from .config import LPACConfig
from .perception import PerceptionCNN

__all__ = ["LPAC", "batch_graph", "sparse_adjacency"]


def batch_graph(pos_m: Tensor, radius_m: float, valid: Tensor | None = None,
                edge_weight: str = "gaussian") -> tuple[Tensor, Tensor, Tensor]:
    """Communication graphs of a batch of swarms as one disjoint ``torch_geometric`` graph.

    Args:
        pos_m: ``[B, N, 2]`` metres; valid: ``[B, N]`` bool or None.
        edge_weight: ``"gaussian"`` (``exp(-d^2 / r^2)``, the library's weights) or ``"binary"``.

    Returns:
        ``node [B, N]`` long: node id of each valid robot in the flat graph (-1 at padding; valid
        robots are numbered in row-major order, so ``x[valid]`` lines up with the node ids);
        ``edge_index [2, E]`` long (both directions, no self loops); ``weight [E]``.
    """
    b, n = pos_m.shape[:2]
    if valid is None:
        valid = torch.ones(b, n, dtype=torch.bool, device=pos_m.device)
    valid = valid.to(torch.bool)
    adj = radius_adjacency(pos_m, radius_m, valid, self_loops=False)  # [B, N, N]
    flat_valid = valid.reshape(-1)
    node = torch.cumsum(flat_valid.long(), 0) - 1
    node = torch.where(flat_valid, node, torch.full_like(node, -1)).view(b, n)
    bb, ii, jj = adj.nonzero(as_tuple=True)  # row-major: sorted by (graph, target i, source j)
    # message from source j to target i (symmetric graph, so both directions are present)
    edge_index = torch.stack([node[bb, jj], node[bb, ii]])
    if edge_weight == "gaussian":
        d2 = (pos_m[bb, ii] - pos_m[bb, jj]).square().sum(-1)
        weight = torch.exp(-d2 / (radius_m * radius_m))
    elif edge_weight == "binary":
        weight = torch.ones(bb.shape[0], device=pos_m.device, dtype=pos_m.dtype)
    else:
        raise ValueError(f"unknown edge_weight {edge_weight!r}")
    return node, edge_index, weight


def sparse_adjacency(edge_index: Tensor, weight: Tensor, num_nodes: int) -> Tensor:
    """``[num_nodes, num_nodes]`` sparse CSR adjacency (row = target, col = source, i.e. pyg's
    ``adj_t``) for TAGConv. Message passing then runs as sparse-dense matmuls, ~3x faster on CPU
    than ``edge_index`` scatter/gather and numerically the same.

    Expects the edge order of :func:`batch_graph` (sorted by target, then source), which is already
    CSR order, so no sort or coalesce is needed.
    """
    target, source = edge_index[1], edge_index[0]
    counts = torch.bincount(target, minlength=num_nodes)
    crow = torch.cat([counts.new_zeros(1), torch.cumsum(counts, 0)])
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return torch.sparse_csr_tensor(crow, source, weight, (num_nodes, num_nodes), check_invariants=False)


class LPAC(ActionStatsMixin):
    """LPAC-K3. ``forward(obs [B, N, 4, 32, 32], pos_m [B, N, 2], valid=None) -> actions_norm [B, N, 2]``."""

    def __init__(self, config: LPACConfig | None = None):
        super().__init__()
        cfg = config or LPACConfig()
        self.config = cfg
        self.cnn = PerceptionCNN(cfg.obs_channels, cfg.obs_size, cfg.cnn_channels, cfg.cnn_kernel, cfg.cnn_stride,
                                 cfg.cnn_padding, "batch", cfg.z_dim, cfg.leaky_slope)
        dims = [cfg.z_dim + 2] + [cfg.gnn_hidden] * cfg.gnn_layers
        self.gnn = nn.ModuleList(TAGConv(dims[i], dims[i + 1], K=cfg.gnn_hops) for i in range(cfg.gnn_layers))
        self.mlp = MLP([cfg.gnn_hidden, *cfg.mlp_hidden])
        self.out = nn.Linear(cfg.mlp_hidden[-1], cfg.action_dim)
        self._init_action_stats(cfg.action_dim)
        self._fired: list[Tensor] | None = None  # set by units_fired()

    @property
    def dtype(self) -> torch.dtype:
        return self.out.weight.dtype

    def normalize_positions(self, pos_m: Tensor) -> Tensor:
        w = self.config.world_size
        if self.config.pos_norm == "library":
            return (pos_m + w / 2.0) / w
        return pos_m / w

    def forward(self, obs: Tensor, pos_m: Tensor, valid: Tensor | None = None) -> Tensor:
        cfg = self.config
        b, n = pos_m.shape[:2]
        if valid is None:
            valid = torch.ones(b, n, dtype=torch.bool, device=pos_m.device)
        valid = valid.to(torch.bool)
        node, edge_index, weight = batch_graph(pos_m, cfg.comm_radius_m, valid, cfg.edge_weight)
        x_img = obs[valid].to(self.dtype)  # [R, C, S, S], R valid robots in node-id order
        z = self.cnn(x_img)
        h = torch.cat([z, self.normalize_positions(pos_m[valid]).to(z.dtype)], dim=-1)
        adj_t = sparse_adjacency(edge_index, weight.to(h.dtype), h.shape[0])
        with warnings.catch_warnings():
            # pyg's gcn_norm builds CSR tensors without opting in/out of invariant checks
            warnings.filterwarnings("ignore", message="Sparse invariant checks are implicitly disabled")
            for conv in self.gnn:
                h = torch.relu(conv(h, adj_t))
                if self._fired is not None:
                    self._fired.append((h > 0).any(0))
        u = self.out(self.mlp(h))
        out = u.new_zeros(b, n, cfg.action_dim)
        out[valid] = u
        return out

    @torch.no_grad()
    def units_fired(self, obs: Tensor, pos_m: Tensor, valid: Tensor | None = None) -> Tensor:
        """``[gnn_layers, gnn_hidden]`` bool: which ReLU units of each graph layer are positive for at
        least one robot of the batch. A unit that fires for no robot of many real swarms is dead: it
        passes no gradient, and (with coupled L2 decay) its weights decay to zero."""
        self._fired = []
        try:
            self(obs, pos_m, valid)
            return torch.stack(self._fired)
        finally:
            self._fired = None

    def loss(self, obs: Tensor, pos_m: Tensor, actions_norm: Tensor, valid: Tensor | None = None) -> Tensor:
        """MSE on normalised actions over valid robots and action dims."""
        err = (self(obs, pos_m, valid) - actions_norm.to(self.dtype)).square()
        if valid is None:
            return err.mean()
        w = valid.unsqueeze(-1).to(err.dtype)
        return (err * w).sum() / (w.sum() * err.shape[-1]).clamp_min(1)
