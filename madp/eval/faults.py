"""The faults suite's report: each group paired against the ideal one on the same environments
(:func:`paired_against_ideal`, a table of ``summary.md``), and the plot of the mean final cost of each
controller against the network's loss rate and against its delay (the groups of
:data:`madp.eval.suites.FAULTS`, the ideal group at 0), with one standard error. The cost curve across
the robots' failure is the suite's ``cost_fail_25.png``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from madp.controllers import display_name

from .plots import _new_figure, _save
from .suites import FAULTS


def fault_axes(dt_s: float) -> dict[str, list[tuple[str, float]]]:
    """The groups on each axis with their x values: ``loss`` (%) and ``delay`` (s), ideal at 0."""
    loss = [(g, 100 * s.loss) for g, s in FAULTS.items() if s.loss > 0 or g == "ideal"]
    delay = [(g, s.delay_steps * dt_s) for g, s in FAULTS.items() if s.delay_steps > 0 or g == "ideal"]
    return {"loss": loss, "delay": delay}


def plot_faults(path: Path, final: np.ndarray, group: np.ndarray, controller: np.ndarray,
                controllers: Sequence[str], colors: Mapping[str, str], suite: str, dt_s: float) -> Path | None:
    """Write :func:`faults_figure` to ``path``; None when the suite ran neither axis' groups."""
    fig = faults_figure(final, group, controller, controllers, colors, suite, dt_s)
    return None if fig is None else _save(fig, path)


def faults_figure(final: np.ndarray, group: np.ndarray, controller: np.ndarray, controllers: Sequence[str],
                  colors: Mapping[str, str], suite: str, dt_s: float):
    """Two panels: mean final cost ± SE per controller against the loss rate and against the delay.
    ``final``, ``group``, ``controller``: one entry per (environment, controller) of ``results.parquet``."""
    axes_groups = {k: [(g, x) for g, x in v if np.any(group == g)] for k, v in fault_axes(dt_s).items()}
    if not any(len(v) > 1 for v in axes_groups.values()):
        return None
    fig = _new_figure(11.0, 4.4)
    for ax, (kind, points) in zip(fig.subplots(1, 2), axes_groups.items()):
        for c in controllers:
            xs, means, ses = [], [], []
            for g, x in points:
                v = final[(group == g) & (controller == c)]
                v = v[np.isfinite(v)]
                if v.size:
                    xs.append(x)
                    means.append(v.mean())
                    ses.append(v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else 0.0)
            if xs:
                ax.errorbar(xs, means, yerr=ses, marker="o", capsize=3, color=colors[c], label=display_name(c))
        ax.set_xlabel("message loss (%)" if kind == "loss" else "message delay (s)")
        ax.set_ylabel("final normalised cost J(T) / J(0)")
        ax.set_title(f"{suite}: cost against {kind} (mean ± SE)", fontsize=10)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def paired_against_ideal(final: np.ndarray, group: np.ndarray, env: np.ndarray, controller: np.ndarray,
                         controllers: Sequence[str]) -> list[dict]:
    """Per (group, controller), the final cost paired with the ideal group's on the same environment:
    ``{"group", "controller", "n", "mean", "ideal", "diff", "se", "relative"}`` (``relative``: diff over
    the ideal mean), groups in :data:`FAULTS` order; none for a controller without an ideal run."""
    rows = []
    for c in controllers:
        ideal = {int(e): v for e, v in zip(env[(group == "ideal") & (controller == c)],
                                           final[(group == "ideal") & (controller == c)])}
        for g in FAULTS:
            if g == "ideal":
                continue
            sel = (group == g) & (controller == c)
            pairs = [(v, ideal[int(e)]) for e, v in zip(env[sel], final[sel]) if int(e) in ideal]
            if not pairs:
                continue
            a, b = np.array(pairs).T
            d = a - b
            rows.append({"group": g, "controller": c, "n": len(d), "mean": float(a.mean()), "ideal": float(b.mean()),
                         "diff": float(d.mean()), "se": float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0,
                         "relative": float(d.mean() / b.mean())})
    return rows


def paired_markdown(rows: list[dict]) -> str:
    """:func:`paired_against_ideal` as a Markdown table: one row per group, one column per controller."""
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    groups = list(dict.fromkeys(r["group"] for r in rows))
    cell = {(r["group"], r["controller"]): r for r in rows}
    out = ["Each group against the ideal network, paired by environment: final cost, difference ± SE "
           "(relative to the ideal group's mean):", "",
           "| group | " + " | ".join(display_name(c) for c in controllers) + " |",
           "| --- | " + " | ".join("---" for _ in controllers) + " |"]
    for g in groups:
        vals = []
        for c in controllers:
            r = cell.get((g, c))
            vals.append("–" if r is None else f"{r['mean']:.3f}: {r['diff']:+.3f} ± {r['se']:.3f} ({r['relative']:+.1%})")
        out.append(f"| {g} | " + " | ".join(vals) + " |")
    return "\n".join(out)
