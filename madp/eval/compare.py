"""``madp eval compare``: finished evaluations side by side, paired on their shared environments.

A *run* is a suite directory written by ``madp eval`` (``OUT/<suite>/`` holding ``config.json`` and
``results.parquet``). The runs compared must hold the same suite, the same number of control steps
and the same environments (groups, indices and scenario seeds), so that every environment's final
cost can be paired across runs; otherwise :func:`compare_runs` refuses with one line naming what
differs. Within each run every controller must have run on every environment.

For every controller and group (and ``all``, pooling the suite's environments, when it has more
than one group) :func:`compare_runs` gives

* each run's mean final cost J(T)/J(0) over the group's environments;
* for every run but the baseline, the paired difference ``d_e = run_e − baseline_e`` per environment
  (negative: the run ends at a lower cost): its mean, standard error and Student-t 95 % interval
  (:func:`madp.eval.report.grouped_stats` over the differences);
* wins k/n: the environments on which the run ends strictly below the baseline (ties are counted
  apart in the JSON).

A controller is paired by its name: ``madp`` of one run with ``madp`` of the other, a named one
(``madp:r4``, :mod:`madp.controllers`) with the same name (the runs' checkpoints or sampler settings
are what differs; :func:`markdown` names the settings that do, ``madp:r4 checkpoint`` among them).

:func:`write_compare` writes ``compare.md``, ``compare.json`` and ``compare.png`` (the paired
differences per group with their intervals, :func:`madp.eval.compare_plot.plot_paired`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from madp.errors import InputError, SettingError
from madp.io.jsonfile import read_json

from .stats import CONFIDENCE, grouped_stats, order_controllers, order_groups, paired_stats

__all__ = ["Run", "load_run", "parse_run_argument", "name_runs", "compare_runs", "markdown", "write_compare"]

#: Columns of ``results.parquet`` a comparison reads.
RESULT_COLUMNS = ("suite", "group", "env", "scenario_seed", "controller", "final_cost")
#: Settings of ``config.json`` that describe the environments, not how the controllers ran.
_ENV_SETTINGS = ("suite", "num_envs", "env_keys", "env_seeds")


@dataclass(frozen=True)
class Run:
    """One finished suite directory. Arrays are aligned: one entry per (environment, controller)."""

    name: str
    path: Path
    config: dict
    group: np.ndarray  # str
    env: np.ndarray  # int64, index within its group
    seed: np.ndarray  # int64, scenario seed
    controller: np.ndarray  # str
    final_cost: np.ndarray  # float64, J(T)/J(0)

    @property
    def suite(self) -> str:
        return str(self.config["suite"])

    @property
    def steps(self) -> int:
        return int(self.config["steps"])

    def environments(self) -> set[tuple[str, int, int]]:
        """``{(group, env index, scenario seed)}`` of this run."""
        return set(zip(self.group.tolist(), self.env.tolist(), self.seed.tolist()))


def _suite_dirs_below(path: Path) -> list[str]:
    return sorted(p.parent.name for p in path.glob("*/results.parquet"))


def load_run(path: str | Path, name: str | None = None) -> Run:
    """Read a finished suite directory; ``ValueError`` (one line, naming the file) if it is not one.
    ``name`` may be left empty (:func:`name_runs` names the runs)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{path}: no such run directory (expected a suite directory of madp eval, OUT/<suite>/)")
    results_file, config_file = path / "results.parquet", path / "config.json"
    if not results_file.is_file():
        below = _suite_dirs_below(path)
        if below:
            raise InputError(f"{path}: holds the suites {', '.join(below)}, not one; pass one of them, e.g. {path / below[0]}")
        raise InputError(f"{results_file}: not found; expected a finished madp eval suite directory (OUT/<suite>/)")
    config = read_json(config_file, "expected a finished madp eval suite directory (OUT/<suite>/)")
    if not isinstance(config, dict) or not isinstance(config.get("suite"), str) or not isinstance(config.get("steps"), int):
        raise InputError(f"{config_file}: expected madp eval's config (a JSON object with 'suite' and 'steps')")
    try:
        table = pq.read_table(results_file)
    except (OSError, pa.ArrowException) as e:
        raise InputError(f"{results_file}: unreadable Parquet ({type(e).__name__}: {e})") from None
    missing = [c for c in RESULT_COLUMNS if c not in table.column_names]
    if missing:
        raise InputError(f"{results_file}: no column {missing[0]!r}; expected results.parquet of madp eval")
    cols = {c: table.column(c).to_numpy(zero_copy_only=False) for c in RESULT_COLUMNS}
    run = Run(name or "", path, config, cols["group"].astype(str), cols["env"].astype(np.int64),
              cols["scenario_seed"].astype(np.int64), cols["controller"].astype(str),
              cols["final_cost"].astype(np.float64))
    _check_run(run, results_file, cols["suite"].astype(str))
    return run


