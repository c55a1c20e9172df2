"""``madp bench infer``: which (sampler, S) costs nothing in closed loop, and how fast MADP then is.

1. **Closed-loop sweep.** For every (sampler, S) of the grid, decentralized MADP (the shipped
   ``cpu`` checkpoint unless another is given) runs the ``uniform`` suite through :func:`run_suite`
   (``envs`` environments, ``steps`` control steps; one resumable suite directory per setting under
   ``sweep_out``, so an interrupted sweep continues and a finished one is only read). The DDIM-50
   run also evaluates the centralized-masked pass, today's cheap approximation, for the step-time
   comparison.
2. **S\\*** of a sampler = the fewest steps whose mean final cost J(T)/J(0) lies within one standard
   error of DDIM-50's (SE of DDIM-50's mean over the environments). The paired difference to
   DDIM-50 on the same environments (mean, SE) is reported beside it.
3. **Latency** of one control step for one swarm of N = 32 (uniform launch, random weights:
   latency does not depend on them), per preset and mode, for DDIM-50 (the baseline, measured in
   the same run) and each sampler at its S\\*; medians of ``repeats`` calls.
4. The **best** setting: the (sampler, S\\*) of lowest cpu-preset decentralized latency.
5. ``cost_vs_steps.png``: mean cost ± SE against S per sampler, with DDIM-50's band.
6. With ``candidates`` (``--candidates 1,4,16``; ``K:S`` at S sampler steps): the latency of one whole decentralized MADP control
   step (cpu preset, the default sampler at its default S, or S given) with K samples per robot and each rule that chooses among
   them (:mod:`madp.policies.select`): :func:`bench_select`.
7. With ``robot`` (``--robot``, the default where onnxruntime imports): one robot's control step through
   the files of ``madp export`` on one thread, at the evaluation default's sampling, beside PyTorch's per robot
   (:mod:`madp.export.bench`); with a ``--madp`` policy file that carries a map prior, also under ``value``.
8. With ``roofline`` (``--roofline``): FLOPs, bytes and time of the evaluation default's control step by
   part (observations, perception, masks, encoder, denoiser × K × S, selection) against this machine's
   measured matmul peak, fp32 and bf16 (:mod:`madp.inference_bench.roofline`).

The paper reports 0.36 s per control step (N = 32) on an RTX 3090.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from madp.controllers import SAMPLING
from madp.errors import SettingError
from madp.models.bench import torch_threads, timed, bench_infer

from madp.policies import load, shipped_checkpoint

PAPER_LATENCY_S = 0.36
#: Default sweep: {sampler: S values}; DDIM-50 (the paper's sampler) is the baseline.
DEFAULT_GRID = {"dpm++": (3, 5, 10, 20), "ddim": (10, 20, 50)}
BASELINE = ("ddim", 50)
#: The standard error the S* comparison aims for (more environments lower it as 1/sqrt(n)).
SE_TARGET = 0.02


def parse_presets(text: str) -> tuple[str, ...]:
    """``"cpu,paper"`` -> ``("cpu", "paper")``: the presets whose latency is measured."""
    from madp.models.config import PRESETS

    names = tuple(p.strip() for p in text.split(",") if p.strip())
    if not names or any(p not in PRESETS for p in names):
        raise SettingError("presets", f"expected a comma-separated subset of {','.join(PRESETS)}, got {text!r}")
    return names


def parse_grid(text: str) -> dict[str, tuple[int, ...]]:
    """``"dpm++:5,10,20;ddim:10,20,50"`` -> ``{"dpm++": (5, 10, 20), "ddim": (10, 20, 50)}`` (DDIM-50 is
    always added). A one-line :class:`madp.errors.SettingError` on anything else."""
    from madp.models.samplers import SAMPLERS

    grid: dict[str, tuple[int, ...]] = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        name, _, values = part.partition(":")
        if name not in SAMPLERS or not values:
            raise SettingError("grid", f"expected 'sampler:S,S,...' with sampler in {list(SAMPLERS)}, got {part!r}")
        try:
            steps = tuple(sorted({int(v) for v in values.split(",")}))
        except ValueError:
            raise SettingError("grid", f"steps must be integers, got {values!r}") from None
        if min(steps) < 1:
            raise SettingError("grid", f"steps must be >= 1, got {values!r}")
        grid[name] = steps
    grid.setdefault(BASELINE[0], ())
    grid[BASELINE[0]] = tuple(sorted(set(grid[BASELINE[0]]) | {BASELINE[1]}))
    return grid


def parse_candidates(text: str) -> tuple[tuple[int, int | None], ...]:
    """``"1,4:3,8"`` -> ``((1, None), (4, 3), (8, None))``: the K whose selection latency is measured
    (each >= 1), each at S sampler steps when given as ``K:S``, else at the default S."""
    out = set()
    for part in (v.strip() for v in text.split(",")):
        if not part:
            continue
        k, _, steps = part.partition(":")
        try:
            pair = (int(k), int(steps) if steps else None)
        except ValueError:
            raise SettingError("candidates", f"expected comma-separated K or K:S whole numbers, got {text!r}") from None
        if pair[0] < 1 or (pair[1] is not None and pair[1] < 1):
            raise SettingError("candidates", f"expected K and S >= 1, got {part!r}")
        out.add(pair)
    if not out:
        raise SettingError("candidates", f"expected comma-separated K or K:S whole numbers, got {text!r}")
    return tuple(sorted(out, key=lambda p: (p[0], p[1] or 0)))


def bench_select(candidates: tuple[tuple[int, int | None], ...] = ((1, None), (4, None), (16, None)),
                 checkpoint: str | None = None, repeats: int = 5, threads: int | None = 2, device: str = "cpu",
                 num_robots: int = 32, seed: int = 0) -> list[dict]:
    """Median latency of one decentralized MADP control step for one swarm of ``num_robots`` robots
    (a random uniform-launch scenario) with K candidates per robot at S sampler steps, for every
    (K, S) of ``candidates`` (S ``None``: the default S) and every rule of
    :data:`madp.selection.RULES` that fits it (``none`` at K = 1; those that read a learned network
    when the checkpoint carries it, :data:`madp.selection.NEEDS`): the
    policy's whole call (:meth:`MADPPolicy.act_batch`: observations, the batched sampling of K copies,
    the choice), one untimed call first. The model: ``checkpoint``, else the shipped one, else an
    untrained ``cpu`` preset; the default sampler."""
    import torch

    from madp.models import MADP, madp_config
    from madp.policies import MADPPolicy, SamplingSettings, noise_generator
    from madp.selection import RULES, rule_names
    from madp.sim import CoverageEnv, Scenario, SimParams

    path = checkpoint or (str(shipped_checkpoint("madp")) if shipped_checkpoint("madp") else None)
    torch.manual_seed(seed)
    model = load(path, "madp", device)[0] if path else MADP(madp_config("cpu")).to(device)
    from madp.policies.checkpoint import load_learned
    from madp.selection import NEEDS

    carried = {needs: load_learned(path, needs, device) if path else None for needs in NEEDS}
    env = CoverageEnv(Scenario.random(seed, SimParams(num_robots=num_robots, num_features=32)))
    rows = []
    with torch_threads(threads):
        for k, steps in candidates:
            for select in rule_names(sees=("samples",)) if k == 1 else [
                    s for s in rule_names(sees=("own map", "true map", "world"))
                    if not RULES[s].needs or carried[RULES[s].needs] is not None]:
                sampling = SamplingSettings.of(select=select, candidates=k, sampling_steps=steps)
                policy = MADPPolicy(model, "decentralized", sampling, device=device,
                                    network=carried.get(RULES[select].needs))
                gen = noise_generator(seed)
                times = timed(lambda p=policy, g=gen: p.act_batch([env], [g]), 1, repeats, device)
                rows.append({"candidates": k, "select": select, "num_robots": num_robots, "sampler": policy.sampler,
                             "num_steps": policy.num_steps, "threads": torch.get_num_threads(), "device": device,
                             "checkpoint": path, "latency_s": float(np.median(times)), "latency_min_s": min(times)})
    return rows


def _final_costs(suite_dir: Path, controller: str) -> tuple[np.ndarray, float]:
    """Final costs ordered by environment, and the mean step ms, of one controller of a finished suite."""
    import pyarrow.parquet as pq

    t = pq.read_table(suite_dir / "results.parquet").to_pydict()
    rows = sorted((e, c, ms) for e, k, c, ms in zip(t["env"], t["controller"], t["final_cost"], t["mean_step_ms"])
                  if k == controller)
    return np.array([r[1] for r in rows]), float(np.mean([r[2] for r in rows]))


def closed_loop_sweep(checkpoint: str, sweep_out: Path, grid: dict[str, tuple[int, ...]], envs: int, steps: int,
                      workers: int = 0, progress: bool = True, device: str = "cpu") -> dict:
    """Run (or resume, or read) the sweep; returns the per-setting statistics and S* per sampler."""
    from madp.policies import SamplingSettings

    from madp.eval.runner import EvalConfig, run_suite

    settings = [BASELINE] + [(s, k) for s, ks in grid.items() for k in ks if (s, k) != BASELINE]
    costs, step_ms = {}, {}
    for sampler, s in settings:
        controllers = SAMPLING if (sampler, s) == BASELINE else ("madp",)  # DDIM-50: the centralized pass too
        cfg = EvalConfig(suite="uniform", out=str(sweep_out / f"{sampler}-{s}"), num_envs=envs, steps=steps,
                         controllers=controllers, madp=checkpoint,
                         sampling=SamplingSettings(sampler=sampler, sampling_steps=s), workers=workers, device=device)
        run_suite(cfg, "uniform", progress=progress)
        suite_dir = Path(cfg.out) / "uniform"
        costs[(sampler, s)], step_ms[(sampler, s)] = _final_costs(suite_dir, "madp")
        if (sampler, s) == BASELINE:
            central, step_ms["central"] = _final_costs(suite_dir, "madp_central")
    base = costs[BASELINE]
    n = base.size
    se_base = float(base.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    rows = []
    for (sampler, s), c in costs.items():
        d = c - base
        rows.append({"sampler": sampler, "steps": s, "n": int(c.size), "mean": float(c.mean()),
                     "se": float(c.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan"),
                     "diff_vs_baseline": float(d.mean()),
                     "diff_se": float(d.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan"),
                     "within_one_se": bool(abs(c.mean() - base.mean()) <= se_base),
                     "eval_ms_per_env_step": step_ms[(sampler, s)]})
    rows.sort(key=lambda r: (r["sampler"], r["steps"]))
    s_star = {smp: min((r["steps"] for r in rows if r["sampler"] == smp and r["within_one_se"]), default=None)
              for smp in sorted({r["sampler"] for r in rows})}
    return {"envs": n, "steps": steps, "baseline": {"sampler": BASELINE[0], "steps": BASELINE[1],
                                                    "mean": float(base.mean()), "se": se_base,
                                                    "se_at_most_0.02": bool(se_base <= SE_TARGET),
                                                    "envs_for_se_0.02": int(math.ceil(n * (se_base / SE_TARGET) ** 2))},
            "centralized_ddim50": {"mean": float(central.mean()), "eval_ms_per_env_step": step_ms["central"]},
            "rows": rows, "s_star": s_star}


def plot_cost_vs_steps(sweep: dict, path: Path) -> Path:
    """Mean final cost ± SE against S per sampler (log x), with DDIM-50's mean ± SE as a band."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.2))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    b = sweep["baseline"]
    ax.axhspan(b["mean"] - b["se"], b["mean"] + b["se"], color="0.85", label="DDIM-50 ± 1 SE")
    names = {"ddim": "DDIM", "dpm++": "DPM-Solver++(2M)"}
    for smp in sorted({r["sampler"] for r in sweep["rows"]}):
        rs = [r for r in sweep["rows"] if r["sampler"] == smp]
        ax.errorbar([r["steps"] for r in rs], [r["mean"] for r in rs], yerr=[r["se"] for r in rs], marker="o",
                    capsize=3, label=names.get(smp, smp))
    ax.set_xscale("log")
    ticks = sorted({r["steps"] for r in sweep["rows"]})
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.minorticks_off()
    ax.set_xlabel("sampler steps S")
    ax.set_ylabel(f"mean J({sweep['steps']})/J(0) ± SE")
    ax.set_title(f"decentralized MADP, uniform suite ({sweep['envs']} envs)")
    ax.legend(fontsize=9)
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=120)
    tmp.replace(path)
    return path


