"""Statistics of a suite's result tables: per (group, controller) and per controller, the mean final
cost with its standard error and Student-t interval, the per-step bands of the cost curves and the
``scale`` suite's improvement matrices; and the canonical order of controllers and groups.

Everything is computed from column arrays with NumPy grouping (``np.unique`` / ``np.add.reduceat`` /
fancy-index scatter into ``controller x env x step`` cubes); there are no Python loops over rows.
Tables are :class:`pyarrow.Table` s or mappings of column name to array.

Ordering (deterministic, independent of the row order of the tables):

* controllers: the registry's order (:data:`madp.controllers.NAMES`), each followed by its named
  controllers (``madp``, ``madp:r4``, ``madp:r5``, ``madp_central``) in name order, then any other
  name alphabetically;
* groups: *natural* sort of the group names (digit runs compare as numbers, text case-insensitively),
  so ``sigma_5-10 < sigma_10-20 < sigma_20-30``, ``N16_F32 < N16_F128 < N32_F16`` and cities are
  alphabetical.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
from scipy import stats

from madp.controllers import BASELINES, NAMES, ORACLES, SAMPLING, split_name

__all__ = ["CONFIDENCE", "best_per_group", "column", "cost_curve_bands", "grouped_stats", "has_column", "n_range", "natural_key", "order_controllers",
           "order_groups", "sampling_used", "scale_improvement_matrix", "select_suite", "summarize", "symmetry_check"]

#: Two-sided confidence level of every interval (Student t).
CONFIDENCE = 0.95

#: A group of the ``symmetry`` suite: a launch layout under element g of the world's symmetry group.
SYMMETRY_GROUP = re.compile(r"^(?P<layout>.+)_d4-(?P<g>\d+)$")

_META_COLUMNS = ("num_robots", "num_features", "sigma_lo", "sigma_hi", "city", "launch")


def order_controllers(names: Iterable[str]) -> list[str]:
    """Distinct controller names in canonical order (the registry's, :data:`madp.controllers.NAMES`,
    each followed by its named controllers ``madp:NAME`` in name order), then any other name
    alphabetically."""
    def key(name: str) -> tuple:
        base, label = split_name(name)
        if base not in NAMES:
            return (len(NAMES), name, "")
        return (NAMES.index(base), "" if label is None else "~", label or "")

    return sorted(set(names), key=key)


def natural_key(name: str) -> tuple:
    # re.split with a capturing group puts text at even and digit runs at odd positions, so the
    # tuple compares str with str and int with int only.
    parts = re.split(r"(\d+)", name)
    return (tuple(int(p) if i % 2 else p.casefold() for i, p in enumerate(parts)), name)


def order_groups(names: Iterable[str]) -> list[str]:
    """Distinct group names in natural order (numbers numerically, text case-insensitively)."""
    return sorted(set(names), key=natural_key)


def column(table: pa.Table | Mapping[str, Any], name: str) -> np.ndarray:
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


def has_column(table: pa.Table | Mapping[str, Any], name: str) -> bool:
    return name in (table.column_names if isinstance(table, pa.Table) else table)


def select_suite(table: pa.Table | Mapping[str, Any], suite: str | None) -> tuple[Any, str]:
    """Rows of ``suite`` (all rows when ``suite`` is None and the table holds one suite)."""
    names = column(table, "suite")
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


def paired_stats(diff: np.ndarray, confidence: float = CONFIDENCE) -> dict[str, Any]:
    """One set of paired differences ``diff [n]`` (a run minus its baseline on the same environments):
    ``n``, ``diff`` (the mean), ``se``, ``ci_lo``/``ci_hi`` (:func:`grouped_stats` of one group; nan SE
    for n = 1), ``wins`` (environments where the run is lower) and ``ties``."""
    d = np.asarray(diff, dtype=float)
    st = grouped_stats(np.zeros(len(d), dtype=np.int64), d, confidence)
    if not len(d):
        return {"n": 0, "diff": float("nan"), "se": float("nan"), "ci_lo": float("nan"), "ci_hi": float("nan"),
                "wins": 0, "ties": 0}
    return {"n": int(len(d)), "diff": float(st["mean"][0]), "se": float(st["se"][0]), "ci_lo": float(st["ci_lo"][0]),
            "ci_hi": float(st["ci_hi"][0]), "wins": int((d < 0).sum()), "ties": int((d == 0).sum())}


def _group_meta(table, group: np.ndarray, groups: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Scenario parameters of each group (a scalar when constant over the group, else a sorted list)."""
    meta: dict[str, dict[str, Any]] = {g: {} for g in groups}
    g_names, g_idx = np.unique(group, return_inverse=True)
    g_idx = g_idx.reshape(-1)
    for name in _META_COLUMNS:
        if not has_column(table, name):
            continue
        vals, v_idx = np.unique(column(table, name), return_inverse=True)
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
        :func:`scale_improvement_matrix`) and, for the ``cities`` suite, ``"best"`` (each city's best
        deployable controller and the counts, :func:`best_per_group`) and, for the ``symmetry`` suite,
        ``"symmetry"`` (each image of a launch layout against the layout's mean, :func:`symmetry_check`). ``stats`` holds ``n`` (environments), ``mean``, ``se``,
        ``ci_lo``, ``ci_hi``, ``median``, ``std`` of ``final_cost`` and ``mean_step_ms`` (mean over
        the environments). ``overall`` pools every (group, env) of the suite. Controllers are in
        :func:`order_controllers` order, groups in :func:`order_groups` (natural) order; a
        (group, controller) pair without rows is absent. NaN marks undefined values (SE of n = 1).

    Raises:
        ValueError: for rows of other suites only, or a duplicated (group, env, controller).
    """
    table, suite = select_suite(results_table, suite)
    group = column(table, "group")
    env = column(table, "env").astype(np.int64)
    controller = column(table, "controller")
    final = column(table, "final_cost").astype(float)
    step_ms = column(table, "mean_step_ms").astype(float)

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
    if suite == "cities":
        summary["best"] = best_per_group(summary)
    if suite == "symmetry":
        summary["symmetry"] = symmetry_check(summary, (group, env, controller, final))
    # MADP in the scale matrices: the decentralized policy when it ran, else the centralized-masked one.
    method = next((c for c in controllers if c in SAMPLING), None)
    if suite == "scale" and method is not None and \
            has_column(table, "num_robots") and has_column(table, "num_features"):
        imp = {}
        for baseline in BASELINES:
            if baseline in controllers:
                m = scale_improvement_matrix(table, baseline, method)
                if np.isfinite(m["improvement"]).any():
                    imp[baseline] = m
        if imp:
            summary["scale_improvement"] = imp
    return summary


def best_per_group(summary: Mapping[str, Any]) -> dict[str, Any]:
    """Which controller ends each group (a city of ``cities``) at the lowest mean final cost, and in how
    many groups each controller is best (the paper: "MADP achieves the lowest cost in 32 out of 50 cities").

    Only deployable controllers compete: the oracles (:data:`madp.controllers.ORACLES`, the clairvoyant
    expert, which sees the whole map) are left out. A tie makes every tied controller best of that group.

    Returns ``{"best": {group: [controllers]}, "counts": {controller: k}, "groups": n, "excluded":
    [oracles present]}``: ``counts`` holds every competing controller of the summary (0 where never best),
    in the summary's order; ``n`` counts the groups where at least one competed.
    """
    competing = [c for c in summary["controllers"] if split_name(c)[0] not in ORACLES]
    best: dict[str, list[str]] = {}
    for g in summary["groups"]:
        means = {c: st["mean"] for c, st in summary["by_group"].get(g, {}).items()
                 if c in competing and finite(st.get("mean"))}
        if means:
            low = min(means.values())
            best[g] = [c for c in competing if means.get(c) == low]
    counts = {c: sum(c in b for b in best.values()) for c in competing}
    excluded = [c for c in summary["controllers"] if c not in competing]
    return {"best": best, "counts": counts, "groups": len(best), "excluded": excluded}


def symmetry_check(summary: Mapping[str, Any], rows: tuple[np.ndarray, ...] | None = None) -> dict[str, Any]:
    """Whether each controller costs the same on every image of a launch layout (the ``symmetry``
    suite: groups ``<layout>_d4-<g>``, the same environments moved by the world's rotations and
    reflections, which leave the task unchanged).

    For every controller and layout: ``mean``, the mean over the layout's images of their mean final
    costs, and per image ``g``: ``mean``, ``se``, ``n``, ``deviation`` (image mean − layout mean) and
    ``within_se`` (|deviation| ≤ the image's SE); ``within`` counts those images, ``images`` how
    many ran.

    With ``rows`` (``group, env, controller, final_cost`` per results row), the images are also
    compared environment by environment: per image ``paired`` = the mean over the environments that
    ran on every image of (its cost − the mean of the other images' costs), with ``se`` and ``z`` =
    mean / se; per layout ``max_abs_z`` and ``familywise_p``, the chance that an exactly symmetric
    policy (every image's costs the same in distribution, the environments' differences cancelled by
    the pairing) shows some image at least that far out: Šidák over the images of the two-sided
    Student-t p-value of the largest |z|. Returns ``{controller: {layout: {...}}}``; groups of other
    names are ignored."""
    out: dict[str, Any] = {}
    for c in summary["controllers"]:
        layouts: dict[str, dict[int, Mapping[str, Any]]] = {}
        for g in summary["groups"]:
            m, st = SYMMETRY_GROUP.match(g), summary["by_group"].get(g, {}).get(c)
            if m is not None and st is not None and finite(st.get("mean")):
                layouts.setdefault(m["layout"], {})[int(m["g"])] = st
        for layout, images in layouts.items():
            mean = float(np.mean([st["mean"] for st in images.values()]))
            by_image = {}
            for g in sorted(images):
                st = images[g]
                dev = float(st["mean"]) - mean
                by_image[g] = {"mean": float(st["mean"]), "se": float(st["se"]), "n": int(st["n"]), "deviation": dev,
                               "within_se": bool(finite(st["se"]) and abs(dev) <= st["se"])}
            lay = {"mean": mean, "by_image": by_image, "images": len(by_image),
                   "within": sum(r["within_se"] for r in by_image.values())}
            if rows is not None:
                lay.update(_paired_images(rows, c, layout, sorted(images), by_image))
            out.setdefault(c, {})[layout] = lay
    return out


def _paired_images(rows: tuple[np.ndarray, ...], controller: str, layout: str, images: list[int],
                   by_image: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """:func:`symmetry_check`'s environment-by-environment comparison of one controller's images of one
    layout: fills ``by_image[g]["paired"]``, returns the layout's ``max_abs_z`` and ``familywise_p``."""
    group, env, controller_col, final = rows
    envs = np.unique(env)
    cube = np.full((len(envs), len(images)), np.nan)  # [env, image]
    for j, g in enumerate(images):
        pick = (controller_col == controller) & (group == f"{layout}_d4-{g}")
        cube[np.searchsorted(envs, env[pick]), j] = final[pick]
    cube = cube[np.isfinite(cube).all(1)]
    n, k = cube.shape
    if n < 2 or k < 2:
        return {"max_abs_z": math.nan, "familywise_p": math.nan}
    others = (cube.sum(1, keepdims=True) - cube) / (k - 1)
    d = cube - others  # [env, image]
    se = d.std(0, ddof=1) / math.sqrt(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(se > 0, d.mean(0) / se, np.where(d.mean(0) == 0, 0.0, np.inf))
    for j, g in enumerate(images):
        by_image[g]["paired"] = {"diff": float(d[:, j].mean()), "se": float(se[j]), "z": float(z[j]), "n": int(n)}
    zmax = float(np.abs(z).max())
    p_one = float(2 * stats.t.sf(zmax, df=n - 1))
    return {"max_abs_z": zmax, "familywise_p": float(1 - (1 - p_one) ** k)}


def cost_curve_bands(controller: np.ndarray, env_key: np.ndarray, step: np.ndarray, cost: np.ndarray,
                     confidence: float = CONFIDENCE) -> dict[str, dict[str, np.ndarray]]:
    """Mean normalised cost per step and its per-step band across environments, as the paper draws it
    (Fig. 3): mean ± z·SE, SE the standard error over the environments at that step and z the normal
    quantile of ``confidence`` (1.96 at 95 %). The tables' intervals are Student-t; the band is the
    normal one, which at the paper's 50 environments is nearly the same (t = 2.01) and at a handful
    does not swell to fill the plot (t = 12.7 at two).

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
        ``{controller: {"step", "mean", "se", "lo", "hi", "n"}}`` in canonical controller order; ``step``
        holds the steps at which the controller has at least one environment. With one environment
        at a step, ``lo = hi = mean`` (``se`` nan).
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
    half = np.where(n > 1, stats.norm.ppf(0.5 + confidence / 2.0) * se, 0.0)
    out: dict[str, dict[str, np.ndarray]] = {}
    for name in order_controllers(c_names.tolist()):
        j = int(np.searchsorted(c_names, name))
        keep = n[j] > 0
        out[name] = {"step": steps[keep], "mean": mean[j, keep], "se": se[j, keep], "lo": (mean[j] - half[j])[keep],
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
    controller = column(results_table, "controller")
    nr = column(results_table, "num_robots").astype(np.int64)
    nf = column(results_table, "num_features").astype(np.int64)
    final = column(results_table, "final_cost").astype(float)
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


def sampling_used(results: pa.Table | Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """``{controller: {"sampler", "sampling_steps"}}`` for the controllers that sample (MADP), from
    the ``sampler`` / ``sampling_steps`` columns of ``results.parquet`` (absent in older tables: {});
    with ``fixed_noise``, ``frame`` (d4) and ``select`` / ``candidates`` where those were not the defaults."""
    if not (has_column(results, "sampler") and has_column(results, "sampling_steps")):
        return {}
    ctrl, smp, steps = column(results, "controller"), column(results, "sampler"), column(results, "sampling_steps")
    out: dict[str, dict[str, Any]] = {}
    for c in order_controllers(sorted(set(ctrl[smp != ""].tolist()))):
        sel = (ctrl == c) & (smp != "")
        keys = np.unique(np.char.add(np.char.add(smp[sel].astype(str), "|"), steps[sel].astype(np.int64).astype(str)))
        pairs = [(k.split("|")[0], int(k.split("|")[1])) for k in keys.tolist()]
        out[c] = {"sampler": "/".join(p[0] for p in pairs), "sampling_steps": pairs[0][1] if len(pairs) == 1
                  else [p[1] for p in pairs]}
        if has_column(results, "fixed_noise") and column(results, "fixed_noise")[sel].astype(bool).any():
            out[c]["fixed_noise"] = True
        if has_column(results, "frame") and (column(results, "frame")[sel].astype(str) == "d4").any():
            out[c]["frame"] = "d4"
        picked = column(results, "select")[sel].astype(str) if has_column(results, "select") else np.array([], str)
        if (chosen := np.flatnonzero((picked != "none") & (picked != ""))).size:
            out[c].update(select=str(picked[chosen[0]]), candidates=int(column(results, "candidates")[sel][chosen[0]]))
    return out


def finite(x: Any) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def n_range(ns: Iterable[int]) -> str:
    ns = sorted(set(int(n) for n in ns))
    return "0" if not ns else str(ns[0]) if len(ns) == 1 else f"{ns[0]}–{ns[-1]}"
