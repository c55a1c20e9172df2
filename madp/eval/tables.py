"""Markdown tables of a suite's summary (:func:`madp.eval.stats.summarize`): ``summary.md`` and the results report."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from madp.controllers import display_name

from .paper import PAPER_CONTROLLERS, PAPER_RESULTS, paper_results
from .stats import CONFIDENCE, finite, n_range

__all__ = ["ALL_ROW", "SAMPLER_NAMES", "best_markdown", "markdown_table", "sampling_markdown", "select_prose",
           "symmetry_markdown"]

#: Row label of the whole-suite row of the Markdown tables (and key of ``summary["overall"]``).
ALL_ROW = "all"

#: Sampler names in prose.
SAMPLER_NAMES = {"ddim": "DDIM", "dpm++": "DPM-Solver++(2M)"}


def select_prose(select: str, k: int) -> str:
    """How rule ``select`` among ``k`` samples per robot reads in the summary's prose (from its record,
    :data:`madp.selection.RULES`); empty for ``none`` and for a name that is not a rule."""
    from madp.selection import RULES

    r = RULES.get(select)
    if r is None or r.sees == "samples":
        return ""
    bound = " (an upper bound, not a controller robots could run)" if r.bound else ""
    return f", {k} samples per robot kept by {r.name}: {r.help}{bound}"


def _cell(st: Mapping[str, Any] | None) -> str:
    if not st:
        return "—"
    if st["n"] < 2 or not finite(st.get("se")):
        return f"{st['mean']:.3f} (n=1)" if st["n"] == 1 else f"{st['mean']:.3f}"
    return f"{st['mean']:.3f} ± {st['se']:.3f} [{st['ci_lo']:.3f}, {st['ci_hi']:.3f}]"


def _n_text(stats_by_ctrl: Mapping[str, Mapping[str, Any]]) -> str:
    return n_range(s["n"] for s in stats_by_ctrl.values())


def _md_row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def markdown_table(summary: Mapping[str, Any], suite: str | None = None) -> str:
    """Markdown tables of a :func:`summarize` dict (for ``summary.md`` and the results report).

    1. Final cost: rows = groups then ``all`` (the whole suite), columns = ``n`` (environments; a
       range when controllers differ), one column per controller with ``mean ± SE [lo, hi]`` (95 %
       t interval; ``mean (n=1)`` for a single environment, ``—`` when absent) and, for suites in
       :data:`PAPER_RESULTS`, a column ``paper DCVT / LPAC-K3 / MADP``.
    2. ``cities`` suite only (``summary["best"]``, :func:`madp.eval.stats.best_per_group`): per
       controller, in how many cities it ends at the lowest mean cost, "best in k of n cities"; the
       clairvoyant expert (an oracle) is not counted, and the caption says so.
       ``symmetry`` suite only (``summary["symmetry"]``): :func:`symmetry_markdown`.
    3. Mean wall time per control step (ms): same rows and controller columns.
    4. ``scale`` suite only: per baseline, the N × F matrix of relative improvement of MADP.
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
    header = ["group", "n"] + [display_name(c) for c in controllers]
    if has_paper:
        header.append("paper " + " / ".join(display_name(c) for c in PAPER_CONTROLLERS))
    lines += [_md_row(header), _md_row(["---"] * len(header))]
    for (label, by_ctrl), key in zip(rows, row_keys):
        cells = [label, _n_text(by_ctrl)] + [_cell(by_ctrl.get(c)) for c in controllers]
        if has_paper:
            paper = paper_results(suite, key)
            cells.append(" / ".join(f"{paper[c]:.2f}" if c in paper else "—" for c in PAPER_CONTROLLERS)
                         if paper else "—")
        lines.append(_md_row(cells))

    if summary.get("best"):
        lines += ["", best_markdown(summary["best"])]
    if summary.get("symmetry"):
        lines += ["", symmetry_markdown(summary["symmetry"])]

    lines += ["", f"Mean wall time per control step (ms), suite `{suite}`:", ""]
    header = ["group"] + [display_name(c) for c in controllers]
    lines += [_md_row(header), _md_row(["---"] * len(header))]
    for label, by_ctrl in rows:
        lines.append(_md_row([label] + [f"{by_ctrl[c]['mean_step_ms']:.2f}" if c in by_ctrl and
                                        finite(by_ctrl[c].get("mean_step_ms")) else "—"
                                        for c in controllers]))

    for baseline, m in (summary.get("scale_improvement") or {}).items():
        imp = np.asarray(m["improvement"], dtype=float)
        lines += ["", f"Relative improvement (B̄ − M̄)/B̄ of {display_name(m['method'])} over "
                  f"{display_name(baseline)} (rows N robots, columns F features):", ""]
        header = ["N \\ F"] + [str(f) for f in m["num_features"]]
        lines += [_md_row(header), _md_row(["---"] * len(header))]
        for i, nr in enumerate(m["num_robots"]):
            lines.append(_md_row([str(nr)] + [f"{v:+.1%}" if math.isfinite(v) else "—" for v in imp[i]]))
    return "\n".join(lines) + "\n"


