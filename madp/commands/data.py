"""``madp dataset import``: a run's log back into data (:mod:`madp.datagen.from_log`), a command of
:mod:`madp.cli`'s ``dataset`` group kept here so that module stays small."""

from __future__ import annotations

from pathlib import Path
from typing import List

import typer


def dataset_import_cmd(
    logs: List[Path] = typer.Argument(..., help="rosbag2 MCAP logs of madp swarm (DIR/swarm.mcap) or madp rollout --record-format ros2."),
    out: Path = typer.Option(..., help="Dataset directory (created; refused if it holds files madp did not write)."),
    format: str = typer.Option("mcap", "--format", help="mcap | parquet"),
    split: str = typer.Option("train", help="The split every imported episode goes to: train | val | test."),
    record_every: int = typer.Option(5, min=1, help="Record every K-th state of each log (and its last)."),
    overwrite: bool = typer.Option(False, help="Replace a dataset an earlier madp dataset import wrote here."),
) -> None:
    """Replay run logs on their scenarios and write each state's clairvoyant-expert label as samples (U0, X, O) with a manifest: a swarm's log feeds the next training round (madp train --data BASE --data OUT)."""
    from madp.datagen.from_log import import_logs

    m = import_logs(logs, out, fmt=format, split=split, record_every=record_every, overwrite=overwrite)
    typer.echo(f"{len(logs)} log(s) -> {out}: {m.num_samples} samples in {split} ({format})")
