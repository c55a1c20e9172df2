"""The paper's numbers: what an evaluation's tables put beside ours."""

from __future__ import annotations

from madp.controllers import CONTROLLERS

__all__ = ["PAPER_CONTROLLERS", "PAPER_RESULTS", "paper_results"]

#: Controllers the paper reports, in the order of the paper column (the registry's ``paper``).
PAPER_CONTROLLERS: tuple[str, ...] = tuple(dict.fromkeys(c.paper for c in CONTROLLERS.values() if c.paper))

#: The paper's normalised cost after 600 steps. ``PAPER_RESULTS[suite]`` maps a row of the
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


def paper_results(suite: str, row: str) -> dict[str, float]:
    """The paper's numbers for one Markdown row (a group name or ``"all"``); ``{}`` when none."""
    return dict(PAPER_RESULTS.get(suite, {}).get(row, {}))
