"""``madp eval compare``: finished evaluations of one suite, paired (:mod:`madp.eval.compare`), a command of
:mod:`madp.cli`'s ``eval`` group kept here so that module stays small."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer


def compare_cmd(
    runs: List[str] = typer.Argument(..., metavar="RUN", help="Two or more finished suite directories of madp eval (OUT/<suite>/), each PATH or NAME=PATH."),
    baseline: Optional[str] = typer.Option(None, help="The run the others are compared with: a name or a path (default: the first)."),
    out: Optional[Path] = typer.Option(None, help="Where compare.md, compare.json and compare.png go (default runs/compare/<suite>)."),
    shared: bool = typer.Option(False, help="Pair on the environments every run holds (a --paired-se run against a full one)."),
) -> None:
    """Compare evaluations of one suite on the same environments: each run's mean, the paired difference to the baseline (SE, 95% interval) and wins k/n per controller and group."""
    from madp.eval.compare import compare_runs, load_runs, markdown, write_compare
    cmp = compare_runs(load_runs(runs), baseline, shared=shared)
    files = write_compare(cmp, out or Path("runs/compare") / cmp["suite"])
    typer.echo(markdown(cmp))
    typer.echo(f"-> {', '.join(str(p) for p in files.values())}")
