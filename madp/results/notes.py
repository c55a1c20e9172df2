"""Two blocks of ``madp eval report`` beside the tables of :mod:`madp.results.pages`:

* ``step-time``: how long a control step takes at the default: the wall times the default's kept runs
  recorded and, where ``kept.json``'s ``bench`` entry (``{"file", "date", "commit", "machine", "command"}``)
  names a kept ``madp bench infer --out`` file (:mod:`madp.results.kept_schema`), its swarm's and robot's step;
* ``network-default``: where the ``faults`` suite's ideal network and the default's run of the same
  environments differ, environment by environment, and why they may.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from madp.controllers import display_name
from madp.errors import InputError
from madp.io.jsonfile import read_json

from madp.eval.stats import column, has_column, order_controllers

#: What these blocks read: a :class:`madp.results.pages.Kept` (this module does not import that one, which
#: imports it) and its ``runs`` entry of a directory (:func:`madp.results.pages.run_of`).
Kept = Any
RunOf = Callable[[dict, str], "dict | None"]

__all__ = ["network_default_note", "run_step_times", "step_time_table"]

#: Final costs closer than this agree: the tables' last digit (float rounding moves LPAC-K3's by ~1e-7).
AGREE = 1e-3


def _default_step(bench: dict[str, Any], where: str) -> tuple[dict[str, Any], str]:
    """The benchmark's entry for the evaluation default's decentralized control step (sampler, S, rule, K
    of :class:`madp.policies.SamplingSettings`) and its description."""
    from madp.models.samplers import DEFAULT_SAMPLER
    from madp.policies import SamplingSettings

    d = SamplingSettings()
    entry = next((x for x in bench.get("selection") or [] if x.get("select") == d.select and x.get("candidates") == d.candidates
                  and x.get("sampler") == d.sampler and x.get("num_steps") == d.sampling_steps), None)
    if entry is None:
        raise InputError(f"{where}: no decentralized control step at the default ({d.sampler} S = {d.sampling_steps}, "
                         f"`{d.select}` among K = {d.candidates}); measure it with madp bench infer --candidates "
                         f"{d.candidates}:{d.sampling_steps} --grid {DEFAULT_SAMPLER}:{d.sampling_steps}")
    return entry, f"`{d.select}` among K = {d.candidates}, DPM-Solver++(2M) S = {d.sampling_steps}, frame {d.frame}"


def run_step_times(kept: Kept, summaries: dict[str, dict[str, Any]], run_of: RunOf) -> str:
    """Each controller's mean wall time per control step and environment in the default's kept runs, per
    suite, with the dates and commits of the runs it comes from."""
    controllers = order_controllers(c for s in summaries.values() for c in s["controllers"])
    lines = ["| suite | " + " | ".join(map(display_name, controllers)) + " | measured |",
             "| --- " * (len(controllers) + 2) + "|"]
    for suite, summary in summaries.items():
        stats = summary["overall"]
        runs = dict.fromkeys(f"{r.get('date', '')} `{r.get('commit', '')}`" for rel in kept.spec["default"]["dirs"]
                             if kept.configs[rel].get("suite") == suite and (r := run_of(kept.spec, rel)) is not None)
        cells = [f"{stats[c]['mean_step_ms']:.1f}" if c in stats else "—" for c in controllers]
        lines.append(f"| `{suite}` | " + " | ".join(cells) + f" | {', '.join(runs)} |")
    return "\n".join(lines)


def step_time_table(kept: Kept, summaries: dict[str, dict[str, Any]], run_of: RunOf) -> str:
    """How long a control step takes at the default: the kept runs' own wall times
    (:func:`run_step_times`) and, where ``kept.json`` names one, the kept benchmark's swarm and robot
    steps with the command, the machine, the date and the commit."""
    lines = ["`madp eval`'s wall time per control step and environment (ms, mean over the environments) in the "
             "runs above: one thread per worker process, a worker on every core; a learned controller steps 8 "
             "environments at a time, each charged an eighth of the batch's step. It depends on what else the "
             "machine ran.", "", run_step_times(kept, summaries, run_of)]
    spec = kept.spec.get("bench")
    if not spec:
        return "\n".join(lines)
    bench = read_json(kept.root / spec["file"], "expected the figures of madp bench infer --out")
    entry, settings = _default_step(bench, str(kept.root / spec["file"]))
    lines += ["", f"One control step of MADP at the default ({settings}), observations and choice included:", "",
              "| control step | time | measured |", "| --- | --- | --- |",
              f"| the swarm's decentralized step, every robot on its own neighbourhood (N = {entry.get('num_robots')}, "
              f"PyTorch, {entry.get('threads')} threads) | {entry['latency_s'] * 1e3:.1f} ms | median of the calls |"]
    robot = bench.get("robot_runtime")
    if robot:
        lines.append(f"| one robot's step, the torch-free runtime of `madp export` (onnxruntime, {robot.get('threads')} "
                     f"thread; {robot.get('mean_neighbourhood'):.1f} robots per neighbourhood) | "
                     f"{robot['onnxruntime_per_robot_s'] * 1e3:.1f} ms | mean over the swarm's robots |")
    lines += ["", f"Measured {spec['date']} at commit `{spec['commit']}` on {spec['machine']}: `{spec['command']}` "
                  f"(`{spec['file']}`)."]
    if bench.get("paper_latency_s"):
        lines[-1] += f" The paper's: {bench['paper_latency_s']} s per control step on an RTX 3090."
    return "\n".join(lines)


def network_default_note(kept: Kept, network_suite: str = "faults", ideal: str = "ideal") -> str:
    """For each controller, the environments where the network suite's ideal group and the default's run
    of the same scenarios (matched by seed, and for MADP by its selection rule) end apart, by
    :data:`AGREE` or more; a controller whose runs chose by different rules is named, not paired."""
    if network_suite not in kept.default:
        return f"No kept `{network_suite}` results."
    net = kept.default[network_suite]
    rule = lambda cols: column(cols, "select").astype(str) if has_column(cols, "select") else np.full(len(cols["controller"]), "")  # noqa: E731
    base = {}  # (scenario seed, controller) -> (suite, environment key, final cost, rule) in the default's other suites
    for suite, cols in kept.default.items():
        if suite != network_suite:
            base.update({(int(s), str(c)): (suite, f"{g}-{int(e):03d}", float(f), str(r)) for s, c, g, e, f, r in
                         zip(cols["scenario_seed"], cols["controller"], cols["group"], cols["env"], cols["final_cost"],
                             rule(cols))})
    sel = net["group"] == ideal
    shared = [(int(s), str(c), float(f), str(r)) for s, c, f, r in zip(net["scenario_seed"][sel], net["controller"][sel],
                                                                      net["final_cost"][sel], rule(net)[sel])
              if (int(s), str(c)) in base]
    if not shared:
        return f"The `{network_suite}` suite's `{ideal}` group shares no environment with the default's other runs."
    rows = [(s, c, f) for s, c, f, r in shared if base[s, c][3] == r]
    other = {c: (r, base[s, c][3]) for s, c, f, r in shared if base[s, c][3] != r}
    parts = []
    for c in order_controllers([r[1] for r in rows]):
        pairs = [(base[s, cc], f) for s, cc, f in rows if cc == c]
        differ = [(key, b, f) for (_, key, b, _), f in pairs if abs(f - b) >= AGREE]
        shown = "; ".join(f"`{key}` {f:.3f} against {b:.3f}" for key, b, f in differ[:3]) + ("; …" if len(differ) > 3 else "")
        parts.append(f"{display_name(c)} on {len(pairs) - len(differ)} of {len(pairs)} ({shown})" if differ
                     else f"{display_name(c)} on all {len(pairs)}")
    suites = sorted({base[s, c][0] for s, c, _, _ in shared})
    text = (f"The `{ideal}` network's environments are the {len({s for s, _, _, _ in shared})} of "
            f"{', '.join(f'`{s}`' for s in suites)} above, with the same seeds")
    if parts:
        text += f"; they end where the default's run ends, to {AGREE:g}, for " + ", ".join(parts)
    for c in order_controllers(list(other)):
        text += (f"; {display_name(c)} is not paired: it chose among its samples by `{other[c][0]}` there and by "
                 f"`{other[c][1]}` in the default's run")
    return text + "."
