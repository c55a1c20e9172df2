"""``madp``: the command line. Thin commands that parse options and call the layers.

User mistakes (a bad flag, a missing or malformed file, a wrong schema version) end with one line
``madp: error: …`` on stderr and exit status 2; set MADP_DEBUG=1 to see the traceback instead.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import List, Optional

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, rich_markup_mode=None,
                  help="Multi-agent diffusion policies for coverage control: datasets, training, evaluation.")
bench_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Benchmarks (medians, with a baseline measured in the same run).")
app.add_typer(bench_app, name="bench")


class UserError(Exception):
    """A mistake in what the user asked for; printed as one line."""


def _user_errors() -> tuple[type[BaseException], ...]:
    from madp.sim.scenario import ScenarioError

    errors: list[type[BaseException]] = [UserError, ScenarioError, ValueError, OSError]
    try:
        from madp.data_schema import DataError

        errors.append(DataError)
    except ImportError:  # pragma: no cover - data_schema is part of the package
        pass
    return tuple(errors)


def _write_json(path: Path, obj: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1) + "\n")
    tmp.replace(path)


# --- rollout ---------------------------------------------------------------------------------
@app.command()
def rollout(
    scenario: Path = typer.Option(..., "--scenario", help="Scenario JSON (features, robots, optional params)."),
    controller: str = typer.Option("clairvoyant", help="clairvoyant | dcvt"),
    steps: int = typer.Option(600, min=0, help="Control steps to run."),
    out: Path = typer.Option(Path("result.json"), help="Where to write the result JSON."),
) -> None:
    """Run one controller on one scenario; write J(t)/J(0) for t = 0..steps and the final positions."""
    from madp.sim import Scenario, rollout_scenario

    if controller not in ("clairvoyant", "dcvt"):
        raise UserError(f"--controller: expected clairvoyant or dcvt, got {controller!r}")
    sc = Scenario.load(scenario)
    result = rollout_scenario(sc, controller, steps)
    _write_json(out, result.to_json(controller))
    typer.echo(f"{controller}: J({steps})/J(0) = {result.normalized_cost[-1]:.4f}"
               f" (converged at {result.converged_at}) -> {out}")


# --- benchmarks ------------------------------------------------------------------------------
@bench_app.command("sim")
def bench_sim_cmd(
    steps: int = typer.Option(200, min=100, help="Steps per median (>= 100)."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
) -> None:
    """Simulator hot paths at N = F = 32, 1024² world: clairvoyant step, DCVT step, J, observations."""
    from madp.sim.bench import bench_sim

    res = bench_sim(steps=steps)
    typer.echo(f"{'what':<18}{'median ms':>10}{'p90 ms':>9}{'library ms':>12}{'speed-up':>10}{'target ms':>11}")
    for name, r in res.items():
        typer.echo(f"{name:<18}{r['median_ms']:>10.2f}{r['p90_ms']:>9.2f}{r['library_ms']:>12.1f}"
                   f"{r['speedup_vs_library']:>9.1f}x{r['target_ms']:>10.1f}{'  ok' if r['meets_target'] else '  MISSED'}")
    j = res["cost_J"]
    typer.echo(f"baseline in this run: brute-force J {j['brute_force_median_ms']:.1f} ms "
               f"-> column sums {j['speedup_vs_brute_force']:.0f}x faster")
    if out:
        _write_json(out, res)


def main(argv: Optional[List[str]] = None) -> None:
    """Entry point: run the app, turning user mistakes into one line and exit status 2."""
    args = sys.argv[1:] if argv is None else argv
    try:
        app(args=args, prog_name="madp")  # standalone: usage errors print and exit 2 themselves
    except KeyboardInterrupt:
        sys.stderr.write("madp: interrupted\n")
        sys.exit(130)
    except _user_errors() as e:
        if os.environ.get("MADP_DEBUG"):
            raise
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        sys.stderr.write(f"madp: error: {msg}\n")
        sys.exit(2)


if __name__ == "__main__":
    main()
