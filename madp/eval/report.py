"""Evaluation report: summary statistics, Markdown/JSON tables and PNG plots of one suite run.

The evaluation runner writes two Parquet tables into a suite directory ``runs/eval/<suite>/``
(SPEC §5):

* ``curves.parquet``: one row per (group, env, controller, step) with the normalised coverage cost
  ``cost = J(t)/J(0)``;
* ``results.parquet``: one row per (group, env, controller) with ``final_cost``, ``mean_step_ms`` and
  the scenario's parameters (``num_robots``, ``num_features``, ``sigma_lo``, ``sigma_hi``, ``city``,
  ``launch``).

:func:`write_report` turns them into

* ``summary.json``: the :func:`summarize` dict (per (group, controller) and per controller over the
  whole suite: n, mean final cost, standard error, Student-t 95 % interval, median, std, mean step
  ms) plus metadata (row counts, steps, the paper's numbers, files written). Not-a-number values
  (the standard error of a single environment) are written as ``null``.
* ``summary.md``: :func:`markdown_table` (a pivot with rows = groups + ``all``, columns = controllers,
  cells ``mean ± SE [lo, hi]``, and a paper column where SPEC §5 has a number; a second table with
  the mean wall time per control step; for the ``scale`` suite the relative-improvement matrices)
  followed by links to the plots.
* PNG plots (Agg, 120 dpi): ``cost_<group-slug>.png`` per group (mean cost vs step per controller with a
  shaded per-step 95 % t band across environments), ``cost_all.png`` when the suite has more than
  ``all_threshold`` groups (default 8), and per suite ``sigma_boxplot.png``, ``cities_heatmap.png``
  or ``scale_improvement_<baseline>.png`` (baseline ``dcvt`` / ``lpac``; MADP is ``madp`` when present,
  else ``madp_central``: the first controller of kind ``madp``).

Ordering (deterministic, independent of the row order of the tables):

* controllers: the registry's order (:data:`madp.controllers.NAMES`), then any other name alphabetically;
* groups: *natural* sort of the group names (digit runs compare as numbers, text case-insensitively),
  so ``sigma_5-10 < sigma_10-20 < sigma_20-30``, ``N16_F32 < N16_F128 < N32_F16`` and cities are
  alphabetical.

Everything is computed from column arrays with NumPy grouping (``np.unique`` / ``np.add.reduceat`` /
fancy-index scatter into ``controller x env x step`` cubes); there are no Python loops over rows.
The plots use :class:`matplotlib.figure.Figure` with an explicit Agg canvas, so importing this module
neither selects nor touches the global pyplot backend.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy import stats

from madp.controllers import CONTROLLERS, NAMES

__all__ = [
    "PAPER_CONTROLLERS",
    "PAPER_RESULTS",
    "CONFIDENCE",
    "order_controllers",
    "order_groups",
    "group_slug",
    "grouped_stats",
    "summarize",
    "paper_results",
    "cost_curve_bands",
    "scale_improvement_matrix",
    "markdown_table",
    "write_report",
]

#: Controllers the paper reports (SPEC §5), in the order of the paper column (the registry's ``paper``).
PAPER_CONTROLLERS: tuple[str, ...] = tuple(dict.fromkeys(c.paper for c in CONTROLLERS.values() if c.paper))

#: The paper's normalised cost after 600 steps (SPEC §5). ``PAPER_RESULTS[suite]`` maps a row of the
#: Markdown pivot (a group name, or ``"all"`` for the whole suite) to ``{controller: value}``;
#: ``lpac`` is the paper's LPAC-K3. The ``uniform`` and ``cities`` numbers are suite means
#: (row ``all``); the ``launch`` numbers are per launch group. The launch suite's ``uniform`` group
#: is the configuration of the ``uniform`` suite (N = F = 32, σ ∈ [40, 60], uniform launch), so it
#: carries that suite's numbers. ``sigma`` ("MADP best in every range") and ``scale`` (relative
#: improvement) have no single numbers.
PAPER_RESULTS: dict[str, dict[str, dict[str, float]]] = {
    "uniform": {"all": {"dcvt": 0.72, "lpac": 0.48, "madp": 0.46}},
    "cities": {"all": {"dcvt": 0.63, "lpac": 0.45, "madp": 0.39}},
    "launch": {
        "uniform": {"dcvt": 0.72, "lpac": 0.48, "madp": 0.46},
        "square": {"dcvt": 0.71, "lpac": 0.46, "madp": 0.44},
        "line": {"dcvt": 0.76, "lpac": 0.20, "madp": 0.17},
    },
}

#: Two-sided confidence level of every interval (Student t).
CONFIDENCE = 0.95

#: Row label of the whole-suite row of the Markdown tables (and key of ``summary["overall"]``).
ALL_ROW = "all"

_EXTRA_COLORS = ("#2ca02c", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f")
_META_COLUMNS = ("num_robots", "num_features", "sigma_lo", "sigma_hi", "city", "launch")
_DPI = 120


# --------------------------------------------------------------------------------------------------
# Ordering and names
# --------------------------------------------------------------------------------------------------


def order_controllers(names: Iterable[str]) -> list[str]:
    """Distinct controller names in canonical order (the registry's, :data:`madp.controllers.NAMES`),
    then any other name alphabetically."""
    uniq = set(names)
    known = [c for c in NAMES if c in uniq]
    return known + sorted(uniq - set(NAMES))


def _natural_key(name: str) -> tuple:
    # re.split with a capturing group puts text at even and digit runs at odd positions, so the
    # tuple compares str with str and int with int only.
    parts = re.split(r"(\d+)", name)
    return (tuple(int(p) if i % 2 else p.casefold() for i, p in enumerate(parts)), name)


def order_groups(names: Iterable[str]) -> list[str]:
    """Distinct group names in natural order (numbers numerically, text case-insensitively)."""
    return sorted(set(names), key=_natural_key)


def group_slug(name: str) -> str:
    """File-name slug of a group: lower case, runs of other than ``[a-z0-9._-]`` become ``-``.

    ``"Boston, MA" -> "boston-ma"``, ``"sigma_10-20" -> "sigma_10-20"``, ``"N32_F64" -> "n32_f64"``.
    """
    slug = re.sub(r"[^a-z0-9._-]+", "-", name.casefold())
    slug = re.sub(r"-{2,}", "-", slug).strip("-._")
    return slug or "group"


def _unique_slugs(groups: Sequence[str], reserved: Iterable[str] = ()) -> dict[str, str]:
    """Collision-free slugs for ``groups`` (in order), avoiding ``reserved`` (suffix ``-2``, ``-3``...)."""
    used = set(reserved)
    out: dict[str, str] = {}
    for g in groups:
        base = group_slug(g)
        slug, k = base, 2
        while slug in used:
            slug, k = f"{base}-{k}", k + 1
        used.add(slug)
        out[g] = slug
    return out


def _display(controller: str) -> str:
    return CONTROLLERS[controller].display if controller in CONTROLLERS else controller


def _color_map(controllers: Sequence[str]) -> dict[str, str]:
    extra = iter(_EXTRA_COLORS * 4)
    return {c: CONTROLLERS[c].color if c in CONTROLLERS else next(extra) for c in controllers}


# --------------------------------------------------------------------------------------------------
# Table access
# --------------------------------------------------------------------------------------------------


def _column(table: pa.Table | Mapping[str, Any], name: str) -> np.ndarray:
    """One column as a NumPy array (strings as ``str`` arrays, numbers as they are)."""
    if isinstance(table, pa.Table):
        if name not in table.column_names:
            raise KeyError(f"table has no column {name!r} (columns: {', '.join(table.column_names)})")
        col = table.column(name)
        if pa.types.is_string(col.type) or pa.types.is_large_string(col.type) or \
                pa.types.is_dictionary(col.type):
            return np.asarray(col.to_pylist(), dtype=str) if len(col) else np.zeros(0, dtype=str)
        return col.to_numpy()
    if name not in table:
        raise KeyError(f"table has no column {name!r}")
    arr = np.asarray(table[name])
    return arr.astype(str) if arr.dtype.kind in "OU" else arr


def _has_column(table: pa.Table | Mapping[str, Any], name: str) -> bool:
    return name in (table.column_names if isinstance(table, pa.Table) else table)


def _select_suite(table: pa.Table | Mapping[str, Any], suite: str | None) -> tuple[Any, str]:
    """Rows of ``suite`` (all rows when ``suite`` is None and the table holds one suite)."""
    names = _column(table, "suite")
    present = sorted(set(names.tolist()))
    if suite is None:
        if len(present) != 1:
            raise ValueError(f"table holds suites {present}; pass suite= to choose one")
        return table, present[0]
    if present == [suite]:
        return table, suite
    if suite not in present:
        raise ValueError(f"table holds no rows of suite {suite!r} (suites present: {present})")
    mask = names == suite
    if isinstance(table, pa.Table):
        return table.filter(pa.array(mask)), suite
    return {k: np.asarray(v)[mask] for k, v in table.items()}, suite


# --------------------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------------------


def _t_quantile(n: np.ndarray, confidence: float) -> np.ndarray:
    """Two-sided Student-t quantile for ``n`` samples (nan where n < 2)."""
    n = np.asarray(n, dtype=float)
    df = np.where(n >= 2, n - 1.0, np.nan)
    return stats.t.ppf(0.5 + confidence / 2.0, df)


def grouped_stats(keys: np.ndarray, values: np.ndarray, confidence: float = CONFIDENCE) -> dict[str, np.ndarray]:
    """Per-key statistics of ``values`` (vectorised; one sort).

    Args:
        keys: integer key of each sample (any values; the result is ordered by ascending key).
        values: float sample values.
        confidence: two-sided level of the t interval.

    Returns:
        dict of arrays aligned with ``key`` (the sorted distinct keys): ``n``, ``mean``, ``std``
        (ddof = 1), ``se = std / sqrt(n)``, ``ci_lo``/``ci_hi`` (``mean ∓ t_{n-1} se``), ``median``.
        For ``n = 1`` the std and SE are nan and the interval is ``[mean, mean]``.
    """
    keys = np.asarray(keys)
    values = np.asarray(values, dtype=float)
    if keys.size == 0:
        empty = np.zeros(0)
        return {"key": keys[:0], "n": np.zeros(0, dtype=np.int64), "mean": empty, "std": empty, "se": empty,
                "ci_lo": empty, "ci_hi": empty, "median": empty}
    order = np.lexsort((values, keys))
    k, v = keys[order], values[order]
    uniq, start, counts = np.unique(k, return_index=True, return_counts=True)
    mean = np.add.reduceat(v, start) / counts
    ss = np.add.reduceat((v - np.repeat(mean, counts)) ** 2, start)
    with np.errstate(invalid="ignore", divide="ignore"):
        std = np.where(counts > 1, np.sqrt(ss / np.maximum(counts - 1, 1)), np.nan)
        se = std / np.sqrt(counts)
    half = np.where(counts > 1, _t_quantile(counts, confidence) * se, 0.0)
    median = 0.5 * (v[start + (counts - 1) // 2] + v[start + counts // 2])
    return {"key": uniq, "n": counts.astype(np.int64), "mean": mean, "std": std, "se": se,
            "ci_lo": mean - half, "ci_hi": mean + half, "median": median}


def _group_meta(table, group: np.ndarray, groups: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Scenario parameters of each group (a scalar when constant over the group, else a sorted list)."""
    meta: dict[str, dict[str, Any]] = {g: {} for g in groups}
    g_names, g_idx = np.unique(group, return_inverse=True)
    g_idx = g_idx.reshape(-1)
    for name in _META_COLUMNS:
        if not _has_column(table, name):
            continue
        vals, v_idx = np.unique(_column(table, name), return_inverse=True)
        pairs = np.unique(np.stack([g_idx, v_idx.reshape(-1)], axis=1), axis=0)  # distinct (group, value)
        split = np.searchsorted(pairs[:, 0], np.arange(g_names.size + 1))
        for k, g in enumerate(g_names.tolist()):
            v = [vals[i].item() for i in pairs[split[k]:split[k + 1], 1]]
            meta[g][name] = v[0] if len(v) == 1 else v
    return meta


def summarize(results_table: pa.Table | Mapping[str, Any], suite: str | None = None,
              confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Summary statistics of a suite's ``results`` table.

    Args:
        results_table: the ``results.parquet`` table (a :class:`pyarrow.Table`, or a mapping of
            column name to array) with at least ``suite``, ``group``, ``env``, ``controller``,
            ``final_cost`` and ``mean_step_ms``.
        suite: which suite to summarise; may be omitted when the table holds exactly one.
        confidence: two-sided level of the Student-t intervals.

    Returns:
        ``{"suite", "confidence", "controllers", "groups", "group_order", "groups_meta",
        "by_group": {group: {controller: stats}}, "overall": {controller: stats}}`` and, for the
        ``scale`` suite, ``"scale_improvement": {baseline: matrix dict}`` (see
        :func:`scale_improvement_matrix`). ``stats`` holds ``n`` (environments), ``mean``, ``se``,
        ``ci_lo``, ``ci_hi``, ``median``, ``std`` of ``final_cost`` and ``mean_step_ms`` (mean over
        the environments). ``overall`` pools every (group, env) of the suite. Controllers are in
        :func:`order_controllers` order, groups in :func:`order_groups` (natural) order; a
        (group, controller) pair without rows is absent. NaN marks undefined values (SE of n = 1).

    Raises:
        ValueError: for rows of other suites only, or a duplicated (group, env, controller).
    """
    table, suite = _select_suite(results_table, suite)
    group = _column(table, "group")
    env = _column(table, "env").astype(np.int64)
    controller = _column(table, "controller")
    final = _column(table, "final_cost").astype(float)
    step_ms = _column(table, "mean_step_ms").astype(float)

    groups = order_groups(group.tolist())
    controllers = order_controllers(controller.tolist())
    g_rank = np.array([groups.index(g) for g in np.unique(group).tolist()], dtype=np.int64)
    c_rank = np.array([controllers.index(c) for c in np.unique(controller).tolist()], dtype=np.int64)
    gi = g_rank[np.unique(group, return_inverse=True)[1].reshape(-1)]  # canonical group index per row
    ci = c_rank[np.unique(controller, return_inverse=True)[1].reshape(-1)]

    order = np.lexsort((ci, env, gi))
    same = (np.diff(gi[order]) == 0) & (np.diff(env[order]) == 0) & (np.diff(ci[order]) == 0)
    if same.any():
        r = order[int(np.argmax(same))]
        raise ValueError(f"suite {suite!r}: duplicate results row for group {group[r]!r}, env {int(env[r])}, "
                         f"controller {controller[r]!r}")

    def _records(keys: np.ndarray, n_keys: int) -> list[dict[str, Any] | None]:
        st = grouped_stats(keys, final, confidence)
        ms = np.bincount(keys, weights=step_ms, minlength=n_keys) / np.maximum(
            np.bincount(keys, minlength=n_keys), 1)
        out: list[dict[str, Any] | None] = [None] * n_keys
        for j, key in enumerate(st["key"].tolist()):
            out[key] = {"n": int(st["n"][j]), "mean": float(st["mean"][j]), "se": float(st["se"][j]),
                        "ci_lo": float(st["ci_lo"][j]), "ci_hi": float(st["ci_hi"][j]),
                        "median": float(st["median"][j]), "std": float(st["std"][j]),
                        "mean_step_ms": float(ms[key])}
        return out

    n_c = len(controllers)
    per_pair = _records(gi * n_c + ci, len(groups) * n_c)
    per_ctrl = _records(ci, n_c)
    by_group = {g: {c: per_pair[a * n_c + b] for b, c in enumerate(controllers) if per_pair[a * n_c + b]}
                for a, g in enumerate(groups)}
    overall = {c: per_ctrl[b] for b, c in enumerate(controllers) if per_ctrl[b]}

    summary: dict[str, Any] = {
        "suite": suite,
        "confidence": confidence,
        "controllers": controllers,
        "groups": groups,
        "group_order": "natural sort of group names (digit runs numerically, text case-insensitively)",
        "groups_meta": _group_meta(table, group, groups),
        "by_group": by_group,
        "overall": overall,
    }
    # MADP in the scale matrices: the decentralized policy when it ran, else the centralized-masked one.
    method = next((c for c in controllers if c in CONTROLLERS and CONTROLLERS[c].kind == "madp"), None)
    if suite == "scale" and method is not None and \
            _has_column(table, "num_robots") and _has_column(table, "num_features"):
        imp = {}
        for baseline in ("dcvt", "lpac"):
            if baseline in controllers:
                m = scale_improvement_matrix(table, baseline, method)
                if np.isfinite(m["improvement"]).any():
                    imp[baseline] = m
        if imp:
            summary["scale_improvement"] = imp
    return summary


def paper_results(suite: str, row: str) -> dict[str, float]:
    """The paper's numbers for one Markdown row (a group name or ``"all"``); ``{}`` when none."""
    return dict(PAPER_RESULTS.get(suite, {}).get(row, {}))


def cost_curve_bands(controller: np.ndarray, env_key: np.ndarray, step: np.ndarray, cost: np.ndarray,
                     confidence: float = CONFIDENCE) -> dict[str, dict[str, np.ndarray]]:
    """Mean normalised cost per step and its per-step t interval across environments.

    The rows are scattered into a ``controller x env x step`` cube (nan where absent), so every
    statistic is a reduction over the env axis.

    Args:
        controller: controller name of each curve row.
        env_key: integer identity of the environment of each row (unique across groups when several
            groups are pooled).
        step: step index of each row.
        cost: ``J(t)/J(0)`` of each row.
        confidence: two-sided level of the band.

    Returns:
        ``{controller: {"step", "mean", "lo", "hi", "n"}}`` in canonical controller order; ``step``
        holds the steps at which the controller has at least one environment. With one environment
        at a step, ``lo = hi = mean``.
    """
    controller = np.asarray(controller).astype(str)
    if controller.size == 0:
        return {}
    c_names, c_idx = np.unique(controller, return_inverse=True)
    _, e_idx = np.unique(np.asarray(env_key), return_inverse=True)
    steps, s_idx = np.unique(np.asarray(step), return_inverse=True)
    cube = np.full((c_names.size, int(e_idx.max()) + 1, steps.size), np.nan)
    cube[c_idx.reshape(-1), e_idx.reshape(-1), s_idx.reshape(-1)] = np.asarray(cost, dtype=float)
    valid = np.isfinite(cube)
    n = valid.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(valid, cube, 0.0).sum(axis=1) / n
        dev = np.where(valid, cube - mean[:, None, :], 0.0)
        se = np.sqrt((dev ** 2).sum(axis=1) / (n - 1)) / np.sqrt(n)
    half = np.where(n > 1, _t_quantile(n, confidence) * se, 0.0)
    out: dict[str, dict[str, np.ndarray]] = {}
    for name in order_controllers(c_names.tolist()):
        j = int(np.searchsorted(c_names, name))
        keep = n[j] > 0
        out[name] = {"step": steps[keep], "mean": mean[j, keep], "lo": (mean[j] - half[j])[keep],
                     "hi": (mean[j] + half[j])[keep], "n": n[j, keep]}
    return out


def scale_improvement_matrix(results_table: pa.Table | Mapping[str, Any], baseline: str,
                             method: str = "madp") -> dict[str, Any]:
    """Relative improvement ``(B̄ − M̄)/B̄`` on the N × F grid of the ``scale`` suite.

    ``B̄`` and ``M̄`` are the mean ``final_cost`` of ``baseline`` and ``method`` over all results rows
    with the same ``num_robots`` (N) and ``num_features`` (F); positive values mean ``method`` has
    the lower cost.

    Returns:
        ``{"baseline", "method", "num_robots": [N...], "num_features": [F...], "improvement": [N x F]
        array, "baseline_mean", "method_mean": [N x F] arrays, "n_baseline", "n_method": [N x F] int
        arrays}``, rows ascending N, columns ascending F; nan (n = 0) where either is missing.
    """
    controller = _column(results_table, "controller")
    nr = _column(results_table, "num_robots").astype(np.int64)
    nf = _column(results_table, "num_features").astype(np.int64)
    final = _column(results_table, "final_cost").astype(float)
    n_vals, n_idx = np.unique(nr, return_inverse=True)
    f_vals, f_idx = np.unique(nf, return_inverse=True)
    cell = n_idx.reshape(-1) * f_vals.size + f_idx.reshape(-1)
    size = n_vals.size * f_vals.size

    def cell_means(name: str) -> tuple[np.ndarray, np.ndarray]:
        m = controller == name
        cnt = np.bincount(cell[m], minlength=size)
        tot = np.bincount(cell[m], weights=final[m], minlength=size)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(cnt > 0, tot / cnt, np.nan)
        return mean.reshape(n_vals.size, f_vals.size), cnt.reshape(n_vals.size, f_vals.size)

    b_mean, b_n = cell_means(baseline)
    m_mean, m_n = cell_means(method)
    with np.errstate(invalid="ignore", divide="ignore"):
        imp = (b_mean - m_mean) / b_mean
    return {"baseline": baseline, "method": method, "num_robots": n_vals.tolist(),
            "num_features": f_vals.tolist(), "improvement": imp, "baseline_mean": b_mean,
            "method_mean": m_mean, "n_baseline": b_n, "n_method": m_n}


# --------------------------------------------------------------------------------------------------
# Markdown
# --------------------------------------------------------------------------------------------------


def _finite(x: Any) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def _cell(st: Mapping[str, Any] | None) -> str:
    if not st:
        return "—"
    if st["n"] < 2 or not _finite(st.get("se")):
        return f"{st['mean']:.3f} (n=1)" if st["n"] == 1 else f"{st['mean']:.3f}"
    return f"{st['mean']:.3f} ± {st['se']:.3f} [{st['ci_lo']:.3f}, {st['ci_hi']:.3f}]"


def _n_text(stats_by_ctrl: Mapping[str, Mapping[str, Any]]) -> str:
    ns = sorted({int(s["n"]) for s in stats_by_ctrl.values()})
    return "0" if not ns else str(ns[0]) if len(ns) == 1 else f"{ns[0]}–{ns[-1]}"


def _md_row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def markdown_table(summary: Mapping[str, Any], suite: str | None = None) -> str:
    """Markdown tables of a :func:`summarize` dict (for ``summary.md`` and the README).

    1. Final cost: rows = groups then ``all`` (the whole suite), columns = ``n`` (environments; a
       range when controllers differ), one column per controller with ``mean ± SE [lo, hi]`` (95 %
       t interval; ``mean (n=1)`` for a single environment, ``—`` when absent) and, for suites in
       :data:`PAPER_RESULTS`, a column ``paper DCVT / LPAC-K3 / MADP``.
    2. Mean wall time per control step (ms): same rows and controller columns.
    3. ``scale`` suite only: per baseline, the N × F matrix of relative improvement of MADP.
    """
    suite = suite or summary["suite"]
    controllers: list[str] = list(summary["controllers"])
    rows = [(g, summary["by_group"].get(g, {})) for g in summary["groups"]]
    rows.append((f"**{ALL_ROW}**", summary["overall"]))
    row_keys = list(summary["groups"]) + [ALL_ROW]
    has_paper = suite in PAPER_RESULTS
    level = summary.get("confidence", CONFIDENCE)

    lines = [f"### Suite `{suite}` — normalised coverage cost J(T)/J(0)", "",
             f"Mean ± standard error [{level:.0%} Student-t interval] over environments; "
             f"`all` pools every environment of the suite.", ""]
    header = ["group", "n"] + [_display(c) for c in controllers]
    if has_paper:
        header.append("paper " + " / ".join(_display(c) for c in PAPER_CONTROLLERS))
    lines += [_md_row(header), _md_row(["---"] * len(header))]
    for (label, by_ctrl), key in zip(rows, row_keys):
        cells = [label, _n_text(by_ctrl)] + [_cell(by_ctrl.get(c)) for c in controllers]
        if has_paper:
            paper = paper_results(suite, key)
            cells.append(" / ".join(f"{paper[c]:.2f}" if c in paper else "—" for c in PAPER_CONTROLLERS)
                         if paper else "—")
        lines.append(_md_row(cells))

    lines += ["", f"Mean wall time per control step (ms), suite `{suite}`:", ""]
    header = ["group"] + [_display(c) for c in controllers]
    lines += [_md_row(header), _md_row(["---"] * len(header))]
    for label, by_ctrl in rows:
        lines.append(_md_row([label] + [f"{by_ctrl[c]['mean_step_ms']:.2f}" if c in by_ctrl and
                                        _finite(by_ctrl[c].get("mean_step_ms")) else "—"
                                        for c in controllers]))

    for baseline, m in (summary.get("scale_improvement") or {}).items():
        imp = np.asarray(m["improvement"], dtype=float)
        lines += ["", f"Relative improvement (B̄ − M̄)/B̄ of {_display(m['method'])} over "
                  f"{_display(baseline)} (rows N robots, columns F features):", ""]
        header = ["N \\ F"] + [str(f) for f in m["num_features"]]
        lines += [_md_row(header), _md_row(["---"] * len(header))]
        for i, nr in enumerate(m["num_robots"]):
            lines.append(_md_row([str(nr)] + [f"{v:+.1%}" if math.isfinite(v) else "—" for v in imp[i]]))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------------


def _new_figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=_DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=_DPI, format="png")
    return path


def _n_range(ns: Iterable[int]) -> str:
    ns = sorted(set(int(n) for n in ns))
    return "0" if not ns else str(ns[0]) if len(ns) == 1 else f"{ns[0]}–{ns[-1]}"


def _plot_cost(path: Path, bands: Mapping[str, Mapping[str, np.ndarray]], title: str,
               colors: Mapping[str, str]) -> Path:
    """Mean cost vs step with shaded interval, one line per controller."""
    fig = _new_figure(8.0, 5.0)
    ax = fig.add_subplot()
    top = 1.0
    for name, b in bands.items():
        color = colors[name]
        final = b["mean"][-1]
        ax.plot(b["step"], b["mean"], color=color, lw=1.8,
                ls="--" if name == "clairvoyant" else "-",
                label=f"{_display(name)} (final {final:.3f}, n={_n_range(b['n'][-1:])})")
        ax.fill_between(b["step"], b["lo"], b["hi"], color=color, alpha=0.18, lw=0)
        top = max(top, float(np.nanmax(b["hi"])) if b["hi"].size else top)
    ax.set_xlabel("control step")
    ax.set_ylabel("normalised coverage cost J(t) / J(0)")
    ax.set_ylim(0.0, top * 1.05)
    ax.set_xlim(left=0)
    ax.grid(True, alpha=0.3)
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=9, title=f"mean, shaded {CONFIDENCE:.0%} t interval",
              title_fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def _annotated_heatmap(ax, mat: np.ndarray, row_labels: Sequence[str], col_labels: Sequence[str],
                       fmt, cmap_name: str, vmin: float, vmax: float):
    import matplotlib as mpl

    cmap = mpl.colormaps[cmap_name].with_extremes(bad="#dddddd")
    norm = mpl.colors.Normalize(vmin=vmin, vmax=vmax)
    im = ax.imshow(np.ma.masked_invalid(mat), cmap=cmap, norm=norm, aspect="auto", interpolation="nearest")
    ax.set_xticks(np.arange(len(col_labels)), labels=col_labels)
    ax.set_yticks(np.arange(len(row_labels)), labels=row_labels)
    ax.tick_params(top=True, bottom=False, labeltop=True, labelbottom=False)
    rgba = cmap(norm(np.nan_to_num(mat, nan=vmin)))
    lum = rgba[..., 0] * 0.299 + rgba[..., 1] * 0.587 + rgba[..., 2] * 0.114
    for (i, j), v in np.ndenumerate(mat):
        ax.text(j, i, fmt(v) if math.isfinite(v) else "—", ha="center", va="center", fontsize=9,
                color="white" if math.isfinite(v) and lum[i, j] < 0.5 else "black")
    return im


def _plot_sigma_boxplot(path: Path, final: np.ndarray, group: np.ndarray, controller: np.ndarray,
                        groups: Sequence[str], controllers: Sequence[str], meta: Mapping[str, Mapping],
                        colors: Mapping[str, str], suite: str) -> Path | None:
    """Side-by-side box plots of final cost per σ range (x) and controller."""
    from matplotlib.patches import Patch

    def sigma_of(g: str) -> tuple[float, float]:
        lo, hi = meta.get(g, {}).get("sigma_lo"), meta.get(g, {}).get("sigma_hi")
        return (float(lo), float(hi)) if _finite(lo) and _finite(hi) else (math.inf, math.inf)

    xs = sorted(groups, key=lambda g: (sigma_of(g), _natural_key(g)))
    labels = [f"σ ∈ [{sigma_of(g)[0]:g}, {sigma_of(g)[1]:g}]" if math.isfinite(sigma_of(g)[0]) else g
              for g in xs]
    width = 0.8 / max(len(controllers), 1)
    fig = _new_figure(max(6.0, 1.6 + 0.55 * len(xs) * len(controllers)), 5.0)
    ax = fig.add_subplot()
    ns = []
    drawn = False
    for j, c in enumerate(controllers):
        data, pos = [], []
        for i, g in enumerate(xs):
            v = final[(group == g) & (controller == c)]
            v = v[np.isfinite(v)]
            if v.size:
                data.append(v)
                pos.append(i - 0.4 + width * (j + 0.5))
                ns.append(v.size)
        if not data:
            continue
        drawn = True
        ax.boxplot(data, positions=pos, widths=width * 0.85, patch_artist=True, showmeans=True,
                   manage_ticks=False,
                   boxprops={"facecolor": colors[c], "alpha": 0.55, "edgecolor": colors[c]},
                   medianprops={"color": "black"}, whiskerprops={"color": colors[c]},
                   capprops={"color": colors[c]},
                   meanprops={"marker": "D", "markerfacecolor": "white", "markeredgecolor": "black",
                              "markersize": 4},
                   flierprops={"marker": "o", "markersize": 3, "markeredgecolor": colors[c]})
    if not drawn:
        return None
    ax.set_xticks(np.arange(len(xs)), labels=labels)
    ax.set_xlim(-0.6, len(xs) - 0.4)
    ax.set_xlabel("feature σ range (m)")
    ax.set_ylabel("final normalised cost J(T) / J(0)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(f"{suite}: final cost per σ range (n = {_n_range(ns)} envs per box)")
    ax.legend(handles=[Patch(facecolor=colors[c], alpha=0.55, edgecolor=colors[c], label=_display(c))
                       for c in controllers], loc="best", fontsize=9,
              title="box: quartiles, — median, ◇ mean", title_fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def _plot_cities_heatmap(path: Path, summary: Mapping[str, Any], suite: str) -> Path | None:
    """City × controller heat map of mean final cost, with the suite mean as a last row."""
    controllers, groups = summary["controllers"], summary["groups"]
    if not controllers or not groups:
        return None
    by_group, overall = summary["by_group"], summary["overall"]
    mat = np.array([[by_group.get(g, {}).get(c, {}).get("mean", np.nan) for c in controllers]
                    for g in groups] + [[overall.get(c, {}).get("mean", np.nan) for c in controllers]],
                   dtype=float)
    n_all = _n_range(s["n"] for s in overall.values())
    rows = list(groups) + [f"mean over {len(groups)} (n={n_all})"]
    longest = max(len(r) for r in rows)
    fig = _new_figure(max(5.5, 1.5 + 1.25 * len(controllers) + 0.075 * longest), 1.8 + 0.3 * len(rows))
    ax = fig.add_subplot()
    finite = mat[np.isfinite(mat)]
    vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if vmax - vmin < 1e-9:
        vmin, vmax = vmin - 0.05, vmax + 0.05
    im = _annotated_heatmap(ax, mat, rows, [_display(c) for c in controllers], lambda v: f"{v:.3f}",
                            "viridis_r", vmin, vmax)
    ax.axhline(len(groups) - 0.5, color="white", lw=3)
    fig.colorbar(im, ax=ax, label="final normalised cost J(T) / J(0)", shrink=0.8)
    n_env = _n_range(s["n"] for g in groups for s in by_group.get(g, {}).values())
    ax.set_title(f"{suite}: final cost per city ({len(groups)} cities, n = {n_env} env each)")
    fig.tight_layout()
    return _save(fig, path)


def _plot_scale_improvement(path: Path, m: Mapping[str, Any], suite: str) -> Path | None:
    """N × F heat map of the relative improvement of MADP over one baseline."""
    imp = np.asarray(m["improvement"], dtype=float)
    if not np.isfinite(imp).any():
        return None
    lim = max(0.05, float(np.nanmax(np.abs(imp))))
    fig = _new_figure(max(5.5, 2.2 + 1.1 * imp.shape[1]), max(4.0, 1.8 + 0.75 * imp.shape[0]))
    ax = fig.add_subplot()
    im = _annotated_heatmap(ax, imp, [str(n) for n in m["num_robots"]], [str(f) for f in m["num_features"]],
                            lambda v: f"{v:+.1%}", "RdYlGn", -lim, lim)
    ax.set_xlabel("F (features)")
    ax.xaxis.set_label_position("top")
    ax.set_ylabel("N (robots)")
    fig.colorbar(im, ax=ax, label=f"(B̄ − M̄) / B̄,  B = {_display(m['baseline'])}, M = {_display(m['method'])}",
                 shrink=0.85, format=lambda v, _pos: f"{v:+.0%}")
    n = _n_range(np.concatenate([np.asarray(m["n_baseline"]).ravel(), np.asarray(m["n_method"]).ravel()]))
    ax.set_title(f"{suite}: {_display(m['method'])} vs {_display(m['baseline'])}, relative improvement "
                 f"(n = {n} envs per cell)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


# --------------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------------


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


SAMPLER_NAMES = {"ddim": "DDIM", "dpm++": "DPM-Solver++(2M)"}


def sampling_used(results: pa.Table | Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """``{controller: {"sampler", "sampling_steps"}}`` for the controllers that sample (MADP), from
    the ``sampler`` / ``sampling_steps`` columns of ``results.parquet`` (absent in older tables: {})."""
    if not (_has_column(results, "sampler") and _has_column(results, "sampling_steps")):
        return {}
    ctrl, smp, steps = _column(results, "controller"), _column(results, "sampler"), _column(results, "sampling_steps")
    out: dict[str, dict[str, Any]] = {}
    for c in order_controllers(sorted(set(ctrl[smp != ""].tolist()))):
        sel = (ctrl == c) & (smp != "")
        keys = np.unique(np.char.add(np.char.add(smp[sel].astype(str), "|"), steps[sel].astype(np.int64).astype(str)))
        pairs = [(k.split("|")[0], int(k.split("|")[1])) for k in keys.tolist()]
        out[c] = {"sampler": "/".join(p[0] for p in pairs), "sampling_steps": pairs[0][1] if len(pairs) == 1
                  else [p[1] for p in pairs]}
        if _has_column(results, "fixed_noise") and _column(results, "fixed_noise")[sel].astype(bool).any():
            out[c]["fixed_noise"] = True
    return out


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
    results, _ = _select_suite(pq.read_table(results_path), suite)
    summary = summarize(results, suite, confidence)
    summary["sampling"] = sampling_used(results)
    controllers, groups = summary["controllers"], summary["groups"]
    colors = _color_map(order_controllers(list(controllers) + (
        _column(pq.read_table(curves_path, columns=["controller"]), "controller").tolist()
        if curves_path.is_file() else [])))
    written: dict[str, Path] = {}

    def record(path: Path | None) -> None:
        if path is not None:
            written[path.name] = path

    # Cost vs step per group (and pooled).
    curve_info: dict[str, Any] = {"present": curves_path.is_file()}
    if curves_path.is_file():
        curves, _ = _select_suite(pq.read_table(curves_path), suite)
        c_group = _column(curves, "group")
        c_ctrl = _column(curves, "controller")
        c_env = _column(curves, "env").astype(np.int64)
        c_step = _column(curves, "step").astype(np.int64)
        c_cost = _column(curves, "cost").astype(float)
        curve_groups = groups + [g for g in order_groups(c_group.tolist()) if g not in set(groups)]
        g_names, g_inv = np.unique(c_group, return_inverse=True)
        g_inv = g_inv.reshape(-1)
        env_lo = int(c_env.min()) if c_env.size else 0
        env_span = int(c_env.max()) - env_lo + 1 if c_env.size else 1
        env_key = g_inv * env_span + (c_env - env_lo)  # unique per (group, env)
        draw_all = len(curve_groups) > all_threshold
        slugs = _unique_slugs(curve_groups, reserved=("all",) if draw_all else ())
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
            record(_plot_cost(suite_dir / f"cost_{slugs[g]}.png", bands,
                              f"{suite} · {g}: mean cost vs step (n = {n_env} env{'s' * (n_env != 1)})",
                              colors))
        if draw_all and c_step.size:
            bands = cost_curve_bands(c_ctrl, env_key, c_step, c_cost, confidence)
            n_env = np.unique(env_key).size
            record(_plot_cost(suite_dir / "cost_all.png", bands,
                              f"{suite} · all {len(curve_groups)} groups: mean cost vs step (n = {n_env} envs)",
                              colors))

    # Suite-specific plots.
    if suite == "sigma":
        record(_plot_sigma_boxplot(suite_dir / "sigma_boxplot.png", _column(results, "final_cost").astype(float),
                                   _column(results, "group"), _column(results, "controller"), groups,
                                   controllers, summary["groups_meta"], colors, suite))
    elif suite == "cities":
        record(_plot_cities_heatmap(suite_dir / "cities_heatmap.png", summary, suite))
    elif suite == "scale":
        for baseline, m in (summary.get("scale_improvement") or {}).items():
            record(_plot_scale_improvement(suite_dir / f"scale_improvement_{baseline}.png", m, suite))

    # Markdown.
    md = [markdown_table(summary, suite).rstrip("\n")]
    if summary["sampling"]:
        md += ["", "MADP sampling: " + "; ".join(
            f"{_display(c)}: {SAMPLER_NAMES.get(v['sampler'], v['sampler'])}, S = {v['sampling_steps']}"
            + (", initial noise fixed per episode" if v.get("fixed_noise") else "")
            for c, v in summary["sampling"].items()) + "."]
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
        "steps": sorted(set(_column(results, "steps").astype(int).tolist())) if _has_column(results, "steps") else None,
        "paper": PAPER_RESULTS.get(suite),
        "paper_controllers": {c: _display(c) for c in PAPER_CONTROLLERS},
        "files": sorted(list(written) + [json_path.name]),
    }
    json_path.write_text(json.dumps(_json_safe(doc), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    record(json_path)
    return written
