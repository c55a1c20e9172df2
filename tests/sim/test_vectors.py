"""The simulator and controllers against the Coverage Control Library's reference vectors.

Tolerances (``tests/data/README.md``): the library computes its map in float32 as differences of erfc products, so
each cell carries up to ~2e-3 absolute noise against our exact float64 map. Everything computed on
*our* map therefore inherits that noise (J and masses ~1e-3 relative; centroids, actions and
positions to millimetres). Given the library's *own* map (``world_idf`` of seed 1000) the same code
reproduces its Voronoi sums, both controllers' actions and trajectories to ~1e-6 or better.
"""

import json

import numpy as np
import pytest

from madp.sim import (ClairvoyantCVT, ColumnPrefix, CoverageEnv, DecentralizedCVT, Scenario, SimParams,
                      coverage_cost, importance_map, rollout, voronoi_sums)

from tests.conftest import VECTORS

TAGS = sorted(p.stem for p in VECTORS.glob("*.npz"))  # test_vectors_present fails when there are none


def load(tag):
    d = dict(np.load(VECTORS / f"{tag}.npz"))
    meta = json.loads((VECTORS / f"{tag}.json").read_text())
    params = SimParams(num_robots=len(d["positions0"]), num_features=len(d["features"]),
                       sigma_range_m=meta["sigma_range"], comm_radius_m=meta["params"]["comm_radius"])
    return d, meta, Scenario(d["features"], d["positions0"], params)


@pytest.fixture(scope="module", params=TAGS)
def case(request, vectors_dir):
    d, meta, sc = load(request.param)
    world = d.get("world_idf")
    return request.param, d, meta, CoverageEnv(sc), (CoverageEnv(sc, world_map=world) if world is not None else None)


def test_vectors_present(vectors_dir):
    assert len(TAGS) >= 7


def test_map_at_sampled_cells(case):
    tag, d, meta, env, _ = case
    cells = d["idf_cells"]
    err = np.abs(env.world_map[cells[:, 0], cells[:, 1]] - d["idf_values"])
    assert err.max() < 2e-3 and err.mean() < 2e-4, (err.max(), err.mean())
    assert env.world_map.max() == pytest.approx(1.0)
    # The peak may sit on a plateau where float32 noise picks the library's argmax: compare values.
    assert env.world_map[tuple(meta["idf_argmax_xy"])] == pytest.approx(1.0, abs=2e-3)


def test_whole_map_seed1000(vectors_dir):
    d, meta, sc = load("uniform_seed1000")
    ours = importance_map(sc.features)
    err = np.abs(ours - d["world_idf"])
    assert err.max() < 2e-3 and err.mean() < 2e-4
    assert ours.sum() == pytest.approx(meta["idf_sum"], rel=1e-3)


def test_objective0(case):
    tag, d, meta, env, lib = case
    assert env.cost0 == pytest.approx(meta["objective0"], rel=1e-3)
    if lib is not None:
        assert lib.cost0 == pytest.approx(meta["objective0"], rel=1e-9)


def test_voronoi_masses_and_centroids(case):
    tag, d, meta, env, lib = case
    s = voronoi_sums(env.prefix, d["positions0"])
    np.testing.assert_allclose(s.mass, d["voronoi_masses"], rtol=2e-3, atol=1e-3)
    np.testing.assert_allclose(s.centroid_m, d["voronoi_centroids"], atol=5e-3)
    if lib is not None:
        s = voronoi_sums(lib.prefix, d["positions0"])
        np.testing.assert_allclose(s.mass, d["voronoi_masses"], rtol=1e-6)
        np.testing.assert_allclose(s.centroid_m, d["voronoi_centroids"], rtol=0, atol=1e-6)


@pytest.mark.parametrize("name,cls", [("clairvoyant", ClairvoyantCVT), ("dcvt", DecentralizedCVT)])
def test_first_actions(case, name, cls):
    tag, d, meta, env, lib = case
    env.reset()
    np.testing.assert_allclose(cls()(env), d[f"{name}_actions0"], atol=1e-3)
    if lib is not None:
        lib.reset()
        np.testing.assert_allclose(cls()(lib), d[f"{name}_actions0"], atol=1e-6)


@pytest.mark.parametrize("name,cls,checkpoints", [("clairvoyant", ClairvoyantCVT, (1, 5, 20, 100)),
                                                  ("dcvt", DecentralizedCVT, (1, 5, 20))])
def test_positions_after_steps(case, name, cls, checkpoints):
    tag, d, meta, env, lib = case
    for e, tol in ((env, 1e-2), (lib, 1e-6)):
        if e is None:
            continue
        e.reset()
        ctrl = cls()
        for t in range(1, max(checkpoints) + 1):
            e.step(ctrl(e))
            if t in checkpoints:
                np.testing.assert_allclose(e.positions_m, d[f"{name}_positions_step{t}"], rtol=0, atol=tol,
                                           err_msg=f"{tag} {name} step {t}")


def test_observation_tensors(case):
    tag, d, meta, env, lib = case
    env.reset()
    obs = env.observations()
    ref = d["lpac_maps0"]
    assert obs.shape == ref.shape
    np.testing.assert_allclose(obs[:, 0], ref[:, 0], atol=2e-3)  # local map: carries the map's noise
    np.testing.assert_allclose(obs[:, 1:], ref[:, 1:], atol=1e-6)  # comm x, comm y, boundary: exact
    np.testing.assert_allclose(env.local_maps()[:4], d["raw_local_maps0_r0to3"], atol=2e-3)
    if lib is not None:
        lib.reset()
        np.testing.assert_allclose(lib.observations(), ref, atol=1e-6)
        np.testing.assert_array_equal(lib.local_maps()[:4], d["raw_local_maps0_r0to3"])


def test_cost_curves_seed1000(vectors_dir):
    """Whole 600-step normalised-cost curves of both controllers (every 50 steps) and convergence."""
    d, meta, sc = load("uniform_seed1000")
    env = CoverageEnv(sc)
    for name, cls in (("clairvoyant", ClairvoyantCVT), ("dcvt", DecentralizedCVT)):
        r = rollout(env, cls(), 600)
        for t, v in meta[name]["cost"].items():
            assert r.normalized_cost[int(t)] == pytest.approx(v, abs=1e-5), (name, t)
        assert r.converged_at == meta[name]["converged_at"]


def test_cost_function_matches_prefix_sums(case):
    tag, d, meta, env, lib = case
    assert coverage_cost(ColumnPrefix(env.world_map), d["positions0"]) == pytest.approx(env.cost0, rel=1e-12)
