"""``madp bench sim``: the simulator's hot paths, madp beside the Coverage Control Library, same run.

For each of a few random scenarios (N = F = 32 on a 1024² world by default) both simulators start
from the same positions on the same features. Along the clairvoyant expert's trajectory each step
times J, the observation tensor and the clairvoyant step; a second pass times the DCVT step along the
DCVT trajectory. Every operation is timed on the library and on madp back to back, alternating which
goes first, so machine load falls on both alike: the ratio of medians is fair on a busy machine even
where the absolute milliseconds are not idle figures. Both run on one thread (a per-core comparison, as
datagen runs one worker per core): madp's numpy and numba kernels are single-threaded, the library's
torch is set to one thread and its OpenMP runtime is capped by ``OMP_THREAD_LIMIT=1`` (unless set
otherwise before it loads); uncapped, its DecentralizedCVT starts one thread per robot. madp's kernels
are compiled (or loaded from numba's cache) by the untimed first calls. Without the library
(``madp[reference]``, see :mod:`madp.sim.reference`) only madp's figures are measured.
"""

from __future__ import annotations

import time
import warnings
from typing import Callable

import numpy as np

from .controllers import ClairvoyantCVT, DecentralizedCVT
from .env import CoverageEnv
from .scenario import Scenario

OPERATIONS = ("clairvoyant_step", "dcvt_step", "cost_J", "observations")


def _ms(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) * 1e3


class _Pair:
    """Timings of one operation on both sides, taken back to back in alternating order."""

    def __init__(self) -> None:
        self.turn = 0
        self.times: dict[str, dict[str, list[float]]] = {op: {"madp": [], "library": []} for op in OPERATIONS}

    def time(self, op: str, madp_fn: Callable[[], object], lib_fn: Callable[[], object] | None) -> None:
        calls = [("madp", madp_fn)] + ([("library", lib_fn)] if lib_fn is not None else [])
        if self.turn % 2:
            calls.reverse()
        self.turn += 1
        for side, fn in calls:
            self.times[op][side].append(_ms(fn))


def _scenario_pass(pair: _Pair, sc: Scenario, steps: int, use_library: bool) -> None:
    from .reference import LibraryEnv

    env = CoverageEnv(sc)
    lib = LibraryEnv(sc) if use_library else None
    # One untimed call of each state-free operation: first-call costs (caches, torch's kernels) aside.
    env.cost(), env.observations()
    if lib is not None:
        lib.cost(), lib.observations()
    expert = ClairvoyantCVT()
    for _ in range(steps):
        pair.time("cost_J", env.cost, lib.cost if lib else None)
        pair.time("observations", env.observations, lib.observations if lib else None)
        pair.time("clairvoyant_step", lambda: env.step(expert(env)), lib.step_clairvoyant if lib else None)
    env.reset()
    if lib is not None:
        lib.reset()
    dcvt = DecentralizedCVT()
    for _ in range(steps):
        pair.time("dcvt_step", lambda: env.step(dcvt(env)), lib.step_dcvt if lib else None)


def bench_sim(scenarios: int = 3, steps: int = 20, seed: int = 12345, library: bool | None = None,
              progress: Callable[[int, int], None] | None = None) -> dict:
    """Time the four operations on ``scenarios`` random scenarios (seeds seed, seed+1, …) × ``steps``.

    ``library``: None uses the Coverage Control Library when it imports, False never, True requires it
    (ImportError with the reason otherwise). Returns ``{"library": version or None, "library_note":
    why not, "scenarios", "steps", "seed", "operations": {op: {"madp_ms", "madp_p90_ms",
    "library_ms", "library_p90_ms", "ratio", "samples"}}}``: medians in ms; ``ratio`` = library median /
    madp median (None without the library).
    """
    from . import reference

    version, note = None, ""
    if library is not False:
        try:
            version = reference.import_library(thread_limit="1").__version__
        except ImportError as e:
            if library:
                raise
            note = str(e).splitlines()[0]
    else:
        note = "not asked for (--no-library)"
    if version is not None:
        import torch

        torch.set_num_threads(1)  # the library's observation tensor is torch: one core, as madp's kernels
    pair = _Pair()
    with warnings.catch_warnings():
        # coverage_control builds its neighbour maps with torch.sparse_coo_tensor, which warns each call.
        warnings.filterwarnings("ignore", message="Sparse invariant checks")
        for k in range(scenarios):
            _scenario_pass(pair, Scenario.random(seed + k), steps, version is not None)
            if progress:
                progress(k + 1, scenarios)
    ops = {}
    for op in OPERATIONS:
        m, lib = np.array(pair.times[op]["madp"]), np.array(pair.times[op]["library"])
        r = {"madp_ms": float(np.median(m)), "madp_p90_ms": float(np.percentile(m, 90)), "samples": len(m),
             "library_ms": None, "library_p90_ms": None, "ratio": None}
        if len(lib):
            r.update(library_ms=float(np.median(lib)), library_p90_ms=float(np.percentile(lib, 90)),
                     ratio=float(np.median(lib) / np.median(m)))
        ops[op] = r
    return {"library": version, "library_note": note, "scenarios": scenarios, "steps": steps, "seed": seed,
            "library_thread_limit": reference.thread_limit_at_import if version else None, "operations": ops}


def format_table(res: dict) -> list[str]:
    """The lines ``madp bench sim`` prints for a :func:`bench_sim` result."""
    head = (f"{res['scenarios']} scenarios x {res['steps']} steps (seeds {res['seed']}..{res['seed'] + res['scenarios'] - 1}),"
            f" N = F = 32, medians of {res['operations']['cost_J']['samples']} calls each")
    if res["library"] is None:
        lines = [head, f"Coverage Control Library not measured: {res['library_note']}",
                 f"{'what':<18}{'madp ms':>10}{'p90 ms':>9}"]
        lines += [f"{op:<18}{r['madp_ms']:>10.2f}{r['madp_p90_ms']:>9.2f}" for op, r in res["operations"].items()]
        return lines
    limit = res["library_thread_limit"]
    threads = "one thread each" if limit == "1" else f"library's OpenMP thread limit {limit or 'unset'}"
    lines = [head + f", interleaved with coverage_control {res['library']} ({threads})",
             f"{'what':<18}{'library ms':>11}{'madp ms':>10}{'ratio':>8}"]
    lines += [f"{op:<18}{r['library_ms']:>11.2f}{r['madp_ms']:>10.2f}{r['ratio']:>7.1f}x"
              for op, r in res["operations"].items()]
    return lines
