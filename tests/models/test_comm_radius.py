"""One communication radius everywhere: robots exactly r_c apart are *not* neighbours (SPEC §2: the
library's ``distance < r_c``), and the attention mask, the packed decentralized mask, LPAC-K3's graph,
the environment's neighbour graph and the observation neighbour maps agree on it.

The layouts put pairs at exactly r_c (and just inside it) on coordinates that are exact in float32,
so ``<`` and ``<=`` give different answers and rounding cannot hide the difference. Guards the mutation
``<`` -> ``<=`` in ``models/attention_mask.py`` (and the same slip in ``sim/observations.py`` or
``CoverageEnv.neighbours``).
"""

import numpy as np
import pytest
import torch

from madp.models import MADP, attention_mask, lpac_config, packed_neighbourhood_mask, radius_adjacency
from madp.models.lpac import LPAC, batch_graph
from madp.sim import CoverageEnv, Scenario, SimParams
from .models_testutils import tiny_madp_config

# (r_c, positions, undirected edges). r_c = 256: exactly-r_c pairs lie on the axes (no dyadic point of
# a circle of radius 2^8 is off the axes); r_c = 250: the 150-200-250 triangle gives a diagonal one.
LAYOUTS = [
    (256.0, [[300.0, 300.0], [556.0, 300.0], [300.0, 44.0], [300.0, 555.9375], [811.9375, 300.0]],
     {(0, 3), (1, 4)}),  # 0-1 and 0-2 exactly r_c apart, 0-3 and 1-4 1/16 m inside
    (250.0, [[300.0, 300.0], [450.0, 500.0], [449.875, 100.0], [100.0, 150.0]],
     {(0, 2)}),  # 0-1 and 0-3 exactly r_c apart (diagonal), 0-2 inside by 0.08 m
]


def expected_adjacency(n, edges):
    adj = np.zeros((n, n), dtype=bool)
    for i, j in edges:
        adj[i, j] = adj[j, i] = True
    return adj


@pytest.mark.parametrize("radius,positions,edges", LAYOUTS)
def test_robots_exactly_r_c_apart_are_not_neighbours_anywhere(radius, positions, edges):
    """Fails if any of the six places that decide "neighbour" uses <= r_c (or another radius)."""
    n = len(positions)
    adj = expected_adjacency(n, edges)
    eye = np.eye(n, dtype=bool)
    pos = torch.tensor(positions)
    assert (torch.cdist(pos.double(), pos.double()) == radius).any()  # the layout really has exact pairs

    # the attention mask (incl. self) and the communication graph behind it
    assert np.array_equal(attention_mask(pos[None], radius)[0].numpy(), adj | eye)
    assert np.array_equal(radius_adjacency(pos[None], radius, self_loops=False)[0].numpy(), adj)
    # MADP's own mask (radius from its config) and the mask of a packed neighbourhood
    madp = MADP(tiny_madp_config(comm_radius_m=radius))
    assert np.array_equal(madp.attention_mask(pos[None])[0].numpy(), adj | eye)
    group = torch.zeros(1, n, dtype=torch.long)
    packed = packed_neighbourhood_mask(pos[None], radius, torch.ones(1, n, dtype=torch.bool), group)
    assert np.array_equal(packed[0].numpy(), adj | eye)
    # LPAC-K3's graph (both edge directions, no self loops)
    lpac = LPAC(lpac_config("cpu", gnn_hidden=8, comm_radius_m=radius))
    _, edge_index, _ = batch_graph(pos[None], lpac.config.comm_radius_m)
    lpac_adj = np.zeros((n, n), dtype=bool)
    lpac_adj[edge_index[1].numpy(), edge_index[0].numpy()] = True
    assert np.array_equal(lpac_adj, adj)

    # the simulator: its neighbour graph and the neighbour channels of the observations
    params = SimParams(num_robots=n, num_features=1, comm_radius_m=radius)
    env = CoverageEnv(Scenario(np.array([[512.0, 512.0, 50.0, 1.0]]), np.array(positions), params))
    assert np.array_equal(env.neighbours(), adj)
    obs = env.observations()
    p = np.array(positions)
    # each map holds (x_j - x_i) / r_c of i's neighbours: a robot exactly r_c away would add +-1
    expect = np.einsum("ij,ijc->ic", adj.astype(float), (p[None] - p[:, None]) / radius)
    np.testing.assert_allclose(obs[:, 1:3].sum(axis=(2, 3)), expect, atol=1e-6)
    assert np.array_equal(np.abs(obs[:, 1:3]).sum(axis=(1, 2, 3)) > 0, adj.any(1))