def _check_run(run: Run, results_file: Path, suite: np.ndarray) -> None:
    """One suite, finite costs, every controller once on every environment of the run."""
    if suite.size == 0:
        raise InputError(f"{results_file}: no rows")
    if set(suite.tolist()) != {run.suite}:
        raise InputError(f"{results_file}: holds suite(s) {sorted(set(suite.tolist()))}, config.json says {run.suite!r}")
    bad = np.flatnonzero(~np.isfinite(run.final_cost))
    if bad.size:
        i = int(bad[0])
        raise InputError(f"{results_file}: final_cost is {run.final_cost[i]} for controller {str(run.controller[i])!r}, "
                         f"group {str(run.group[i])!r}, env {int(run.env[i])}; expected a finite cost")
    envs = run.environments()
    if len({(g, e) for g, e, _ in envs}) != len(envs):
        raise InputError(f"{results_file}: an environment appears with two scenario seeds")
    for c in order_controllers(run.controller.tolist()):
        sel = run.controller == c
        rows = list(zip(run.group[sel].tolist(), run.env[sel].tolist(), run.seed[sel].tolist()))
        if len(set(rows)) != len(rows):
            raise InputError(f"{results_file}: controller {c!r} has two rows for one environment")
        if set(rows) != envs:
            raise InputError(f"{results_file}: controller {c!r} ran on {len(rows)} of the run's {len(envs)} environments")


def parse_run_argument(text: str) -> tuple[str | None, Path]:
    """``NAME=PATH`` or ``PATH`` (a path that exists is taken whole, even with an ``=`` in it)."""
    name, sep, path = text.partition("=")
    if sep and name and "/" not in name and not Path(text).exists():
        return name, Path(path)
    return None, Path(text)


def load_runs(arguments: Sequence[str]) -> list[Run]:
    """The runs named on the command line (``PATH`` or ``NAME=PATH`` each), named apart."""
    if len(arguments) < 2:
        raise SettingError("runs", f"expected at least two run directories, got {len(arguments)}")
    return name_runs([load_run(path, name) for name, path in map(parse_run_argument, arguments)])


def name_runs(runs: Sequence[Run]) -> list[Run]:
    """The runs with short distinct names where they have none: the directory above ``OUT/<suite>/``
    (``OUT``'s last part), else the directory's own name; the path as given where those collide."""
    def short(r: Run) -> str:
        p = r.path.resolve()
        return p.parent.name if p.name == r.suite and p.parent.name else p.name

    names = [r.name or short(r) for r in runs]
    if len(set(names)) < len(names):
        names = [r.name or str(r.path) for r in runs]
    seen: dict[str, int] = {}
    for i, n in enumerate(names):
        seen[n] = seen.get(n, 0) + 1
        if seen[n] > 1:  # the same directory given twice
            names[i] = f"{n}#{seen[n]}"
    return [replace(r, name=n) for r, n in zip(runs, names)]


