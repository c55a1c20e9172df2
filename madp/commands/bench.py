"""``madp bench …``: the benchmark commands of :mod:`madp.cli` (medians, with a baseline measured in the
same run). Each parses its options, calls its bench and prints the lines the bench formats."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from madp.commands.main import ray_option
from madp.errors import SettingError
from madp.io.atomic import write_json_atomic

bench_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Benchmarks (medians, with a baseline measured in the same run).")


def _show(lines: List[str], result: object, out: Optional[Path]) -> None:
    """Print a bench's lines; write its figures as JSON to ``out`` when given."""
    typer.echo("\n".join(lines))
    if out:
        write_json_atomic(out, result)


@bench_app.command("sim")
def bench_sim_cmd(
    scenarios: int = typer.Option(3, min=1, help="Random scenarios (seeds SEED, SEED+1, ...)."),
    steps: int = typer.Option(20, min=10, help="Steps per scenario (>= 10) along each controller's trajectory."),
    seed: int = typer.Option(12345, help="Seed of the first scenario."),
    library: Optional[bool] = typer.Option(None, "--library/--no-library", help="Time the Coverage Control Library (madp[reference]) beside madp: default when it imports; --library requires it."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
) -> None:
    """Clairvoyant step, DCVT step, J and observations at N = F = 32 on a 1024² world: medians of madp and of the Coverage Control Library, interleaved, and their ratio."""
    from madp.sim.bench import bench_sim, format_table

    try:
        res = bench_sim(scenarios=scenarios, steps=steps, seed=seed, library=library)
    except ImportError as e:  # --library without a working coverage_control
        raise SettingError("library", str(e)) from e
    _show(format_table(res), res, out)


@bench_app.command("datagen")
def bench_datagen_cmd(
    n: int = typer.Option(1024, "--n", min=64, help="Samples to generate for the timing."),
    workers: int = typer.Option(0, min=0, help="Worker processes (0: all cores)."),
    format: str = typer.Option("mcap", "--format", help="mcap | parquet"),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
    ray: Optional[str] = ray_option("Measure the Ray backend's per-task overhead on this cluster ('auto', HOST:PORT) instead of a Ray started on this machine (measured whenever madp[ray] is installed)."),
) -> None:
    """End-to-end datagen rate at N = F = 32, the projected time for 100k samples, and the Ray backend's per-task overhead."""
    from madp.datagen.bench import bench_datagen_and_ray, format_table

    r = bench_datagen_and_ray(n, workers, format, ray)
    _show(format_table(r, n, format), r, out)


@bench_app.command("io")
def bench_io_cmd(
    n: int = typer.Option(512, "--n", min=16, help="Samples of real expert rollouts to encode and read."),
    repeats: int = typer.Option(5, min=1, help="Read passes per format (median)."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
) -> None:
    """Bytes per sample and decode throughput: MCAP, Parquet, and a float16 numpy memmap baseline."""
    from madp.data_schema.bench import bench_io_real, format_table

    r = bench_io_real(n, repeats)
    _show(format_table(r, repeats), r, out)


@bench_app.command("train")
def bench_train_cmd(
    models: str = typer.Option("madp,lpac", help="Comma-separated: madp, lpac."),
    presets: str = typer.Option("cpu,paper", help="Comma-separated: cpu, paper."),
    threads: str = typer.Option("1,2", help="Comma-separated torch thread counts."),
    steps: int = typer.Option(10, min=1, help="Timed steps per case (median)."),
    warmup: int = typer.Option(3, min=0, help="Untimed steps per case first."),
    data: Optional[Path] = typer.Option(None, help="Dataset to stream (default: 256 samples made in a temporary directory)."),
    ablate: bool = typer.Option(False, help="Instead: the speed options one at a time (MADP and LPAC-K3, cpu preset, 1 thread)."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
) -> None:
    """Training samples/s by phase (data, forward, backward, optimizer) beside the matmul peak (docs/reports/2026-12-02-training-speed.md)."""
    from madp.training.bench import format_train_bench, parse_cases, run_train_bench

    rows = run_train_bench(parse_cases(models, presets, threads, ablate), data, steps=steps, warmup=warmup)
    _show(format_train_bench(rows), rows, out)


def _onnxruntime() -> bool:
    import importlib.util

    return importlib.util.find_spec("onnxruntime") is not None


@bench_app.command("infer")
def bench_infer_cmd(
    madp: Optional[Path] = typer.Option(None, help="Trained MADP checkpoint for the closed-loop sweep (default: shipped)."),
    envs: int = typer.Option(50, min=2, help="uniform-suite environments per sweep setting."),
    steps: int = typer.Option(600, min=1, help="Control steps per environment in the sweep."),
    grid: Optional[str] = typer.Option(None, help="Sweep settings 'sampler:S,...;...' (default dpm++:3,5,10,20;ddim:10,20,50; DDIM-50 is always run)."),
    sweep_out: Path = typer.Option(Path("runs/bench-infer"), help="Resumable sweep suites and the plot go here."),
    workers: int = typer.Option(0, min=0, help="Worker processes of the sweep (0: all cores)."),
    repeats: int = typer.Option(5, min=1, help="Timed calls per latency median."),
    device: str = typer.Option("cpu", help="Where MADP runs, in the sweep and the latency: cpu | cuda | cuda:I | auto (cuda when there is one)."),
    presets: str = typer.Option("cpu,paper", help="Comma-separated presets whose latency is measured."),
    sweep: bool = typer.Option(True, "--sweep/--no-sweep", help="--no-sweep: no closed-loop sweep; the latency of every --grid setting instead."),
    candidates: Optional[str] = typer.Option(None, help="Also the latency of a whole decentralized control step with K samples per robot and each --select rule of madp eval, for these K (e.g. 1,4,16) at the default S, or K:S at S sampler steps (e.g. 4,8:2)."),
    robot: Optional[bool] = typer.Option(None, "--robot/--no-robot", help="Also one robot's control step through madp export's files (onnxruntime, 1 thread, the evaluation default's sampling) beside PyTorch's per robot; default: when onnxruntime imports (madp[onnx])."),
    roofline: bool = typer.Option(False, "--roofline", help="Also FLOPs, bytes and time per part of the evaluation default's decentralized control step (observations, perception, masks, encoder, denoiser x K x S, selection) and the fraction of the measured matmul peak each reaches, fp32 and bf16."),
    roofline_after: int = typer.Option(300, min=0, help="--roofline: expert steps before its second state (the first is a uniform environment's start)."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
) -> None:
    """MADP: the fewest sampler steps S* that cost nothing in closed loop, and the latency per control step there."""
    from madp.inference_bench.bench import bench_infer_all, format_table, parse_candidates, parse_grid, parse_presets
    from madp.policies.device import resolve_device

    r = bench_infer_all(str(madp) if madp else None, sweep_out, parse_grid(grid) if grid else None, envs=envs, steps=steps,
                        repeats=repeats, workers=workers, presets=parse_presets(presets), device=resolve_device(device),
                        sweep=sweep, candidates=parse_candidates(candidates) if candidates else (),
                        robot=_onnxruntime() if robot is None else robot, roofline=roofline,
                        roofline_after=roofline_after)
    _show(format_table(r), r, out)