def bench_infer_all(checkpoint: str | None = None, sweep_out: str | Path = "runs/bench-infer",
                    grid: dict[str, tuple[int, ...]] | None = None, envs: int = 50, steps: int = 600,
                    repeats: int = 5, workers: int = 0, threads: int | None = 2, presets=("cpu", "paper"),
                    progress: bool = True, device: str = "cpu", sweep: bool = True,
                    candidates: tuple[tuple[int, int | None], ...] = (), robot: bool = False,
                    roofline: bool = False, roofline_after: int = 300) -> dict:
    """The whole ``madp bench infer`` (module docstring) on ``device`` (the sweep's rollouts and the
    latency). Without a checkpoint (none given and none shipped) the sweep is skipped and latency is
    reported for DDIM-50 only; with ``sweep=False`` the sweep is skipped and latency is reported for
    every setting of ``grid`` (DDIM-50 included). ``candidates``: also :func:`bench_select` at those K;
    ``robot``: also one robot's control step through ``madp export``'s files
    (:func:`madp.export.bench.bench_robot_runtime`); ``roofline``: also the control step's roofline at a
    ``uniform`` environment's start and after ``roofline_after`` expert steps (:func:`madp.inference_bench.roofline.roofline`)."""
    grid = grid or dict(DEFAULT_GRID)
    out: dict = {"paper_latency_s": PAPER_LATENCY_S, "sweep": None, "device": device, "swept": sweep}
    path = checkpoint or (str(shipped_checkpoint("madp")) if shipped_checkpoint("madp") else None)
    settings = [BASELINE]
    if not sweep:
        settings += [(smp, s) for smp, ks in grid.items() for s in ks if (smp, s) != BASELINE]
    elif path:
        load(path, "madp")  # a wrong or missing file is a one-line error before hours of work
        sweep_out = Path(sweep_out)
        out["checkpoint"] = path
        out["sweep"] = closed_loop_sweep(path, sweep_out, grid, envs, steps, workers, progress, device)
        out["plot"] = str(plot_cost_vs_steps(out["sweep"], sweep_out / "cost_vs_steps.png"))
        settings += [(smp, s) for smp, s in out["sweep"]["s_star"].items() if s is not None and (smp, s) != BASELINE]
    lat = []
    for preset in presets:
        for mode in ("decentralized", "centralized"):
            base = None
            for smp, s in settings:
                r = bench_infer(preset, mode, num_steps=s, sampler=smp, repeats=repeats, threads=threads, device=device)
                base = base or r["latency_s"]
                lat.append({**r, "sampler": smp, "speedup_vs_ddim50": base / r["latency_s"]})
    out["latency"] = lat
    if candidates:
        out["selection"] = bench_select(candidates, checkpoint, repeats, threads, device)
    if robot:
        from madp.export.bench import bench_robot_runtime
        from madp.policies.checkpoint import load_learned
        from madp.selection import NEEDS, rule_names

        out["robot_runtime"] = bench_robot_runtime(checkpoint, repeats=repeats)
        for needs in NEEDS:  # the rules of each learned network the checkpoint carries, through the export too
            if checkpoint is not None and load_learned(checkpoint, needs) is not None:
                for name in rule_names(needs=needs):
                    out[f"robot_runtime_{name}"] = bench_robot_runtime(checkpoint, repeats=repeats, select=name)
    if roofline:
        from .roofline import roofline as measure_roofline

        out["roofline"] = measure_roofline(checkpoint, roofline_after, repeats, threads, device)
    if out["sweep"] and any(x["preset"] == "cpu" and x["mode"] == "decentralized" for x in lat):
        cands = [x for x in lat if x["preset"] == "cpu" and x["mode"] == "decentralized"]
        best = min(cands, key=lambda x: x["latency_s"])
        out["best"] = {"sampler": best["sampler"], "steps": best["num_steps"]}
    return out