def _env_difference(a: Run, b: Run) -> str | None:
    """One environment that tells ``a`` and ``b`` apart, in words; None when they are the same."""
    ka = {(g, e): s for g, e, s in a.environments()}
    kb = {(g, e): s for g, e, s in b.environments()}
    groups = order_groups([g for g, _ in ka] + [g for g, _ in kb])
    for key in sorted(set(ka) | set(kb), key=lambda k: (groups.index(k[0]), k[1])):
        g, e = key
        if key not in kb:
            return f"group {g!r} env {e} is in {a.name} only"
        if key not in ka:
            return f"group {g!r} env {e} is in {b.name} only"
        if ka[key] != kb[key]:
            return f"group {g!r} env {e} has scenario seed {ka[key]} in {a.name} and {kb[key]} in {b.name}"
    return None


def shared_environments(runs: Sequence[Run]) -> list[Run]:
    """``runs`` each restricted to the environments (group, index and scenario seed) that every one of
    them holds: a run on a subset of a suite's environments (``madp eval --paired-se``) paired with a
    full run of the same suite. One line naming the runs when they share none."""
    shared = set.intersection(*(r.environments() for r in runs))
    if not shared:
        raise SettingError("runs", message=f"runs {', '.join(r.name for r in runs)} share no environment "
                           "(group, index and scenario seed); --shared pairs runs of one suite")
    out = []
    for r in runs:
        keep = np.array([k in shared for k in zip(r.group.tolist(), r.env.tolist(), r.seed.tolist())], dtype=bool)
        out.append(replace(r, group=r.group[keep], env=r.env[keep], seed=r.seed[keep], controller=r.controller[keep],
                           final_cost=r.final_cost[keep]))
    return out


def _check_comparable(runs: Sequence[Run], base: Run) -> None:
    for r in runs:
        if r is base:
            continue
        if r.suite != base.suite:
            raise SettingError("runs", message=f"runs differ in suite: {base.name} is {base.suite!r}, {r.name} is {r.suite!r}; "
                             "compare needs runs of one suite")
        if r.steps != base.steps:
            raise SettingError("runs", message=f"runs differ in steps: {base.name} ran {base.steps}, {r.name} {r.steps} control steps; "
                             "their final costs are not comparable")
        diff = _env_difference(base, r)
        if diff:
            raise SettingError("runs", message=f"runs differ in their environments ({base.name}: {len(base.environments())}, "
                             f"{r.name}: {len(r.environments())}): {diff}; compare needs the same suite, "
                             "--num-envs and cities")


def _settings(run: Run) -> dict[str, Any]:
    """How a run's controllers ran (its config.json less the environments): sampler settings and
    each checkpoint's sha256."""
    out = {k: v for k, v in run.config.items() if k not in _ENV_SETTINGS and k != "checkpoints"}
    for kind, ck in sorted((run.config.get("checkpoints") or {}).items()):
        if isinstance(ck, dict):
            out[f"{kind} checkpoint"] = ck.get("sha256")
    return out


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _stats_row(gi: np.ndarray, n_groups: int, costs: dict[str, np.ndarray], base: str,
               confidence: float) -> list[dict[str, Any]]:
    """Per group index: n, each run's mean, and each other run's paired difference to ``base``."""
    rows: list[dict[str, Any]] = [{"n": 0, "mean": {}, "paired": {}} for _ in range(n_groups)]
    for name, c in costs.items():
        st = grouped_stats(gi, c, confidence)
        for j, k in enumerate(st["key"].tolist()):
            rows[k]["n"] = int(st["n"][j])
            rows[k]["mean"][name] = float(st["mean"][j])
    if base not in costs:
        return rows
    for name, c in costs.items():
        if name == base:
            continue
        d = c - costs[base]
        for k in np.unique(gi).tolist():
            p = paired_stats(d[gi == k], confidence)
            rows[k]["paired"][name] = {**p, "se": _num(p["se"])}
    return rows


