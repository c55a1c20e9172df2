"""The faults suite's plots: the mean final cost of each controller against the network's loss rate
and against its delay (the groups of :data:`madp.eval.suites.FAULTS`, the ideal group at 0), with
one standard error. The cost curve across the robots' failure is the suite's ``cost_fail_25.png``."""

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
