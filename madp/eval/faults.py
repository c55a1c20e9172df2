"""The faults suite's report: each group paired against the ideal one on the same environments
(:func:`paired_against_ideal`, a table of ``summary.md``), ``fail_25`` paired against its reference
``survivors_25`` (the same survivors from the start), the bytes each robot put on the air per step
(:func:`bytes_on_air`), the environments that end above J(0), and the plot ``faults.png`` of the mean
final cost of each controller, with one standard error: against the network's i.i.d. loss rate
(``no_comm`` at 100 %, ``burst_30`` an open marker just right of ``loss_30``), against its delay (the ideal
group at 0 on both), and per group for the other networks. The cost curve across the robots'
failure is the suite's ``cost_fail_25.png`` (every group has its ``cost_<group>.png``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from madp.controllers import display_name

from .plots import _new_figure, _save
from .stats import column, has_column, paired_stats
from .suites import FAULTS

#: Each group read against another on the same environments (besides the ideal group): a failure
#: against the same survivors from the start.
REFERENCES = {"fail_25": "survivors_25"}


def _iid_loss(g: str) -> bool:
    s = FAULTS[g]
    return s.loss > 0 and s.burst_len == 0 and s.delay_steps == 0 and s.loss_at_range == 0


def fault_axes(dt_s: float) -> dict[str, list[tuple[str, float]]]:
    """The groups on each axis with their x values: ``loss`` (%, i.i.d. loss only) and ``delay`` (s),
    ideal at 0 on both; ``bursts``: the bursty groups at their mean loss (%); ``other``: every other
    group, at 0, 1, 2, … (the ideal group first)."""
    loss = [(g, 100 * s.loss) for g, s in FAULTS.items() if _iid_loss(g) or g == "ideal"]
    delay = [(g, s.delay_steps * dt_s) for g, s in FAULTS.items() if s.delay_steps > 0 or g == "ideal"]
    bursts = [(g, 100 * s.loss) for g, s in FAULTS.items() if s.burst_len > 0 and s.loss > 0]
    placed = {g for g, _ in loss + delay + bursts}
    other = ["ideal"] + [g for g in FAULTS if g not in placed]
    return {"loss": loss, "delay": delay, "bursts": bursts, "other": [(g, float(i)) for i, g in enumerate(other)]}


def plot_faults(path: Path, final: np.ndarray, group: np.ndarray, controller: np.ndarray,
                controllers: Sequence[str], colors: Mapping[str, str], suite: str, dt_s: float) -> Path | None:
    """Write :func:`faults_figure` to ``path``; None when the suite ran no axis' groups."""
    fig = faults_figure(final, group, controller, controllers, colors, suite, dt_s)
    return None if fig is None else _save(fig, path)


def _mean_se(v: np.ndarray) -> tuple[float, float] | None:
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else 0.0


def faults_figure(final: np.ndarray, group: np.ndarray, controller: np.ndarray, controllers: Sequence[str],
                  colors: Mapping[str, str], suite: str, dt_s: float):
    """Three panels of mean final cost ± SE per controller: against the i.i.d. loss rate (with the
    bursty groups as open markers), against the delay, and per other network. ``final``, ``group``,
    ``controller``: one entry per (environment, controller) of ``results.parquet``. None when no panel
    has two groups to show."""
    axes_groups = {k: [(g, x) for g, x in v if np.any(group == g)] for k, v in fault_axes(dt_s).items()}
    panels = [k for k in ("loss", "delay", "other") if len(axes_groups[k]) > 1]
    if not panels:
        return None
    fig = _new_figure(5.5 * len(panels), 4.4)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    width = 0.6 / max(len(controllers), 1)
    for ax, kind in zip(axes, panels):
        for k, c in enumerate(controllers):
            series = [("", axes_groups[kind], "o", colors[c])]
            if kind == "loss":
                series.append((" (bursts)", axes_groups["bursts"], "s", "none"))
            for suffix, points, marker, face in series:
                xs, means, ses = [], [], []
                for g, x in points:
                    m = _mean_se(final[(group == g) & (controller == c)])
                    if m is not None:
                        shift = (k - (len(controllers) - 1) / 2) * width if kind == "other" else 2.0 if suffix else 0.0
                        xs.append(x + shift)  # the bursts' marker just right of the i.i.d. point
                        means.append(m[0])
                        ses.append(m[1])
                if xs:
                    ax.errorbar(xs, means, yerr=ses, marker=marker, mfc=face, capsize=3, color=colors[c],
                                ls="none" if kind == "other" or suffix else "-", label=display_name(c) + suffix)
        if kind == "other":
            ax.set_xticks([x for _, x in axes_groups[kind]], [g for g, _ in axes_groups[kind]], rotation=30, fontsize=8)
            ax.set_xlabel("network")
        else:
            ax.set_xlabel("message loss (%)" if kind == "loss" else "message delay (s)")
        ax.set_ylabel("final normalised cost J(T) / J(0)")
        ax.set_title(f"{suite}: cost {'per network' if kind == 'other' else 'against ' + kind} (mean ± SE)",
                     fontsize=10)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def paired_against(final: np.ndarray, group: np.ndarray, env: np.ndarray, controller: np.ndarray,
                   controllers: Sequence[str], reference: str, groups: Sequence[str]) -> list[dict]:
    """Per (group of ``groups``, controller), the final cost paired with group ``reference``'s on the
    same environment: ``{"group", "reference", "controller", "n", "mean", "ideal", "diff", "se",
    "relative"}`` (``ideal``: the reference's mean on those environments; ``relative``: diff over it);
    none for a controller without a run of the reference."""
    rows = []
    for c in controllers:
        sel = (group == reference) & (controller == c)
        base = {int(e): v for e, v in zip(env[sel], final[sel])}
        for g in groups:
            if g == reference:
                continue
            sel = (group == g) & (controller == c)
            pairs = [(v, base[int(e)]) for e, v in zip(env[sel], final[sel]) if int(e) in base]
            if not pairs:
                continue
            a, b = np.array(pairs).T
            p = paired_stats(a - b)
            rows.append({"group": g, "reference": reference, "controller": c, "n": p["n"], "mean": float(a.mean()),
                         "ideal": float(b.mean()), "diff": p["diff"], "se": p["se"] if p["n"] > 1 else 0.0,
                         "relative": p["diff"] / float(b.mean())})
    return rows


