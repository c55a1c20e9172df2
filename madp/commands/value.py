"""``madp value …``: the ``value`` selection rule's learned map prior (:mod:`madp.training.map_prior`):
``collect`` its examples from the deployed policy's rollouts, ``train`` it into a copy of a policy file."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

value_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                        help="The value rule's learned map prior: collect examples, train it into a policy file.")


@value_app.command("collect")
def value_collect_cmd(
    out: Path = typer.Option(..., help="The examples file to write (.npz)."),
    envs: int = typer.Option(48, min=1, help="Rollouts (dataset scenarios, uniform and packed launches in turn)."),
    every: int = typer.Option(20, min=1, help="Take every robot's window every this many steps."),
    steps: int = typer.Option(600, min=1, help="Steps per rollout."),
    seed: int = typer.Option(0, min=0, help="Dataset seed of the scenarios (never an evaluation suite's)."),
    policy: Optional[Path] = typer.Option(None, help="MADP policy file that drives the swarms (default: the shipped one)."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Roll out MADP at the evaluation default and keep each robot's window: its own map and the true one."""
    from madp.training.map_prior import collect

    meta = collect(out, envs, every, steps, seed, policy=str(policy) if policy else None, overwrite=overwrite)
    typer.echo(f"{meta['examples']} examples from {envs} rollouts in {meta['seconds']} s -> {out}")


@value_app.command("train")
def value_train_cmd(
    data: Path = typer.Option(..., help="Examples file from madp value collect."),
    out: Path = typer.Option(..., help="The policy file to write: --policy with the map prior added."),
    policy: Optional[Path] = typer.Option(None, help="MADP policy file to add the prior to (default: the shipped one)."),
    epochs: int = typer.Option(8, min=1, help="Passes over the examples."),
    seed: int = typer.Option(0, min=0, help="Seed of the initial weights and the batches."),
    expectile: float = typer.Option(0.5, help="Expectile τ in (0, 1) the prior predicts: 0.5 the expected importance, "
                                    "more an optimistic one where the unexplored is uncertain."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Fit the map prior (the last tenth of the rollouts held out) and write the policy file that carries it."""
    from madp.controllers import resolve_checkpoint
    from madp.training.map_prior import train

    source = Path(resolve_checkpoint("madp", str(policy) if policy else None))
    s = train(data, source, out, epochs=epochs, seed=seed, expectile=expectile, overwrite=overwrite)
    typer.echo(f"held-out squared error per m² of unexplored window: {s['held_out_mse']:.4f}, mean signed error "
               f"{s['held_out_bias']:+.4f} (explore's mean: {s['explore_mean_mse']:.4f}, {s['explore_mean_bias']:+.4f}; "
               f"zero: {s['zero_mse']:.4f}) -> {out}")