def best_markdown(best: Mapping[str, Any], what: str = "cities") -> str:
    """The table of :func:`madp.eval.stats.best_per_group`: per controller, "best in k of n cities"."""
    n = best["groups"]
    lines = [f"Best controller per city: the lowest mean final cost of the city; ties count for each tied "
             f"controller."]
    if best["excluded"]:
        lines[0] += (f" {' and '.join(display_name(c) for c in best['excluded'])} (an oracle: it sees the whole "
                     f"map, no deployed swarm does) is shown in the tables but not counted.")
    lines += ["", _md_row(["controller", "best in"]), _md_row(["---", "---"])]
    lines += [_md_row([display_name(c), f"{k} of {n} {what}"]) for c, k in best["counts"].items()]
    return "\n".join(lines)


def symmetry_markdown(check: Mapping[str, Any]) -> str:
    """The table of :func:`madp.eval.stats.symmetry_check`: per controller and layout, each image's mean
    final cost and its deviation from the layout's mean over the images, and how many images lie within
    one SE of it."""
    images = sorted({g for layouts in check.values() for lay in layouts.values() for g in lay["by_image"]})
    lines = ["Symmetry: each image's mean final cost (its deviation from the layout's mean over the images); "
             "✓ where the deviation is within the image's SE. Paired: each image against the mean of the "
             "others, environment by environment: the largest |z| and the chance an exactly symmetric policy "
             "shows one at least that large (family-wise p).", ""]
    header = ["controller", "layout", "mean"] + [f"image {g}" for g in images] + ["within one SE", "paired max |z| (p)"]
    lines += [_md_row(header), _md_row(["---"] * len(header))]
    for c, layouts in check.items():
        for layout, lay in layouts.items():
            cells = [f"{r['mean']:.3f} ({r['deviation']:+.3f}){' ✓' if r['within_se'] else ''}"
                     if (r := lay["by_image"].get(g)) else "—" for g in images]
            paired = f"{lay['max_abs_z']:.2f} ({lay['familywise_p']:.2f})" if "max_abs_z" in lay else "—"
            lines.append(_md_row([display_name(c), layout, f"{lay['mean']:.3f}"] + cells
                                 + [f"{lay['within']} of {lay['images']}", paired]))
    return "\n".join(lines)


def sampling_markdown(sampling: Mapping[str, Mapping[str, Any]]) -> str:
    """The line naming how each sampling controller sampled (``summary["sampling"]``, :func:`madp.eval.stats.sampling_used`)."""
    return "MADP sampling: " + "; ".join(
        f"{display_name(c)}: {SAMPLER_NAMES.get(v['sampler'], v['sampler'])}, S = {v['sampling_steps']}"
        + (", initial noise fixed per episode" if v.get("fixed_noise") else "")
        + (", in a random rotation/reflection of the world per step" if v.get("frame") == "d4" else "")
        + select_prose(v.get("select", "none"), v.get("candidates", 1))
        for c, v in sampling.items()) + "."
