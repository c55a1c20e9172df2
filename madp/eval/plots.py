"""PNG plots of a suite (Agg, 120 dpi): cost vs step with its 95 % band (mean ± 1.96·SE), the ``sigma`` box plots,
the ``cities`` heat map (each city's best deployable controller marked, as the paper's Fig. 5) and the
``scale`` improvement matrices (the two panels of the paper's Fig. 7, on one colour scale).

Each plot is drawn by a ``*_figure`` function that returns the :class:`matplotlib.figure.Figure` (what
tests inspect: the band, the markers) and written by a ``plot_*`` function.

The plots use :class:`matplotlib.figure.Figure` with an explicit Agg canvas, so importing this module
neither selects nor touches the global pyplot backend.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from madp.controllers import CONTROLLERS, display_name

from .stats import CONFIDENCE, finite, n_range, natural_key

__all__ = ["BEST_MARKER", "cities_heatmap_figure", "color_map", "cost_figure", "group_slug", "plot_cities_heatmap",
           "plot_cost", "plot_scale_improvement", "plot_sigma_boxplot", "scale_improvement_figure", "scale_limit",
           "unique_slugs"]

#: Colours of controllers that are not in the registry.
_EXTRA_COLORS = ("#2ca02c", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f")
_DPI = 120
#: The mark of a city's best controller on the cities heat map (the paper's red dot).
BEST_MARKER = {"marker": "o", "s": 36, "color": "#e41a1c", "edgecolors": "white", "linewidths": 0.8, "zorder": 3}


def group_slug(name: str) -> str:
    """File-name slug of a group: lower case, runs of other than ``[a-z0-9._-]`` become ``-``.

    ``"Boston, MA" -> "boston-ma"``, ``"sigma_10-20" -> "sigma_10-20"``, ``"N32_F64" -> "n32_f64"``.
    """
    slug = re.sub(r"[^a-z0-9._-]+", "-", name.casefold())
    slug = re.sub(r"-{2,}", "-", slug).strip("-._")
    return slug or "group"


def unique_slugs(groups: Sequence[str], reserved: Iterable[str] = ()) -> dict[str, str]:
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


def color_map(controllers: Sequence[str]) -> dict[str, str]:
    extra = iter(_EXTRA_COLORS * 4)
    return {c: CONTROLLERS[c].color if c in CONTROLLERS else next(extra) for c in controllers}


def _new_figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=_DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=_DPI, format="png")
    return path


def plot_cost(path: Path, bands: Mapping[str, Mapping[str, np.ndarray]], title: str,
               colors: Mapping[str, str]) -> Path:
    """Write :func:`cost_figure` to ``path``."""
    return _save(cost_figure(bands, title, colors), path)


def cost_figure(bands: Mapping[str, Mapping[str, np.ndarray]], title: str, colors: Mapping[str, str]):
    """Mean cost vs step, one line per controller, with its 95 % band shaded (as the paper's Fig. 3):
    ``bands`` from :func:`madp.eval.stats.cost_curve_bands`, the shaded area between ``lo`` and ``hi``
    (mean ± 1.96·SE over the environments at each step) drawn in the order of ``bands``."""
    fig = _new_figure(8.0, 5.0)
    ax = fig.add_subplot()
    top = 1.0
    for name, b in bands.items():
        color = colors[name]
        final = b["mean"][-1]
        ax.plot(b["step"], b["mean"], color=color, lw=1.8,
                ls="--" if name == "clairvoyant" else "-",
                label=f"{display_name(name)} (final {final:.3f}, n={n_range(b['n'][-1:])})")
        ax.fill_between(b["step"], b["lo"], b["hi"], color=color, alpha=0.18, lw=0)
        top = max(top, float(np.nanmax(b["hi"])) if b["hi"].size else top)
    ax.set_xlabel("control step")
    ax.set_ylabel("normalised coverage cost J(t) / J(0)")
    ax.set_ylim(0.0, top * 1.05)
    ax.set_xlim(left=0)
    ax.grid(True, alpha=0.3)
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=9, title=f"mean; shaded {CONFIDENCE:.0%} band, mean ± 1.96·SE over environments",
              title_fontsize=8)
    fig.tight_layout()
    return fig


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


def plot_sigma_boxplot(path: Path, final: np.ndarray, group: np.ndarray, controller: np.ndarray,
                        groups: Sequence[str], controllers: Sequence[str], meta: Mapping[str, Mapping],
                        colors: Mapping[str, str], suite: str) -> Path | None:
    """Side-by-side box plots of final cost per σ range (x) and controller."""
    from matplotlib.patches import Patch

    def sigma_of(g: str) -> tuple[float, float]:
        lo, hi = meta.get(g, {}).get("sigma_lo"), meta.get(g, {}).get("sigma_hi")
        return (float(lo), float(hi)) if finite(lo) and finite(hi) else (math.inf, math.inf)

    xs = sorted(groups, key=lambda g: (sigma_of(g), natural_key(g)))
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
    ax.set_title(f"{suite}: final cost per σ range (n = {n_range(ns)} envs per box)")
    ax.legend(handles=[Patch(facecolor=colors[c], alpha=0.55, edgecolor=colors[c], label=display_name(c))
                       for c in controllers], loc="best", fontsize=9,
              title="box: quartiles, — median, ◇ mean", title_fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def plot_cities_heatmap(path: Path, summary: Mapping[str, Any], suite: str) -> Path | None:
    """Write :func:`cities_heatmap_figure` to ``path``; None when there is nothing to draw."""
    fig = cities_heatmap_figure(summary, suite)
    return None if fig is None else _save(fig, path)


def cities_heatmap_figure(summary: Mapping[str, Any], suite: str):
    """City × controller heat map of mean final cost, with the suite mean as a last row. With
    ``summary["best"]`` (:func:`madp.eval.stats.best_per_group`) a red dot marks each city's best
    deployable controller (the paper's Fig. 5) and each column says in how many cities it is best; an
    oracle's column (the clairvoyant expert) is drawn but marked "not counted". Darker is better (lower
    cost), as in the paper."""
    controllers, groups = summary["controllers"], summary["groups"]
    if not controllers or not groups:
        return None
    by_group, overall = summary["by_group"], summary["overall"]
    mat = np.array([[by_group.get(g, {}).get(c, {}).get("mean", np.nan) for c in controllers]
                    for g in groups] + [[overall.get(c, {}).get("mean", np.nan) for c in controllers]],
                   dtype=float)
    n_all = n_range(s["n"] for s in overall.values())
    rows = list(groups) + [f"mean over {len(groups)} (n={n_all})"]
    longest = max(len(r) for r in rows)
    fig = _new_figure(max(5.5, 1.5 + 1.25 * len(controllers) + 0.075 * longest), 1.8 + 0.3 * len(rows))
    ax = fig.add_subplot()
    finite = mat[np.isfinite(mat)]
    vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if vmax - vmin < 1e-9:
        vmin, vmax = vmin - 0.05, vmax + 0.05
    best = summary.get("best")
    labels = [display_name(c) for c in controllers]
    if best:
        labels = [f"{lab}\nbest in {best['counts'][c]}/{best['groups']}" if c in best["counts"] else f"{lab}\n(not counted)"
                  for lab, c in zip(labels, controllers)]
    im = _annotated_heatmap(ax, mat, rows, labels, lambda v: f"{v:.3f}", "viridis", vmin, vmax)  # darker: better (the paper's)
    ax.axhline(len(groups) - 0.5, color="white", lw=3)
    title = f"{suite}: final cost per city ({len(groups)} cities, n = {_n_env(summary)} env each)"
    if best:
        cells = [(controllers.index(c), groups.index(g)) for g, cs in best["best"].items() for c in cs]
        xy = np.array(cells, dtype=float).reshape(-1, 2)
        ax.scatter(xy[:, 0] + 0.32, xy[:, 1], **BEST_MARKER)
        title += "\nred dot: the city's best controller" + (" (the clairvoyant, an oracle, not counted)"
                                                            if best["excluded"] else "")
    fig.colorbar(im, ax=ax, label="final normalised cost J(T) / J(0)", shrink=0.8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def plot_symmetry(path: Path, check: Mapping[str, Any], colors: Mapping[str, str], suite: str) -> Path | None:
    """Write :func:`symmetry_figure` to ``path``; None when there is nothing to draw."""
    fig = symmetry_figure(check, colors, suite)
    return None if fig is None else _save(fig, path)


def symmetry_figure(check: Mapping[str, Any], colors: Mapping[str, str], suite: str):
    """One panel per launch layout of :func:`madp.eval.stats.symmetry_check`: each image's mean final
    cost ± SE per controller, and the layout's mean over the images as a dashed line of the controller's
    colour; a symmetric policy's points straddle its line."""
    layouts = list(dict.fromkeys(lay for per in check.values() for lay in per))
    if not layouts:
        return None
    fig = _new_figure(4.2 * len(layouts) + 1.0, 4.2)
    axes = fig.subplots(1, len(layouts), squeeze=False)[0]
    width = 0.6 / max(len(check), 1)
    for ax, layout in zip(axes, layouts):
        runs = {c: per[layout] for c, per in check.items() if layout in per}  # the controllers that ran it
        for j, (c, lay) in enumerate(runs.items()):
            g = np.array(sorted(lay["by_image"]))
            rows = [lay["by_image"][k] for k in g]
            ax.errorbar(g - 0.3 + width * (j + 0.5), [r["mean"] for r in rows], yerr=[r["se"] for r in rows], fmt="o",
                        color=colors[c], capsize=3, label=f"{display_name(c)}: {lay['within']} of {lay['images']} "
                                                          f"within one SE")
            ax.axhline(lay["mean"], color=colors[c], ls="--", lw=1)
        ax.set_xticks(sorted({g for lay in runs.values() for g in lay["by_image"]}))
        ax.set_xlabel("image g under the world's D4 symmetries (0: the layout)")
        ax.set_ylabel("final normalised cost J(T) / J(0)")
        n = n_range(r["n"] for lay in runs.values() for r in lay["by_image"].values())
        ax.set_title(f"{suite} · {layout}: mean ± SE per image (n = {n})", fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _n_env(summary: Mapping[str, Any]) -> str:
    """The environments per (group, controller) of a summary, as a number or a range."""
    return n_range(s["n"] for g in summary["groups"] for s in summary["by_group"].get(g, {}).values())


def scale_limit(matrices: Iterable[Mapping[str, Any]]) -> float:
    """The colour limit ±L that the ``scale`` improvement heat maps share (the largest |improvement|,
    at least 5 %), so the panels against DCVT and against LPAC-K3 read on one scale as in the paper."""
    vals = [np.abs(np.asarray(m["improvement"], dtype=float)) for m in matrices]
    finite_vals = [v[np.isfinite(v)] for v in vals]
    return max([0.05] + [float(v.max()) for v in finite_vals if v.size])


def plot_scale_improvement(path: Path, m: Mapping[str, Any], suite: str, lim: float | None = None) -> Path | None:
    """Write :func:`scale_improvement_figure` to ``path``; None when the matrix has no finite cell."""
    fig = scale_improvement_figure(m, suite, lim)
    return None if fig is None else _save(fig, path)


def scale_improvement_figure(m: Mapping[str, Any], suite: str, lim: float | None = None):
    """N × F heat map of the relative improvement (B̄ − M̄)/B̄ of MADP over one baseline (a
    :func:`madp.eval.stats.scale_improvement_matrix`), coloured on ±``lim`` (default: this matrix's
    :func:`scale_limit`; the report passes the limit of both baselines, one scale for both panels)."""
    imp = np.asarray(m["improvement"], dtype=float)
    if not np.isfinite(imp).any():
        return None
    lim = scale_limit([m]) if lim is None else lim
    fig = _new_figure(max(5.5, 2.2 + 1.1 * imp.shape[1]), max(4.0, 1.8 + 0.75 * imp.shape[0]))
    ax = fig.add_subplot()
    im = _annotated_heatmap(ax, imp, [str(n) for n in m["num_robots"]], [str(f) for f in m["num_features"]],
                            lambda v: f"{v:+.1%}", "RdYlGn", -lim, lim)
    ax.set_xlabel("F (features)")
    ax.xaxis.set_label_position("top")
    ax.set_ylabel("N (robots)")
    fig.colorbar(im, ax=ax, label=f"(B̄ − M̄) / B̄,  B = {display_name(m['baseline'])}, M = {display_name(m['method'])}",
                 shrink=0.85, format=lambda v, _pos: f"{v:+.0%}")
    n = n_range(np.concatenate([np.asarray(m["n_baseline"]).ravel(), np.asarray(m["n_method"]).ravel()]))
    ax.set_title(f"{suite}: {display_name(m['method'])} vs {display_name(m['baseline'])}, relative improvement "
                 f"(n = {n} envs per cell)", fontsize=10)
    fig.tight_layout()
    return fig
