"""Two blocks of ``madp eval report`` beside the tables of :mod:`madp.eval.results_pages`:

* ``step-time``: how long a control step takes at the default, from a kept ``madp bench infer --out`` file
  named by ``kept.json``'s ``bench`` entry (``{"file", "date", "commit", "machine", "command"}``);
* ``network-default``: where the ``faults`` suite's ideal network and the default's run of the same
  environments differ, environment by environment, and why they may.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from madp.controllers import display_name
from madp.errors import InputError
from madp.io.jsonfile import read_json

if TYPE_CHECKING:
    from .results_pages import Kept

__all__ = ["network_default_note", "step_time_table"]

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


def step_time_table(kept: Kept) -> str:
    """The default's control step from the kept benchmark: the whole swarm's decentralized step in
    PyTorch and, where measured, one robot's step in the torch-free runtime, with the command, the
    machine, the date and the commit."""
    spec = kept.spec.get("bench")
    if not spec:
        return "No kept benchmark."
    where = f"{kept.root / 'kept.json'}: bench"
    missing = [k for k in ("file", "date", "commit", "machine", "command") if not spec.get(k)]
    if missing:
        raise InputError(f"{where}: expected {', '.join(missing)}")
    bench = read_json(kept.root / spec["file"], "expected the figures of madp bench infer --out")
    entry, settings = _default_step(bench, str(kept.root / spec["file"]))
    n = entry.get("num_robots")
    rows = [("| control step | time | measured |", "| --- | --- | --- |"),
            (f"| the swarm's decentralized step, every robot on its own neighbourhood (N = {n}, PyTorch, "
             f"{entry.get('threads')} threads) | {entry['latency_s'] * 1e3:.1f} ms | median of the calls |",)]
    robot = bench.get("robot_runtime")
    if robot:
        rows.append((f"| one robot's step, the torch-free runtime of `madp export` (onnxruntime, {robot.get('threads')} "
                     f"thread; {robot.get('mean_neighbourhood'):.1f} robots per neighbourhood) | "
                     f"{robot['onnxruntime_per_robot_s'] * 1e3:.1f} ms | mean over the swarm's robots |",))
    lines = [f"MADP at the default ({settings}), observations and choice included:", ""]
    lines += [r for row in rows for r in row]
    lines += ["", f"Measured {spec['date']} at commit `{spec['commit']}` on {spec['machine']}: `{spec['command']}` "
                  f"(`{spec['file']}`)."]
    if bench.get("paper_latency_s"):
        lines[-1] += f" The paper's: {bench['paper_latency_s']} s per control step on an RTX 3090."
    return "\n".join(lines)


def network_default_note(kept: Kept, network_suite: str = "faults", ideal: str = "ideal") -> str:
    """For each controller, the environments where the network suite's ideal group and the default's run
    of the same scenarios (matched by seed) end apart, by :data:`AGREE` or more."""
    if network_suite not in kept.default:
        return f"No kept `{network_suite}` results."
    net = kept.default[network_suite]
    by_seed = {}  # scenario seed -> (suite, environment key) of the default's other suites
    for suite, cols in kept.default.items():
        if suite != network_suite:
            by_seed.update({(int(s), str(c)): (suite, f"{g}-{int(e):03d}", float(f)) for s, c, g, e, f in
                            zip(cols["scenario_seed"], cols["controller"], cols["group"], cols["env"], cols["final_cost"])})
    parts, suites, n_same = [], set(), 0
    sel = net["group"] == ideal
    for c in dict.fromkeys(net["controller"][sel].tolist()):
        pairs = [(by_seed[int(s), c], float(f)) for s, cc, f in zip(net["scenario_seed"][sel], net["controller"][sel],
                                                                     net["final_cost"][sel]) if cc == c and (int(s), c) in by_seed]
        if not pairs:
            continue
        suites.update(p[0][0] for p in pairs)
        differ = [(key, base, f) for (_, key, base), f in pairs if abs(f - base) >= AGREE]
        n_same = len(pairs)
        if differ:
            shown = "; ".join(f"`{key}` {f:.3f} against {base:.3f}" for key, base, f in differ[:3])
            parts.append(f"{display_name(c)} on {len(pairs) - len(differ)} of {len(pairs)} ({shown}"
                         f"{'; …' if len(differ) > 3 else ''})")
        else:
            parts.append(f"{display_name(c)} on all {len(pairs)}")
    if not parts:
        return f"The `{network_suite}` suite's `{ideal}` group shares no environment with the default's other runs."
    return (f"The `{ideal}` network's environments are the {n_same} of {', '.join(f'`{s}`' for s in sorted(suites))} "
            f"above, with the same seeds; they end where the default's run ends, to {AGREE:g}, for " + ", ".join(parts) + ".")
