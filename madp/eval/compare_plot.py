"""The plot of ``madp eval compare``: paired differences to the baseline run, per group, with intervals.

One panel per controller that the baseline and at least one other run evaluated; rows are the
suite's groups (then ``all`` when there are several), one marker per other run at the mean paired
difference ``run − baseline`` of final cost, with its Student-t interval as a horizontal error bar
and its wins k/n beside it. Left of the zero line the run ends at a lower cost than the baseline.
The figure is a :class:`matplotlib.figure.Figure` with its own Agg canvas (pyplot is not touched).
"""

from __future__ import annotations

from typing import Any

import numpy as np

_DPI = 120
_ANNOTATE_AT_MOST = 24  # markers per panel up to which each gets its wins k/n written beside it


def plot_paired(cmp: dict[str, Any]):
    """The figure of a :func:`madp.eval.compare.compare_runs` dict; None when no controller has a
    paired difference (the baseline ran none of the others' controllers)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    base = cmp["baseline"]
    others = [r["name"] for r in cmp["runs"] if r["name"] != base]
    panels = [(c, b) for c, b in cmp["by_controller"].items() if base in b["runs"] and len(b["runs"]) > 1]
    if not panels:
        return None
    labels = list(cmp["groups"]) + (["all"] if len(cmp["groups"]) > 1 else [])
    n_rows, n_runs = len(labels), len(others)
    colors = {n: f"C{i % 10}" for i, n in enumerate(others)}
    fig = Figure(figsize=(max(7.5, 1.6 + 4.2 * len(panels)), 2.0 + 0.3 * n_rows * max(1.0, 0.6 * n_runs)), dpi=_DPI,
                 layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), sharey=True, squeeze=False)[0]
    y = np.arange(n_rows)[::-1].astype(float)  # the first group on top
    height = 0.7 / n_runs
    handles: dict[str, Any] = {}
    for ax, (controller, block) in zip(axes, panels):
        rows = [block["groups"][g] for g in cmp["groups"]] + ([block["all"]] if block["all"] else [])
        annotate = n_rows * n_runs <= _ANNOTATE_AT_MOST
        for k, name in enumerate(n for n in others if n in block["runs"]):
            p = [row["paired"][name] for row in rows]
            diff = np.array([q["diff"] for q in p])
            lo, hi = np.array([q["ci_lo"] for q in p]), np.array([q["ci_hi"] for q in p])
            yk = y + (n_runs - 1) / 2 * height - k * height
            handles[name] = ax.errorbar(diff, yk, xerr=np.stack([diff - lo, hi - diff]), fmt="o", ms=4, capsize=3,
                                        lw=1.3, color=colors[name])
            if annotate:
                for xi, yi, q in zip(hi, yk, p):
                    ax.annotate(f" {q['wins']}/{q['n']}", (xi, yi), xytext=(3, 0), textcoords="offset points",
                                va="center", fontsize=7, color=colors[name])
        ax.axvline(0.0, color="black", lw=0.8)
        if len(cmp["groups"]) > 1:
            ax.axhline(0.5, color="0.6", lw=0.6, ls=":")
        ax.set_title(f"{controller}", fontsize=10)
        ax.set_xlabel(f"paired Δ final cost vs {base}")
        ax.grid(True, axis="x", alpha=0.3)
        ax.margins(x=0.25)
    axes[0].set_yticks(y, labels=labels)
    axes[0].set_ylim(-0.6, n_rows - 0.4)
    fig.legend([handles[n] for n in others if n in handles], [f"{n} − {base}" for n in others if n in handles],
               loc="outside lower center", ncols=min(n_runs, 4), fontsize=8,
               title=f"mean paired difference, {cmp['confidence']:.0%} t interval, wins k/n (run below {base})",
               title_fontsize=8)
    fig.suptitle(f"{cmp['suite']}: final cost J(T)/J(0) minus {base}'s on the same environments\n"
                 f"(left of 0: lower cost than {base})", fontsize=10)
    return fig
