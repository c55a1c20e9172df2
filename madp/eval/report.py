"""Evaluation report: summary statistics, Markdown/JSON tables and PNG plots of one suite run.

The evaluation runner writes two Parquet tables into a suite directory ``runs/eval/<suite>/``
(the columns below):

* ``curves.parquet``: one row per (group, env, controller, step) with the normalised coverage cost
  ``cost = J(t)/J(0)``;
* ``results.parquet``: one row per (group, env, controller) with ``final_cost``, ``mean_step_ms`` and
  the scenario's parameters (``num_robots``, ``num_features``, ``sigma_lo``, ``sigma_hi``, ``city``,
  ``launch``).

:func:`write_report` turns them into

* ``summary.json``: the :func:`madp.eval.stats.summarize` dict (per (group, controller) and per
  controller over the whole suite: n, mean final cost, standard error, Student-t 95 % interval,
  median, std, mean step ms) plus metadata (row counts, steps, the paper's numbers, files written).
  Not-a-number values (the standard error of a single environment) are written as ``null``.
* ``summary.md``: :func:`madp.eval.tables.markdown_table` (a pivot with rows = groups + ``all``,
  columns = controllers, cells ``mean ± SE [lo, hi]``, and a paper column where the paper has a number,
  :mod:`madp.eval.paper`; a second table with the mean wall time per control step; for the ``scale``
  suite the relative-improvement matrices) followed by links to the plots.
* PNG plots (:mod:`madp.eval.plots`): ``cost_<group-slug>.png`` per group (mean cost vs step per
  controller with its shaded per-step 95 % band, mean ± 1.96·SE across environments, as the paper's
  Fig. 3), ``cost_all.png`` when the
  suite has more than ``all_threshold`` groups (default 8), and per suite ``sigma_boxplot.png``,
  ``cities_heatmap.png`` (a red dot on each city's best deployable controller; the summary's "best in
  k of n cities") or the paper's Fig. 7 as ``scale_improvement_dcvt.png`` (left: MADP over DCVT) and
  ``scale_improvement_lpac.png`` (right: over LPAC-K3), on one colour scale, each drawn when its
  baseline ran (MADP is ``madp`` when present, else ``madp_central``), or ``symmetry.png`` (each
  launch layout's images: mean ± SE per image beside the layout's mean, :func:`madp.eval.stats.symmetry_check`).

Statistics, tables, plots and the paper's numbers live in their own modules; this one reads the
tables and writes the files.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from madp.controllers import display_name

from .paper import PAPER_CONTROLLERS, PAPER_RESULTS
from .plots import color_map, plot_cities_heatmap, plot_cost, plot_scale_improvement, plot_sigma_boxplot, \
    plot_symmetry, scale_limit, unique_slugs
from .stats import CONFIDENCE, column, cost_curve_bands, has_column, order_controllers, order_groups, sampling_used, \
    select_suite, summarize
from .tables import markdown_table, sampling_markdown

__all__ = ["write_report"]


def _json_safe(obj: Any) -> Any:
    """Convert NumPy values, paths and tuples for JSON; NaN and ±inf become ``None`` (``null``)."""
    if isinstance(obj, Mapping):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return _json_safe(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_report(suite_dir: Path, suite: str, *, all_threshold: int = 8,
                 confidence: float = CONFIDENCE) -> dict[str, Path]:
    """Write ``summary.json``, ``summary.md`` and the PNG plots of one suite into ``suite_dir``.

    Args:
        suite_dir: directory holding ``results.parquet`` (required) and ``curves.parquet`` (without
            it the cost-vs-step plots are skipped).
        suite: suite name; rows of other suites in the tables are ignored. Selects the suite-specific
            plots: ``sigma`` → ``sigma_boxplot.png``, ``cities`` → ``cities_heatmap.png``, ``scale`` →
            ``scale_improvement_<baseline>.png`` for ``dcvt`` / ``lpac`` when ``madp`` and the
            baseline are present.
        all_threshold: also draw ``cost_all.png`` (mean over every environment of the suite) when
            the suite has more than this many groups.
        confidence: two-sided level of the intervals and bands.

    Returns:
        ``{file name: path}`` of every file written, in writing order (plots first, then
        ``summary.md`` and ``summary.json``). Plots that cannot be drawn (no data, a baseline or
        MADP missing) are skipped.
    """
    suite_dir = Path(suite_dir)
    results_path, curves_path = suite_dir / "results.parquet", suite_dir / "curves.parquet"
    results, _ = select_suite(pq.read_table(results_path), suite)
    summary = summarize(results, suite, confidence)
    summary["sampling"] = sampling_used(results)
    controllers, groups = summary["controllers"], summary["groups"]
    colors = color_map(order_controllers(list(controllers) + (
        column(pq.read_table(curves_path, columns=["controller"]), "controller").tolist()
        if curves_path.is_file() else [])))
    written: dict[str, Path] = {}

    def record(path: Path | None) -> None:
        if path is not None:
            written[path.name] = path

    # Cost vs step per group (and pooled).
    curve_info: dict[str, Any] = {"present": curves_path.is_file()}
    if curves_path.is_file():
        curves, _ = select_suite(pq.read_table(curves_path), suite)
        c_group = column(curves, "group")
        c_ctrl = column(curves, "controller")
        c_env = column(curves, "env").astype(np.int64)
        c_step = column(curves, "step").astype(np.int64)
        c_cost = column(curves, "cost").astype(float)
        curve_groups = groups + [g for g in order_groups(c_group.tolist()) if g not in set(groups)]
        g_names, g_inv = np.unique(c_group, return_inverse=True)
        g_inv = g_inv.reshape(-1)
        env_lo = int(c_env.min()) if c_env.size else 0
        env_span = int(c_env.max()) - env_lo + 1 if c_env.size else 1
        env_key = g_inv * env_span + (c_env - env_lo)  # unique per (group, env)
        draw_all = len(curve_groups) > all_threshold
        slugs = unique_slugs(curve_groups, reserved=("all",) if draw_all else ())
        curve_info.update(rows=int(c_step.size), max_step=int(c_step.max()) if c_step.size else None,
                          slugs=slugs)
        order = np.argsort(g_inv, kind="stable")
        bounds = np.searchsorted(g_inv[order], np.arange(g_names.size + 1))
        for g in curve_groups:
            k = int(np.searchsorted(g_names, g))
            sel = order[bounds[k]:bounds[k + 1]]
            bands = cost_curve_bands(c_ctrl[sel], env_key[sel], c_step[sel], c_cost[sel], confidence)
            if not bands:
                continue
            n_env = np.unique(c_env[sel]).size
            record(plot_cost(suite_dir / f"cost_{slugs[g]}.png", bands,
                              f"{suite} · {g}: mean cost vs step (n = {n_env} env{'s' * (n_env != 1)})",
                              colors))
        if draw_all and c_step.size:
            bands = cost_curve_bands(c_ctrl, env_key, c_step, c_cost, confidence)
            n_env = np.unique(env_key).size
            record(plot_cost(suite_dir / "cost_all.png", bands,
                              f"{suite} · all {len(curve_groups)} groups: mean cost vs step (n = {n_env} envs)",
                              colors))

    # Suite-specific plots.
    if suite == "sigma":
        record(plot_sigma_boxplot(suite_dir / "sigma_boxplot.png", column(results, "final_cost").astype(float),
                                   column(results, "group"), column(results, "controller"), groups,
                                   controllers, summary["groups_meta"], colors, suite))
    elif suite == "cities":
        record(plot_cities_heatmap(suite_dir / "cities_heatmap.png", summary, suite))
    elif suite == "faults":
        from madp.sim import SimParams

        from .faults import plot_faults

        record(plot_faults(suite_dir / "faults.png", column(results, "final_cost").astype(float),
                           column(results, "group"), column(results, "controller"), controllers, colors, suite,
                           SimParams().dt_s))
    elif suite == "symmetry":
        record(plot_symmetry(suite_dir / "symmetry.png", summary["symmetry"], colors, suite))
    elif suite == "scale":
        matrices = summary.get("scale_improvement") or {}
        lim = scale_limit(matrices.values())
        for baseline, m in matrices.items():
            record(plot_scale_improvement(suite_dir / f"scale_improvement_{baseline}.png", m, suite, lim))

    # Markdown.
    md = [markdown_table(summary, suite).rstrip("\n")]
    if summary["sampling"]:
        md += ["", sampling_markdown(summary["sampling"])]
    if suite == "faults":
        from .faults import faults_sections

        entries, sections = faults_sections(results, controllers)
        summary.update(entries)
        for section in sections:
            md += ["", section]
    plots = [name for name in written if name.endswith(".png")]
    if plots:
        md += ["", "Plots:", ""] + [f"![{name[:-4]}]({name})" for name in plots]
    md_path = suite_dir / "summary.md"
    md_path.write_text("\n".join(md).rstrip("\n") + "\n", encoding="utf-8")
    record(md_path)

    # JSON (last, so it can list every file).
    json_path = suite_dir / "summary.json"
    doc = dict(summary)
    doc["metadata"] = {
        "suite_dir": str(suite_dir),
        "results_rows": results.num_rows,
        "curves": curve_info,
        "steps": sorted(set(column(results, "steps").astype(int).tolist())) if has_column(results, "steps") else None,
        "paper": PAPER_RESULTS.get(suite),
        "paper_controllers": {c: display_name(c) for c in PAPER_CONTROLLERS},
        "files": sorted(list(written) + [json_path.name]),
    }
    json_path.write_text(json.dumps(_json_safe(doc), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    record(json_path)
    return written