def compare_runs(runs: Sequence[Run], baseline: str | None = None, confidence: float = CONFIDENCE,
                 shared: bool = False) -> dict[str, Any]:
    """The comparison of ``runs`` (at least two) against the run named ``baseline`` (default: the first);
    ``shared``: on the environments every run holds (:func:`shared_environments`), not all of each.

    Returns ``{"suite", "steps", "confidence", "baseline", "runs": [{"name", "path", "settings"}],
    "differing_settings": [names], "groups", "controllers", "by_controller": {controller: {"runs":
    [names that ran it], "groups": {group: row}, "all": row | None}}}``; a row is ``{"n", "mean":
    {run: mean final cost}, "paired": {run: {"n", "diff", "se", "ci_lo", "ci_hi", "wins", "ties"}}}``
    (``paired`` is empty where the baseline did not run the controller; ``se`` is None for n = 1;
    ``all`` is None for a suite of one group). Groups in natural order, controllers in the report's order.

    Raises:
        ValueError: fewer than two runs, an unknown baseline, or runs of another suite, other steps or
            other environments (one line naming what differs).
    """
    if len(runs) < 2:
        raise SettingError("runs", "expected at least two runs to compare")
    full = {r.name: len(r.environments()) for r in runs}
    if shared:
        runs = shared_environments(runs)
    by_name = {r.name: r for r in runs}
    base_name = baseline if baseline is not None else runs[0].name
    if base_name not in by_name:
        paths = {str(r.path): r.name for r in runs} | {str(r.path.resolve()): r.name for r in runs}
        resolved = str(Path(base_name).resolve()) if base_name else base_name
        base_name = paths.get(base_name) or paths.get(resolved)
        if base_name is None:
            raise SettingError("baseline", f"expected one of the runs ({', '.join(by_name)}) or its path, got {baseline!r}")
    base = by_name[base_name]
    _check_comparable(runs, base)

    groups = order_groups(g for g, _, _ in base.environments())
    rank = {g: i for i, g in enumerate(groups)}
    envs = sorted(base.environments(), key=lambda x: (rank[x[0]], x[1]))
    row_of = {(g, e): i for i, (g, e, _) in enumerate(envs)}
    gi = np.array([rank[g] for g, _, _ in envs], dtype=np.int64)
    controllers = order_controllers(c for r in runs for c in r.controller.tolist())

    by_controller: dict[str, Any] = {}
    for c in controllers:
        costs: dict[str, np.ndarray] = {}
        for r in runs:
            sel = r.controller == c
            if not sel.any():
                continue
            cost = np.empty(len(envs))
            cost[[row_of[(g, e)] for g, e in zip(r.group[sel].tolist(), r.env[sel].tolist())]] = r.final_cost[sel]
            costs[r.name] = cost
        per_group = _stats_row(gi, len(groups), costs, base.name, confidence)
        pooled = _stats_row(np.zeros(len(envs), dtype=np.int64), 1, costs, base.name, confidence)[0]
        by_controller[c] = {"runs": list(costs), "groups": dict(zip(groups, per_group)),
                            "all": pooled if len(groups) > 1 else None}

    settings = {r.name: _settings(r) for r in runs}
    keys = list(dict.fromkeys(k for s in settings.values() for k in s))
    differing = [k for k in keys if len({json.dumps(s.get(k), sort_keys=True) for s in settings.values()}) > 1]
    return {"suite": base.suite, "steps": base.steps, "confidence": confidence, "baseline": base.name,
            "runs": [{"name": r.name, "path": str(r.path), "settings": settings[r.name]} for r in runs],
            "differing_settings": differing, "groups": groups, "environments": len(envs),
            "shared_of": full if shared else None,
            "controllers": controllers, "by_controller": by_controller}


# --------------------------------------------------------------------------------------------------
# Markdown
# --------------------------------------------------------------------------------------------------


def _md_row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"


def _setting_text(value: Any, key: str) -> str:
    if value is None:
        return "—"
    if key.endswith("checkpoint") and isinstance(value, str):
        return value[:12]
    return str(value)


def _diff_cell(p: dict[str, Any] | None) -> str:
    if not p:
        return "—"
    if p["se"] is None:
        return f"{p['diff']:+.3f} (n=1)"
    return f"{p['diff']:+.3f} ± {p['se']:.3f} [{p['ci_lo']:+.3f}, {p['ci_hi']:+.3f}]"


