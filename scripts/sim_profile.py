"""Where madp's simulator spends a call: thread-CPU medians of each stage of the clairvoyant step, J,
the DCVT step and the observation tensor (docs/sim-speed.md quotes its output).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/sim_profile.py [--seed S] [--repeats R]

One scenario (N = F = 32, 1024² world), 30 clairvoyant steps in, then each stage repeated on that state.
Thread-CPU time (not wall time) so that other jobs on the machine do not count; stages are timed
alone and warm, so they add up to a little less than the totals.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from madp.sim import ClairvoyantCVT, CoverageEnv, DecentralizedCVT, Scenario
from madp.sim.controllers import lloyd_velocity
from madp.sim.observations import boundary_maps, neighbour_maps, resize_maps
from madp.sim.voronoi import MASS_EPS, Cells, delaunay_neighbours, polygon_vertex_means, reduce_cells, world_cells


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
    env = CoverageEnv(Scenario.random(a.seed))
    expert, dcvt = ClairvoyantCVT(), DecentralizedCVT()
    for _ in range(30):
        env.step(expert(env))
    x, p = env.positions_m, env.params
    w, n = p.world_size, len(x)
    rows: list[tuple[str, float]] = []

    def t(name, fn):
        rows.append((name, cpu_ms(fn, a.repeats)))

    # clairvoyant goals and J: the world's Voronoi cells over the column prefix sums
    t("J (coverage_cost), total", env.cost)
    t("clairvoyant goals, total", lambda: expert.goals(env))
    t("  Delaunay neighbours (scipy)", lambda: delaunay_neighbours(x))
    t("  world_cells: duplicate check + Delaunay + Cells() setup", lambda: world_cells(x, w))
    cells = world_cells(x, w)
    t("  column_pairs (coarse pass every 16 columns)", cells.column_pairs)
    robot, column = cells.column_pairs()
    t("  row_intervals (bisector envelopes, rounding)", lambda: cells.row_intervals(robot, column))
    lo, hi = cells.row_intervals(robot, column)
    t("  interval_sums (prefix lookups, 3 moments)", lambda: env.prefix.interval_sums(column, lo, hi, 3))
    s = env.prefix.interval_sums(column, lo, hi, 3)
    t("  reduce_cells (bincounts)", lambda: reduce_cells(cells, robot, column, s, True, with_centroids=False))
    empty = np.flatnonzero(reduce_cells(cells, robot, column, s, False, with_centroids=False).mass < MASS_EPS)
    if len(empty):
        t(f"  polygon_vertex_means ({len(empty)} cells without importance)", lambda: polygon_vertex_means(cells, empty))
    goals = expert.goals(env)
    t("lloyd_velocity (with the oscillation check)", lambda: lloyd_velocity(env, goals))
    u = expert(env)
    saved = (env.positions_m.copy(), env.offset_m.copy(), list(env.history), env.maps._last_cells.copy(), env.steps)

    def step_only():
        env.positions_m, env.offset_m, env.history = saved[0].copy(), saved[1].copy(), list(saved[2])
        env.maps._last_cells, env.steps = saved[3].copy(), saved[4]
        env.step(u)

    t("env.step(u): move, clamp, sense, history", step_only)
    # DCVT goals: each robot's cell among its neighbours, on its own map (block prefix sums)
    t("DCVT goals, total (block sums up to date)", lambda: dcvt.goals(env))
    base = env.cells() - p.local_map_size // 2
    boxes = np.concatenate([np.maximum(base, 0), np.minimum(base + p.local_map_size, w)], axis=1).astype(np.float64)
    nbr = env.neighbours()
    t("  Cells() setup (N x N competitors)", lambda: Cells(x, np.broadcast_to(x[None], (n, n, 2)), nbr, boxes))
    dcells = Cells(x, np.broadcast_to(x[None], (n, n, 2)), nbr, boxes)
    dr, dc = dcells.column_pairs()
    t("  column_pairs", dcells.column_pairs)
    t("  row_intervals", lambda: dcells.row_intervals(dr, dc))
    dlo, dhi = dcells.row_intervals(dr, dc)
    t("  row_sums (four block-prefix lookups a pair)", lambda: env.maps.row_sums(dr, dc, dlo, dhi))
    cells_xy = env.cells()

    def refresh_all_moved():
        env.maps._stale.append(cells_xy.copy())
        env.maps._refresh()

    t("block-sum refresh after a step (all robots in new cells)", refresh_all_moved)
    # observations
    t("observations, total", env.observations)
    lm = env.local_maps()
    t("  local_maps crop (N x 256² float32 copy)", env.local_maps)
    t("  resize_maps (dense [32, 256] products)", lambda: resize_maps(lm, p.obs_size))
    t("  neighbour_maps", lambda: neighbour_maps(x, p.comm_radius_m, p.obs_size))
    t("  boundary_maps", lambda: boundary_maps(cells_xy, w, p.local_map_size, p.obs_size))
    print(f"N = {n}, F = {len(env.scenario.features)}; world (robot, column) pairs {len(robot)} "
          f"(bounds a pair: {cells.slope_up.shape[1]} above, {cells.slope_lo.shape[1]} below); "
          f"DCVT pairs {len(dr)}")
    for name, ms in rows:
        print(f"{name:<62}{ms:8.3f} ms")


if __name__ == "__main__":
    main()
