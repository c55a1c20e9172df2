"""The training progress bar (rich): an epoch's steps with loss, samples/s, elapsed time and ETA."""

from __future__ import annotations

__all__ = ["EpochBar"]


class EpochBar:
    """Rich progress with loss and samples/s (a no-op when disabled)."""

    def __init__(self, enabled: bool, total: int, done: int, label: str):
        self.enabled = enabled
        if enabled:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                       TimeRemainingColumn)

            self.p = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                              TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn())
            self.p.start()
            self.task = self.p.add_task(label, total=total, completed=done, info="")

    def update(self, done: int, loss: float, rate: float) -> None:
        if self.enabled:
            self.p.update(self.task, completed=done, info=f"loss {loss:.4f} {rate:.1f} samples/s")

    def close(self) -> None:
        if self.enabled:
            self.p.stop()
            self.enabled = False
