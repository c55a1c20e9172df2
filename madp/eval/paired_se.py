"""How many environments a paired comparison needs: ``madp eval --paired-se S``.

A setting is judged by MADP's paired difference of final cost J(T)/J(0) against a run on the same
environments (``madp eval compare --shared``). The difference's spread per environment, σ_d, is read
from the kept results (:data:`PAIRED_SD_FILE`, written by ``scripts/paired_sd.py``): the median over
kept runs of another setting of the standard deviation over a suite's environments. The mean of n
paired differences then has standard error σ_d / √n, so a target S needs n = ⌈(σ_d / S)²⌉
environments of the suite, spread evenly over its groups (the cities suite's groups are its cities,
one environment each: n cities). The environments are each group's first, the same scenario seeds as a
full run's, so the subset pairs with a kept full run.
"""

from __future__ import annotations

import json
import math
from importlib import resources

from madp.errors import SettingError

#: The kept spread of MADP's paired differences per suite (``scripts/paired_sd.py``).
PAIRED_SD_FILE = "paired_sd.json"


def paired_sd(suite: str) -> float:
    """σ_d of ``suite``: the standard deviation of MADP's paired difference of final cost per environment."""
    table = json.loads(resources.files("madp.eval").joinpath(PAIRED_SD_FILE).read_text(encoding="utf-8"))["suites"]
    if suite not in table:
        raise SettingError("paired_se", f"no kept spread of paired differences for suite {suite!r}; "
                                        f"expected one of {', '.join(table)}")
    return float(table[suite]["sd"])


def envs_for_se(suite: str, se: float, groups: int, cap: int) -> int:
    """Environments per group so that the mean paired difference over ``suite``'s ``groups`` groups has
    standard error at most ``se`` (at most ``cap`` per group; cities: ``groups`` is 1, the count is cities)."""
    if isinstance(se, bool) or not isinstance(se, (int, float)) or not math.isfinite(se) or se <= 0:
        raise SettingError("paired_se", f"expected a standard error > 0 (e.g. 0.01), got {se!r}")
    total = math.ceil((paired_sd(suite) / se) ** 2)
    return max(1, min(cap, math.ceil(total / max(1, groups))))