def format_table(r: dict) -> list[str]:
    """The lines ``madp bench infer`` prints for a :func:`bench_infer_all` result."""
    lines: list[str] = []
    sw = r["sweep"]
    if sw is None and r.get("swept", True) is False:
        lines.append("--no-sweep: latency of every --grid setting")
    elif sw is None:
        lines.append("no trained MADP checkpoint: no closed-loop sweep (latency of DDIM-50 only)")
    else:
        b = sw["baseline"]
        lines.append(f"decentralized MADP on uniform ({sw['envs']} envs, {sw['steps']} steps): mean J/J0 ± SE; "
                     f"DDIM-50 {b['mean']:.4f} ± {b['se']:.4f}")
        if not b["se_at_most_0.02"]:
            lines.append(f"note: DDIM-50's SE {b['se']:.3f} > 0.02; about {b['envs_for_se_0.02']} environments would reach it "
                         f"(--envs)")
        lines.append(f"{'sampler':<8}{'S':>4}{'mean':>9}{'SE':>8}{'diff vs DDIM-50':>22}{'within 1 SE':>13}{'eval ms/env-step':>18}")
        for x in sw["rows"]:
            lines.append(f"{x['sampler']:<8}{x['steps']:>4}{x['mean']:>9.4f}{x['se']:>8.4f}"
                         f"{x['diff_vs_baseline']:>+13.4f} ± {x['diff_se']:.4f}{'yes' if x['within_one_se'] else 'no':>13}"
                         f"{x['eval_ms_per_env_step']:>18.1f}")
        c = sw["centralized_ddim50"]
        lines.append(f"centralized-masked DDIM-50: {c['mean']:.4f}, {c['eval_ms_per_env_step']:.1f} eval ms/env-step; "
                     f"S* = {', '.join(f'{k}: {v}' for k, v in sw['s_star'].items())}; best: {r['best']['sampler']} "
                     f"S = {r['best']['steps']}; plot {r['plot']}")
    lines.append(f"{'preset':<7}{'mode':<15}{'sampler':<8}{'S':>4}{'latency ms':>12}{'vs DDIM-50':>12}"
                 f"   (median, N = 32, {'2 threads' if r.get('device', 'cpu') == 'cpu' else r['device']}; "
                 f"paper: {r['paper_latency_s']} s on an RTX 3090)")
    for x in r["latency"]:
        lines.append(f"{x['preset']:<7}{x['mode']:<15}{x['sampler']:<8}{x['num_steps']:>4}{1e3 * x['latency_s']:>12.1f}"
                     f"{x['speedup_vs_ddim50']:>11.1f}x")
    for i, x in enumerate(r.get("selection") or []):
        if i == 0:
            model = "untrained cpu preset" if x["checkpoint"] is None else x["checkpoint"]
            lines.append(f"{'K':>4}{'S':>3}  {'select':<12}{'latency ms':>12}   (one decentralized MADP control step, "
                         f"observations and choice included: {x['sampler']} at S steps, N = {x['num_robots']}, "
                         f"{x['threads']} threads, {model})")
        lines.append(f"{x['candidates']:>4}{x['num_steps']:>3}  {x['select']:<12}{1e3 * x['latency_s']:>12.1f}")
    if r.get("robot_runtime"):
        from madp.export.bench import format_robot_runtime

        lines += format_robot_runtime(r["robot_runtime"])
        lines += [line for key, x in r.items() if key.startswith("robot_runtime_") for line in format_robot_runtime(x)]
    if r.get("roofline"):
        from .roofline import format_roofline

        lines += format_roofline(r["roofline"])
    return lines
