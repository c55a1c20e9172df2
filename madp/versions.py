"""What ``madp --version`` prints: madp's version, the installed torch build and whether it sees a GPU, so
that one line tells whether an install is the one a machine wants (the CPU build on a machine without a
GPU, a CUDA build that finds the GPU on one with)."""

from __future__ import annotations

import platform

__all__ = ["print_version", "version_line"]


def torch_build(version: str, cuda: str | None, gpus: list[str]) -> str:
    """``torch VERSION`` and its build: ``CPU only``; ``CUDA X: GPU name`` (the first of several, with
    their count); or ``CUDA X build, no GPU visible`` (a CUDA build on a machine without one)."""
    if cuda is None:
        return f"torch {version}, CPU only"
    if not gpus:
        return f"torch {version}, CUDA {cuda} build, no GPU visible"
    more = f" and {len(gpus) - 1} more" if len(gpus) > 1 else ""
    return f"torch {version}, CUDA {cuda}: {gpus[0]}{more}"


def version_line() -> str:
    """``madp VERSION (torch VERSION, BUILD; Python VERSION)`` for the running interpreter."""
    import torch

    from madp import __version__

    cuda = torch.version.cuda
    gpus = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())] if cuda else []
    return f"madp {__version__} ({torch_build(torch.__version__, cuda, gpus)}; Python {platform.python_version()})"


def print_version(value: bool) -> None:
    """``madp --version``'s callback: print :func:`version_line` and end the command."""
    if value:
        import typer

        typer.echo(version_line())
        raise typer.Exit()