def _wins_cell(p: dict[str, Any] | None) -> str:
    if not p:
        return "—"
    return f"{p['wins']}/{p['n']}" + (f" ({p['ties']} tied)" if p["ties"] else "")


def markdown(cmp: dict[str, Any]) -> str:
    """The comparison as Markdown: the runs and the settings they differ in, then one table per
    controller (rows: groups, then ``all``; columns: n, each run's mean, and per other run the paired
    difference ``mean ± SE [95 % interval]`` and its wins k/n)."""
    base, names = cmp["baseline"], [r["name"] for r in cmp["runs"]]
    others = [n for n in names if n != base]
    level = cmp["confidence"]
    lines = [f"### Compare: suite `{cmp['suite']}`, {cmp['environments']} environments, {cmp['steps']} steps", ""]
    lines.append("Runs: " + ", ".join(f"**{r['name']}** = `{r['path']}`" + (" (baseline)" if r["name"] == base else "")
                                      for r in cmp["runs"]) + ".")
    if cmp.get("shared_of"):
        lines += ["", f"Paired on the {cmp['environments']} environments every run holds (of "
                  + ", ".join(f"{n}'s {k}" for n, k in cmp["shared_of"].items()) + ")."]
    if cmp["differing_settings"]:
        header = ["run"] + cmp["differing_settings"]
        lines += ["", "They differ in:", "", _md_row(header), _md_row(["---"] * len(header))]
        for r in cmp["runs"]:
            lines.append(_md_row([r["name"]] + [_setting_text(r["settings"].get(k), k) for k in cmp["differing_settings"]]))
    else:
        lines += ["", "Their config.json settings and checkpoints are the same."]
    lines += ["", f"Final cost J(T)/J(0), lower is better. Paired difference d = run − {base} on the same "
              f"environments: mean ± SE [{level:.0%} Student-t interval]; wins: environments where the run ends "
              f"below {base}."]
    for c, block in cmp["by_controller"].items():
        ran = block["runs"]
        paired = [n for n in others if n in ran and base in ran]
        header = ["group", "n"] + [n for n in names if n in ran]
        for n in paired:
            header += [f"{n} − {base}", f"{n} wins"]
        lines += ["", f"#### `{c}`" + ("" if base in ran else f" (not run by {base}: no paired difference)"), "",
                  _md_row(header), _md_row(["---"] * len(header))]
        rows = list(block["groups"].items()) + ([("**all**", block["all"])] if block["all"] else [])
        for label, row in rows:
            cells = [label, str(row["n"])] + [f"{row['mean'][n]:.3f}" for n in names if n in ran]
            for n in paired:
                p = row["paired"].get(n)
                cells += [_diff_cell(p), _wins_cell(p)]
            lines.append(_md_row(cells))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------------


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


def write_compare(cmp: dict[str, Any], out_dir: str | Path) -> dict[str, Path]:
    """Write ``compare.md``, ``compare.png`` (when some controller has a paired difference) and
    ``compare.json`` (listing the files) into ``out_dir``, each atomically. Returns ``{name: path}``."""
    from madp.io.atomic import atomic_path, write_text_atomic

    from .compare_plot import plot_paired

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    png = out_dir / "compare.png"
    fig = plot_paired(cmp)
    drawn = fig is not None
    if drawn:
        with atomic_path(png, ".png", fsync=False) as tmp:
            fig.savefig(tmp, format="png")
        written[png.name] = png
    else:
        png.unlink(missing_ok=True)  # a plot of an earlier comparison here would not match compare.md
    md = markdown(cmp) + (f"\n![paired differences]({png.name})\n" if drawn else "")
    written["compare.md"] = write_text_atomic(out_dir / "compare.md", md, fsync=False)
    doc = {**cmp, "files": sorted([*written, "compare.json"])}
    written["compare.json"] = write_text_atomic(out_dir / "compare.json",
                                                json.dumps(_json_safe(doc), indent=1, allow_nan=False) + "\n", fsync=False)
    return written
