"""Where madp's simulator spends a call: thread-CPU medians of each stage of the clairvoyant step, J,
the DCVT step and the observation tensor (docs/sim-speed.md quotes its output).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/sim_profile.py [--seed S] [--repeats R]

One scenario (N = F = 32, 1024² world), 30 clairvoyant steps in, then each stage repeated on that state.
Thread-CPU time (not wall time) so that other jobs on the machine do not count; stages are timed
alone and warm, so they add up to a little less than the totals. The compiled kernels
(madp/sim/kernels.py) are compiled, or loaded from numba's cache, before anything is timed.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario
from madp.sim.controllers import lloyd_velocity
from madp.sim.observations import boundary_maps, neighbour_maps
from madp.sim.voronoi import cell_sums, delaunay_neighbours, world_competitors


def cpu_ms(fn, repeats: int) -> float:
    fn()
    t = np.empty(repeats)
    for i in range(repeats):
        t0 = time.thread_time()
        fn()
        t[i] = time.thread_time() - t0
    return float(np.median(t)) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=12345)
    ap.add_argument("--repeats", type=int, default=200)
    a = ap.parse_args()
    t0 = time.perf_counter()
    env = CoverageEnv(Scenario.random(a.seed))
    expert, dcvt = ClairvoyantCVT(), DecentralizedCVT()
    env.step(expert(env)), dcvt(env), env.observations()
    first = time.perf_counter() - t0
    for _ in range(29):
        env.step(expert(env))
    x, p = env.positions_m, env.params
    w, n = p.world_size, len(x)
    rows: list[tuple[str, float]] = []

    def t(name, fn):
        rows.append((name, cpu_ms(fn, a.repeats)))

    # clairvoyant goals and J: the world's Voronoi cells over the column prefix table
    t("J (coverage_cost), total", env.cost)
    t("clairvoyant goals, total", lambda: expert.goals(env))
    t("  Delaunay neighbours (scipy)", lambda: delaunay_neighbours(x))
    t("  world_competitors: duplicate check + Delaunay", lambda: world_competitors(x))
    pts, idx, valid, _ = world_competitors(x)
    boxes = np.broadcast_to(np.array([0.0, 0.0, w, w]), (n, 4))
    t("  cell_sums kernel, J (3 moments, no vertex means)",
      lambda: cell_sums(x, pts, idx, valid, boxes, prefix=env.prefix, with_cost=True, with_centroids=False))
    t("  cell_sums kernel, goals (2 moments, vertex means)",
      lambda: cell_sums(x, pts, idx, valid, boxes, prefix=env.prefix))
    goals = expert.goals(env)
    t("lloyd_velocity (with the oscillation check)", lambda: lloyd_velocity(env, goals))
    u = expert(env)
    saved = (env.positions_m.copy(), env.offset_m.copy(), list(env.history), env.maps._last_cells.copy(), env.steps,
             env.maps.seen_lo.copy(), env.maps.seen_hi.copy(), env.maps._last_lo, env.maps._last_hi)

    def step_only():
        env.positions_m, env.offset_m, env.history = saved[0].copy(), saved[1].copy(), list(saved[2])
        env.maps._last_cells, env.steps = saved[3].copy(), saved[4]
        env.maps.seen_lo[:], env.maps.seen_hi[:] = saved[5], saved[6]
        env.maps._last_lo, env.maps._last_hi = saved[7], saved[8]
        env.step(u)

    t("env.step(u): move, clamp, sense, history", step_only)
    # DCVT goals: each robot's cell among its neighbours, on its own map (block prefix sums)
    t("DCVT goals, total (block sums up to date)", lambda: dcvt.goals(env))
    t("  neighbours (comm graph)", env.neighbours)
    cells_xy = env.cells()

    def refresh_all_moved():
        env.maps._stale.append(cells_xy.copy())
        env.maps.block_sums()

    t("block-sum refresh after a step (all robots in new cells)", refresh_all_moved)
    # observations
    t("observations, total", env.observations)
    t("  resized_local_maps (banded resize from the padded maps)", lambda: env.maps.resized_local_maps(cells_xy, p.obs_size))
    t("  neighbour_maps", lambda: neighbour_maps(x, p.comm_radius_m, p.obs_size))
    t("  boundary_maps", lambda: boundary_maps(cells_xy, w, p.local_map_size, p.obs_size))
    print(f"N = {n}, F = {len(env.scenario.features)}; first env + step + DCVT + observations (imports, "
          f"numba compile or cache load): {first:.2f} s")
    for name, ms in rows:
        print(f"{name:<62}{ms:8.3f} ms")


if __name__ == "__main__":
    main()