def paired_against_ideal(final: np.ndarray, group: np.ndarray, env: np.ndarray, controller: np.ndarray,
                         controllers: Sequence[str]) -> list[dict]:
    """:func:`paired_against` the ideal group, every other group of :data:`FAULTS` in its order."""
    return paired_against(final, group, env, controller, controllers, "ideal", list(FAULTS))


def paired_markdown(rows: list[dict], reference: str = "the ideal network") -> str:
    """:func:`paired_against_ideal` (or :func:`paired_against` ``reference``) as a Markdown table: one
    row per group, one column per controller."""
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    groups = list(dict.fromkeys(r["group"] for r in rows))
    cell = {(r["group"], r["controller"]): r for r in rows}
    out = [f"Each group against {reference}, paired by environment: final cost, difference ± SE "
           f"(relative to {reference}'s mean):", "",
           "| group | " + " | ".join(display_name(c) for c in controllers) + " |",
           "| --- | " + " | ".join("---" for _ in controllers) + " |"]
    for g in groups:
        vals = []
        for c in controllers:
            r = cell.get((g, c))
            vals.append("–" if r is None else f"{r['mean']:.3f}: {r['diff']:+.3f} ± {r['se']:.3f} ({r['relative']:+.1%})")
        out.append(f"| {g} | " + " | ".join(vals) + " |")
    return "\n".join(out)


def bytes_on_air(bytes_per_step: np.ndarray, group: np.ndarray, controller: np.ndarray,
                 controllers: Sequence[str]) -> list[dict]:
    """Per (group, controller) with counted bytes: ``{"group", "controller", "n", "bytes_per_robot_step"}``,
    the mean over the environments of the bytes each robot put on the air per step (every channel)."""
    rows = []
    for g in FAULTS:
        for c in controllers:
            v = bytes_per_step[(group == g) & (controller == c)]
            v = v[np.isfinite(v)]
            if v.size:
                rows.append({"group": g, "controller": c, "n": int(v.size), "bytes_per_robot_step": float(v.mean())})
    return rows


def above_start(final: np.ndarray, group: np.ndarray, controller: np.ndarray, controllers: Sequence[str]) -> list[dict]:
    """Per (group, controller): ``{"group", "controller", "n", "above"}``, how many environments end with
    J(T) > J(0) (worse than where they started)."""
    rows = []
    for g in FAULTS:
        for c in controllers:
            v = final[(group == g) & (controller == c)]
            if v.size:
                rows.append({"group": g, "controller": c, "n": int(v.size), "above": int((v > 1.0).sum())})
    return rows


def _grid(rows: list[dict], title: str, fmt) -> str:
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    cell = {(r["group"], r["controller"]): r for r in rows}
    out = [title, "", "| group | " + " | ".join(display_name(c) for c in controllers) + " |",
           "| --- | " + " | ".join("---" for _ in controllers) + " |"]
    for g in dict.fromkeys(r["group"] for r in rows):
        out.append(f"| {g} | " + " | ".join("–" if (g, c) not in cell else fmt(cell[(g, c)]) for c in controllers) + " |")
    return "\n".join(out)


def faults_sections(results, controllers: Sequence[str]) -> tuple[dict, list[str]]:
    """The faults suite's part of the report from ``results`` (``results.parquet``): its entries of
    ``summary.json`` (``paired_against_ideal``, ``paired_against_reference``, ``bytes_per_robot_step``,
    ``above_start``) and its Markdown sections, in order."""
    final, group = column(results, "final_cost").astype(float), column(results, "group")
    env, ctrl = column(results, "env"), column(results, "controller")
    out = {"paired_against_ideal": paired_against_ideal(final, group, env, ctrl, controllers),
           "paired_against_reference": [r for g, ref in REFERENCES.items()
                                        for r in paired_against(final, group, env, ctrl, controllers, ref, [g])],
           "bytes_per_robot_step": bytes_on_air(column(results, "bytes_per_robot_step").astype(float), group, ctrl,
                                                controllers) if has_column(results, "bytes_per_robot_step") else [],
           "above_start": above_start(final, group, ctrl, controllers)}
    md = []
    if out["paired_against_ideal"]:
        md.append(paired_markdown(out["paired_against_ideal"]))
    if out["paired_against_reference"]:
        md.append(paired_markdown(out["paired_against_reference"], "`survivors_25`"))
    if out["bytes_per_robot_step"]:
        md.append(_grid(out["bytes_per_robot_step"], "Bytes each robot put on the air per step (every channel, "
                        "mean over the environments):", lambda r: f"{r['bytes_per_robot_step']:.0f}"))
    if any(r["above"] for r in out["above_start"]):
        md.append(_grid(out["above_start"], "Environments that end above J(0) (k of n):",
                        lambda r: f"{r['above']}/{r['n']}"))
    return out, md
