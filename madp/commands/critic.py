"""``madp critic …``: the learned critic of MADP's joint copies (:mod:`madp.training.critic`,
:mod:`madp.training.critic_fit`): ``collect`` its labels from the deployed policy's rollouts, ``train``
it with some rollouts held out, ``rank`` how it and the ``explore`` and ``value`` rules rank the
copies of the held-out states, ``attach`` a trained critic to another policy file (a fine-tuned policy,
say: the critic reads what robots know and the copies' moves, not the policy's weights), ``export`` it
as an ONNX graph for the robot."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

critic_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                         help="The learned critic of MADP's joint copies: collect labels, train it, rank copies.")


@critic_app.command("collect")
def critic_collect_cmd(
    out: Path = typer.Option(..., help="The labels file to write (.npz)."),
    envs: int = typer.Option(4, min=1, help="Rollouts (dataset scenarios, uniform and packed launches in turn)."),
    first: int = typer.Option(0, min=0, help="Index of the first dataset scenario."),
    every: int = typer.Option(20, min=1, help="Draw the copies of every this many steps' state."),
    steps: int = typer.Option(600, min=1, help="Steps per rollout."),
    copies: int = typer.Option(16, min=2, help="Joint copies K drawn per kept state."),
    seed: int = typer.Option(0, min=0, help="Dataset seed of the scenarios (never an evaluation suite's)."),
    policy: Optional[Path] = typer.Option(None, help="MADP policy file that drives the swarms (default: the shipped one)."),
    prior: Optional[Path] = typer.Option(None, help="A policy file with a map prior: the value rule's costs as a baseline."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Roll out MADP at the evaluation default; at kept states, K joint copies and their true J after the step."""
    from madp.training.critic import collect

    meta = collect(out, envs, every, steps, copies, seed, first=first, policy=str(policy) if policy else None,
                   prior=str(prior) if prior else None, overwrite=overwrite)
    typer.echo(f"{meta['states']} states of {copies} copies from {envs} rollouts in {meta['seconds']} s -> {out}")


@critic_app.command("train")
def critic_train_cmd(
    data: List[Path] = typer.Option(..., help="Labels files from madp critic collect (repeat for several)."),
    out: Path = typer.Option(..., help="The policy file to write (.safetensors): --policy carrying the critic, "
                             "for madp eval --sampling rule=critic."),
    policy: Optional[Path] = typer.Option(None, help="MADP policy file to carry the critic (default: the shipped one)."),
    held_out: float = typer.Option(0.25, help="The share of the environments (the last ones) left out of training "
                                   "(0: all of them train; rank on other files)."),
    epochs: int = typer.Option(12, min=1, help="Passes over the training states."),
    rank_weight: float = typer.Option(3.0, min=0.0, help="Weight of the copies' ranking loss beside the cell loss."),
    lr: float = typer.Option(2e-3, min=0.0, help="Peak learning rate of the one-cycle schedule."),
    init: Optional[Path] = typer.Option(None, help="Continue from the critic this policy file carries (a next round "
                                        "on new labels) instead of fresh weights."),
    seed: int = typer.Option(0, min=0, help="Seed of the initial weights and the batches."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Fit the critic to the labels of the first environments, the last ``--held-out`` share left out."""
    from madp.errors import SettingError
    from madp.io.checksum import sha256_file
    from madp.models.critic import load_critic
    from madp.training.critic import load_many, split_envs
    from madp.training.critic_fit import train

    if out.exists() and not overwrite:
        raise SettingError("out", f"{out} exists; pass --overwrite to replace it")
    start = load_critic(init) if init is not None else None
    if start is not None:
        start.record = {**start.record, "path": str(init), "sha256": sha256_file(init)}
    arrays, meta = load_many(data)
    train_envs, _ = split_envs(arrays["env"], held_out)
    train(arrays, train_envs, out, epochs=epochs, lr=lr, rank_weight=rank_weight, seed=seed,
          record={"data": [str(p) for p in data], "collect": meta, "held_out": held_out}, log=typer.echo,
          policy=policy, init=start)
    typer.echo(f"policy with its critic -> {out}")


@critic_app.command("rank")
def critic_rank_cmd(
    data: List[Path] = typer.Option(..., help="Labels files from madp critic collect (repeat for several)."),
    critic: Path = typer.Option(..., help="Policy file from madp critic train: its critic's training environments are left out."),
    out: Path = typer.Option(..., help="The JSON file to write the ranking numbers to."),
) -> None:
    """Rank the copies of the states the critic was not trained on: the critic, explore, value and the true cells."""
    from madp.io.atomic import write_json_atomic
    from madp.training.critic_fit import rank_study

    result = rank_study(data, critic)
    result["command"] = " ".join(["madp critic rank", *(f"--data {p}" for p in data), f"--critic {critic}", f"--out {out}"])
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, result)
    for name, r in result["rules"].items():
        typer.echo(f"{name:12s} spearman {r['spearman_team']:+.3f}  gain share robot {r['gain_share_robot']:+.2f} "
                   f"neighbourhood {r['gain_share_neighbourhood']:+.2f} team {r['gain_share_team']:+.2f}")
    typer.echo(f"-> {out}")


@critic_app.command("attach")
def critic_attach_cmd(
    critic: Path = typer.Option(..., help="Policy file that carries the critic (madp critic train)."),
    policy: Path = typer.Option(..., help="MADP policy file to carry it."),
    out: Path = typer.Option(..., help="The policy file to write (.safetensors): --policy carrying the critic."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Copy the critic that --critic carries onto --policy: the policy's weights and metadata, the critic's
    weights and how it was trained, plus where it came from."""
    from madp.errors import SettingError
    from madp.io.checksum import sha256_file
    from madp.models.critic import load_critic
    from madp.policies.checkpoint import attach, load

    if out.suffix != ".safetensors":
        raise SettingError("out", f"expected a .safetensors file, got {out}")
    if out.exists() and not overwrite:
        raise SettingError("out", f"{out} exists; pass --overwrite to replace it")
    load(policy, "madp")  # a MADP policy file: one-line errors otherwise
    net = load_critic(critic)
    attach(policy, out, "critic", net, net.config.to_dict(),
           {**net.record, "attached_from": {"path": str(critic), "sha256": sha256_file(critic)}})
    typer.echo(f"{policy} with the critic of {critic} -> {out}")


@critic_app.command("export")
def critic_export_cmd(
    critic: Path = typer.Option(..., help="Policy file from madp critic train."),
    out: Path = typer.Option(..., help="The ONNX graph to write (.onnx)."),
) -> None:
    """Export the critic as an ONNX graph the robot runs without torch (madp.robot.critic.onnx_predictor)."""
    from madp.errors import SettingError
    from madp.export.onnx import export_critic
    from madp.models.critic import load_critic

    if out.suffix != ".onnx":
        raise SettingError("out", f"expected an .onnx file, got {out}")
    export_critic(load_critic(critic), out)
    typer.echo(f"critic graph -> {out}")
