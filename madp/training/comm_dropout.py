"""Communication dropout: training samples in which robots stop hearing some of their neighbours.

Over a lossy network (:mod:`madp.sim.network`) a robot's attention neighbourhood and its neighbour
channels hold only the robots it heard from; with every message lost it is alone. ``--comm-dropout P``
trains on such inputs. Each training sample, with probability P, loses links:

* a link-loss rate ``q`` is drawn uniformly from :data:`LOSS_RATES` = (0.3, 0.6, 1.0): a few,
  most, or all links lost (q = 1: every robot isolated, the ``no_comm`` fault);
* each undirected pair of robots is lost independently with probability ``q``: the two stop hearing
  each other (``links [B, N, N]`` bool, symmetric, True on the diagonal: a robot always hears itself).

A sample not drawn keeps every link (all True). What a lost link changes:

* the attention mask of encoder and decoder (``MADP.loss(..., links=links)``): distance < r_c AND
  heard AND same component of the graph of links heard
  (:func:`madp.models.attention_mask.attention_mask`), so the token's neighbourhood offset is over
  the neighbours still heard too;
* the observation's neighbour channels 1-2 (:func:`drop_neighbour_channels`): a robot that lost a
  neighbour gets them recomputed from the positions of those it still hears
  (:func:`neighbour_channels`, the simulator's rasterisation), rounded to the dataset's storage
  precision (float16) as recorded channels are; a robot that lost none keeps its recorded channels.

The draws come from their own generator (the trainer's stream 2, validation's stream 3), so the
diffusion draws of a step do not change and a resumed run continues exactly.
"""

from __future__ import annotations

import torch
from torch import Tensor

from madp.models.attention_mask import pairwise_offsets

__all__ = ["LOSS_RATES", "draw_links", "in_comm_range", "neighbour_channels", "drop_neighbour_channels"]

#: The per-sample link-loss rates q a dropped sample draws from, uniformly.
LOSS_RATES = (0.3, 0.6, 1.0)

#: Storage precision of recorded observations (``madp.data_schema.schema.OBSERVATIONS_DTYPE``).
_STORED = torch.float16


def draw_links(generator: torch.Generator, num_samples: int, num_robots: int, p: float,
               rates: tuple[float, ...] = LOSS_RATES) -> Tensor:
    """``links [num_samples, num_robots, num_robots]`` bool on the generator's device (module docstring).

    Draws, in this order: which samples lose links (``[S]`` uniforms < ``p``), each sample's rate
    (``[S]`` indices into ``rates``), each pair's loss (``[S, N, N]`` uniforms < q, upper triangle
    read, mirrored). A fixed number of draws whatever ``p``, so the links of sample s depend only on
    the generator and s's place."""
    dev = generator.device
    hit = torch.rand(num_samples, generator=generator, device=dev) < p
    q = torch.tensor(rates, dtype=torch.float32, device=dev)[
        torch.randint(len(rates), (num_samples,), generator=generator, device=dev)]
    lost = torch.rand((num_samples, num_robots, num_robots), generator=generator, device=dev) < q[:, None, None]
    lost = torch.triu(lost, diagonal=1) & hit[:, None, None]
    return ~(lost | lost.transpose(1, 2))


def in_comm_range(pos_m: Tensor, comm_radius_m: float, valid: Tensor | None = None) -> Tensor:
    """``[B, N, N]`` bool: the simulator's neighbour rule (:func:`madp.sim.rules.closer_than`,
    ``‖x_j - x_i‖ < r_c`` in float64) between real robots (``valid [B, N]``; None: all), no self pairs."""
    off = pairwise_offsets(pos_m.double())
    eye = torch.eye(pos_m.shape[-2], dtype=torch.bool, device=pos_m.device)
    near = (off.square().sum(-1).sqrt() < comm_radius_m) & ~eye
    return near if valid is None else near & valid[:, :, None] & valid[:, None, :]


def neighbour_channels(pos_m: Tensor, comm_radius_m: float, out_size: int = 32, heard: Tensor | None = None,
                       valid: Tensor | None = None) -> Tensor:
    """The neighbour channels ``[B, N, 2, out, out]`` float32 of ``pos_m [B, N, 2]``: robot i's shows the
    robots j within r_c (:func:`in_comm_range`) that it hears (``heard [B, N, N]``; None: all) and that
    are real (``valid [B, N]``). The torch twin of :func:`madp.sim.observations.neighbour_maps`, equal to
    it bit for bit on float64 positions: offset r = float32(x_j - x_i), pixel
    round(r · out / (2 r_c) + out/2 - 0.5) per axis clipped to the map, value r / r_c, values sharing a
    pixel summed in float32 in increasing j (as ``np.add.at``)."""
    b, n = pos_m.shape[:2]
    dev = pos_m.device
    mask = in_comm_range(pos_m, comm_radius_m, valid)
    if heard is not None:
        mask = mask & heard
    rel = pairwise_offsets(pos_m.double()).float()  # [B, i, j, 2]
    f32 = dict(dtype=torch.float32, device=dev)  # 0-dim device tensors: float32 arithmetic as numpy's
    pix = torch.round(rel * torch.tensor(out_size / (comm_radius_m * 2.0), **f32)
                      + torch.tensor(out_size / 2.0 - 0.5, **f32)).long().clamp(0, out_size - 1)
    vals = rel / torch.tensor(comm_radius_m, **f32)
    # Sequential float32 sums as np.add.at: a neighbour's rank among robot i's earlier neighbours in
    # the same pixel; each pass adds one rank (no two writes of a pass share a pixel).
    key = torch.where(mask, pix[..., 0] * out_size + pix[..., 1], out_size * out_size)
    sorted_key, order = torch.sort(key, dim=-1, stable=True)
    place = torch.arange(n, device=dev).expand(b, n, n)
    start = torch.ones_like(sorted_key, dtype=torch.bool)
    start[..., 1:] = sorted_key[..., 1:] != sorted_key[..., :-1]
    rank = torch.empty_like(order).scatter_(-1, order, place - torch.where(start, place, 0).cummax(-1).values)
    out = torch.zeros(b, n, 2, out_size * out_size, **f32)
    for r in range(int(rank[mask].max()) + 1 if bool(mask.any()) else 0):
        bi, ii, jj = (mask & (rank == r)).nonzero(as_tuple=True)
        k = key[bi, ii, jj]
        for c in range(2):
            out[bi, ii, c, k] = out[bi, ii, c, k] + vals[bi, ii, jj, c]
    return out.view(b, n, 2, out_size, out_size)


def drop_neighbour_channels(obs: Tensor, pos_m: Tensor, links: Tensor, comm_radius_m: float,
                            valid: Tensor | None = None) -> Tensor:
    """``obs [B, N, C, S, S]`` with channels 1-2 of every robot that lost a neighbour (a robot within
    r_c whose link ``links [B, N, N]`` is False) recomputed from the neighbours it still hears, in
    float16 precision; the other robots' channels, and ``obs`` itself, untouched (``obs`` returned when
    no robot lost one). Same memory layout."""
    lost = (in_comm_range(pos_m, comm_radius_m, valid) & ~links).any(-1)  # [B, N]
    hit = lost.any(-1).nonzero(as_tuple=True)[0]  # the samples to redraw
    if not len(hit):
        return obs
    fresh = neighbour_channels(pos_m[hit], comm_radius_m, obs.shape[-1], links[hit],
                               None if valid is None else valid[hit]).to(_STORED).to(obs.dtype)
    out = obs.clone()
    out[hit, :, 1:3] = torch.where(lost[hit][:, :, None, None, None], fresh, obs[hit, :, 1:3])
    return out
