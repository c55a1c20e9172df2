"""``madp``: the command line. Thin commands: each parses its options, calls one function of the
layers and prints the result. A user's mistake ends in one line ``madp: error: …`` naming the flag or
file (exit status 2), a bug in its traceback and a request for a report (exit status 1): :mod:`madp.commands.main`.
"""

from __future__ import annotations

import os

# The simulator's matrix products are small; BLAS threads only fight over the cores (and the
# datagen/eval worker processes). Must be set before numpy loads; torch keeps its own threads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json
import sys
from pathlib import Path
from typing import List, Optional, Tuple

import typer

from madp.commands.main import ray_option
from madp.controllers import DEFAULT, NAMES, parse_controllers
from madp.sampling import sampling_help
from madp.selection import NEEDS, RULES, select_help
from madp.versions import print_version

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, rich_markup_mode=None,
                  help="Multi-agent diffusion policies for coverage control: datasets, training, evaluation.")
dataset_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Inspect, verify, convert and merge datasets.")
scenario_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Scenario files.")
app.add_typer(dataset_app, name="dataset")
app.add_typer(scenario_app, name="scenario")


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=print_version, is_eager=True,
                                       help="Print madp's and torch's versions, torch's build (CPU only or CUDA) and the GPU it sees, then exit.")) -> None:
    """The options before a command (``madp --version``)."""


# MADP's choice among K samples per robot (madp.selection's records), wherever MADP samples.
SELECT = typer.Option(None, help=select_help())
SAMPLING = typer.Option(None, "--sampling", help=sampling_help())
CANDIDATES = typer.Option(None, help="MADP: samples per robot per control step, drawn in one batch (default: 4, or 1 with --select none; K > 1 needs a rule other than none).")

# --- rollout, datagen, datasets ----------------------------------------------------------------
@app.command()
def rollout(
    scenario: Path = typer.Option(..., "--scenario", help="Scenario JSON (features, robots, optional params)."),
    controller: str = typer.Option("clairvoyant", help=" | ".join(NAMES)),
    checkpoint: Optional[Path] = typer.Option(None, help="Checkpoint of a learned controller (default: the shipped one)."),
    seed: Optional[int] = typer.Option(None, help="MADP's sampling-noise seed (default: the scenario's seed, else 0, as madp eval)."),
    steps: int = typer.Option(600, min=0, help="Control steps to run."),
    out: Path = typer.Option(Path("result.json"), help="Where to write the result JSON."),
    video: Optional[Path] = typer.Option(None, help="Also write the rollout as an MP4 video (steps + 1 frames: map, Voronoi cells, trails, robots, step and J(t)/J(0))."),
    device: str = typer.Option("cpu", help="Where a learned controller's model runs: cpu | cuda | cuda:I | auto (cuda when there is one)."),
    sampling: Optional[str] = SAMPLING,
    select: Optional[str] = SELECT,
    candidates: Optional[int] = CANDIDATES,
    network: Optional[str] = typer.Option(None, help="A network between the robots: a group of the faults suite (ideal, loss_30, burst_30, no_comm, distance, bandwidth, delay_1s, fail_25, noise_5m, ...) or NAME=VALUE items, each at most once, e.g. loss=0.3,burst_len=5,loss_at_range=0.6,delay_steps=5,max_age_steps=10,missing=keep,max_bytes_per_step=2000,fail_fraction=0.25,fail_step=200,position_noise_m=5,seed=0 (docs/guides/robots.md; default: none, every robot reads the true state). The result JSON then holds the bytes each robot put on the air per step."),
    record: Optional[Path] = typer.Option(None, help="Also record the rollout here (see --record-format)."),
    record_format: str = typer.Option("foxglove", help="--record's format: foxglove (MCAP with Foxglove schemas) | ros2 (a rosbag2 MCAP file: geometry_msgs/TwistStamped on /robot_I/cmd_vel, PoseStamped on /robot_I/pose, MADP's tokens, the scenario; madp dataset import reads it back; docs/guides/swarm.md)."),
    runtime: str = typer.Option("torch", help="How MADP (decentralized) runs: torch (the PyTorch policy) | onnx (every robot through the files of madp export and the torch-free robot runtime, each robot's starting noise its own, as a robot process draws it: the one-process reference of madp swarm; docs/guides/export.md)."),
) -> None:
    """Run one controller on one scenario; write J(t)/J(0) for t = 0..steps and the final positions."""
    from madp.commands.rollout import run_rollout

    run_rollout(scenario, controller, checkpoint, seed, steps, out, video, device, sampling, select, candidates, network,
                record, record_format, runtime)


@app.command()
def datagen(
    n: int = typer.Option(..., "--n", help="Number of samples in total (split 70/20/10 by episode)."),
    out: Path = typer.Option(Path("data"), help="Dataset directory."),
    format: str = typer.Option("mcap", "--format", help="mcap | parquet"),
    workers: int = typer.Option(0, min=0, help="Worker processes (0: all cores). Never changes the bytes."),
    seed: int = typer.Option(0, min=0, help="Dataset seed."),
    num_robots: int = typer.Option(32, min=1, help="N, robots per swarm."),
    num_features: int = typer.Option(32, min=1, help="F, Gaussian features per map."),
    sigma: Tuple[float, float] = typer.Option((40.0, 60.0), help="σ range of the features (m)."),
    peak: Tuple[float, float] = typer.Option((0.6, 1.0), help="Peak-height range of the features."),
    comm_radius_m: float = typer.Option(256.0, "--comm-radius", help="Communication radius r_c (m)."),
    world_size: int = typer.Option(1024, help="World side (m); 1 m cells."),
    samples_per_shard: int = typer.Option(512, min=1, help="Samples per shard (the last of a split holds the rest)."),
    shards: Optional[str] = typer.Option(None, help="Run only shard tasks I:J of the plan (merge parts later)."),
    overwrite: bool = typer.Option(False, help="Replace a dataset made with other parameters: removes only the files madp wrote there (its manifest, shard records and the shards they list); any other file makes it refuse, naming the file."),
    policy: Optional[Path] = typer.Option(None, help="Expert relabelling (DAgger): this policy.safetensors (MADP decentralized or LPAC-K3) drives; every sample keeps the expert's label."),
    beta: float = typer.Option(0.0, help="With --policy: probability that a step executes the expert's action instead."),
    sampling: Optional[str] = typer.Option(None, "--sampling", help=sampling_help("With an MADP --policy; default: one sample per robot (rule=none), not the evaluation default, so a dataset's bytes do not change with it. The manifest records the rule, K, S and the noise source.")),
    select: Optional[str] = typer.Option(None, help="With an MADP --policy: its rule to choose among its samples (as --sampling rule=), at the rule's default K."),
    max_steps: Optional[int] = typer.Option(None, min=1, help="Steps per episode at most (default 2100 for the expert, which stops when converged; exactly 600, the evaluation horizon, with --policy)."),
    launch: str = typer.Option("uniform", help="Where swarms start: uniform (anywhere) | packed (random boxes, bands and clusters; docs/guides/datasets.md)."),
    dart_sigma_mps: float = typer.Option(0.0, "--dart-sigma", help="DART (expert rollouts, not with --policy): the swarm executes the expert's action plus Gaussian noise of this standard deviation (m/s) per robot and axis, clipped to the maximum speed, seeded by each episode's scenario; every sample keeps the expert's noiseless label. 0: off."),
    ray: Optional[str] = ray_option(),
) -> None:
    """Generate (U0, X, O) samples from clairvoyant-CVT rollouts (or a learned policy's, relabelled by the expert) as MCAP or Parquet shards."""
    from madp.datagen import DatagenConfig, learner_settings, parse_shards, run_datagen
    from madp.sim import SimParams

    params = SimParams(world_size=world_size, num_robots=num_robots, num_features=num_features,
                       sigma_range_m=sigma, peak_range=peak, comm_radius_m=comm_radius_m)
    cfg = DatagenConfig(num_samples=n, seed=seed, format=format, samples_per_shard=samples_per_shard, params=params,
                        policy=learner_settings(policy, beta, sampling, select), max_steps=max_steps or (600 if policy else 2100),
                        launch=launch, dart_sigma_mps=dart_sigma_mps)
    run_datagen(cfg, out, workers=workers, shards=parse_shards(shards), overwrite=overwrite, ray=ray)


@dataset_app.command("info")
def dataset_info_cmd(root: Path = typer.Argument(..., help="Dataset directory."),
                     json_out: bool = typer.Option(False, "--json", help="Print JSON instead of a table.")) -> None:
    """Counts, sizes, parameters and action statistics."""
    from madp.data_schema.dataset import dataset_info, format_info

    info = dataset_info(root)
    typer.echo(json.dumps(info, indent=1) if json_out else "\n".join(format_info(info)))


@dataset_app.command("verify")
def dataset_verify_cmd(root: Path = typer.Argument(..., help="Dataset directory.")) -> None:
    """Checksums of every shard and a full decode of every sample; non-zero exit naming any fault."""
    from madp.data_schema.dataset import verify_dataset

    typer.echo(f"{root}: ok, {verify_dataset(root)} samples verified")


@dataset_app.command("convert")
def dataset_convert_cmd(root: Path = typer.Argument(..., help="Dataset directory."),
                        to: str = typer.Option(..., "--to", help="mcap | parquet"),
                        out: Path = typer.Option(..., help="Directory for the converted dataset."),
                        overwrite: bool = typer.Option(False, help="Replace a dataset in --out: removes only its manifest and the shards madp wrote there; any other file makes it refuse, naming the file.")) -> None:
    """Re-encode a dataset (same samples, same manifest content)."""
    from madp.data_schema.dataset import convert_dataset

    m = convert_dataset(root, to, out, overwrite)
    typer.echo(f"{root} -> {out}: {m.num_samples} samples as {m.format}")


@dataset_app.command("merge")
def dataset_merge_cmd(parts: List[Path] = typer.Argument(..., help="Part directories made with --shards."),
                      out: Path = typer.Option(..., help="Merged dataset directory.")) -> None:
    """Combine parts generated with ``madp datagen --shards I:J`` into one dataset."""
    from madp.datagen import merge_parts

    m = merge_parts(parts, out)
    if m is not None:
        typer.echo(f"merged {len(parts)} part(s) -> {out}: {m.num_samples} samples")


# --- training and evaluation -------------------------------------------------------------------
@app.command()
def train(
    model: str = typer.Option("madp", help="madp | lpac"),
    data: List[Path] = typer.Option([Path("data")], help="Dataset directory (from madp datagen); repeat to train on several (DAgger rounds): the first one's action statistics and val split are used."),
    data_weights: Optional[str] = typer.Option(None, help="Comma-separated weight per --data (default all 1): each dataset's shards per epoch x weight."),
    preset: str = typer.Option("cpu", help="paper (the paper's sizes) | cpu (trains on 2 cores in ~2 h)"),
    epochs: Optional[int] = typer.Option(None, help="Override the preset's epochs."),
    batch_size: Optional[int] = typer.Option(None, help="Override the preset's batch size (per rank)."),
    lr: Optional[float] = typer.Option(None, help="Override the preset's learning rate."),
    out: Optional[Path] = typer.Option(None, help="Run directory (default runs/<model>-<preset>)."),
    resume: bool = typer.Option(False, help="Continue the run in --out from its latest checkpoint."),
    seed: Optional[int] = typer.Option(None, help="Seed of initialisation, data order and noise."),
    workers: Optional[int] = typer.Option(None, help="DataLoader worker processes per rank."),
    grad_accum: Optional[int] = typer.Option(None, help="Micro-batches per optimizer step (default 1). One process with --grad-accum R and R x --workers trains exactly as torchrun with R ranks."),
    val_samples: Optional[int] = typer.Option(None, help="Validation samples per epoch."),
    max_steps_per_epoch: Optional[int] = typer.Option(None, help="Cap the steps of an epoch (0: whole split)."),
    checkpoint_every: Optional[int] = typer.Option(None, help="Steps between 'latest' checkpoints."),
    threads: Optional[int] = typer.Option(None, min=1, help="torch intra-op threads (default: torch's choice)."),
    augment: Optional[str] = typer.Option(None, help="none | d4: each training sample as one of its 8 rotations/reflections."),
    init: Optional[Path] = typer.Option(None, help="Start from this policy.safetensors' weights (same model and preset; fresh optimizer), e.g. the previous DAgger round."),
    edge_weight: Optional[str] = typer.Option(None, help="LPAC-K3's graph: binary (the library's, default) | gaussian."),
    compile: bool = typer.Option(False, "--compile", help="MADP: run the model through torch.compile (docs/reports/2026-12-02-training-speed.md)."),
    stop_after_minutes: Optional[float] = typer.Option(None, help="Stop (with a checkpoint) at the first optimizer step after this many minutes of training (a time budget; the lr schedule is not shortened)."),
    stop_after_steps: Optional[int] = typer.Option(None, hidden=True),
    comm_dropout: Optional[float] = typer.Option(None, help="MADP: each training sample, with this probability (0-1; default 0), loses links: a rate q from {0.3, 0.6, 1} (1: every robot alone), each pair of robots lost with probability q; attention and neighbour channels show only the robots still heard (madp.training.comm_dropout)."),
    distill: Optional[Path] = typer.Option(None, help="MADP: distil this policy file's sampler into one step: the student starts as this teacher and learns to predict, from the same noise, the sample its DPM-Solver++(2M) draws in 3 steps (the evaluation default); evaluate it with --sampling-steps 1."),
) -> None:
    """Train MADP or LPAC-K3 on a dataset; checkpoints, metrics.jsonl, resume; DDP under torchrun."""
    from madp.training import resolve, train as run_train
    from madp.training.config import parse_weights

    if threads:
        import torch

        torch.set_num_threads(threads)
    cfg = resolve(model, preset, data=str(data[0]), more_data=tuple(str(d) for d in data[1:]),
                  data_weights=parse_weights(data_weights) if data_weights else None,
                  out=str(out) if out else None, epochs=epochs, batch_size=batch_size,
                  lr=lr, seed=seed, num_workers=workers, grad_accum=grad_accum, val_samples=val_samples,
                  max_steps_per_epoch=max_steps_per_epoch, checkpoint_every=checkpoint_every,
                  stop_after_steps=stop_after_steps, stop_after_minutes=stop_after_minutes, augment=augment,
                  edge_weight=edge_weight, init=str(init) if init else None, compile=compile or None, distill=str(distill) if distill else None,
                  comm_dropout=comm_dropout)
    res = run_train(cfg, resume=resume)
    if int(os.environ.get("RANK", "0")) == 0:
        typer.echo(f"{cfg.model}/{cfg.preset}: {res['stopped']} at step {res['step']}; "
                   f"best val loss {res.get('best_val_loss', float('nan')):.5f} -> {cfg.out}")


eval_app = typer.Typer(invoke_without_command=True, no_args_is_help=False, rich_markup_mode=None)
app.add_typer(eval_app, name="eval")


@eval_app.callback()
def eval_cmd(
    ctx: typer.Context,
    suite: str = typer.Option("uniform", help="uniform | sigma | cities | launch | scale | all, or a comma-separated list (uniform,cities); symmetry (the launch layouts' rotations and reflections) runs by name only"),
    num_envs: int = typer.Option(50, min=1, help="Environments per group (cities: at most this many cities)."),
    paired_se: Optional[float] = typer.Option(None, help="Run each suite's first environments, as many (at most --num-envs) as a paired difference of MADP needs for this standard error (e.g. 0.01; docs/guides/evaluation.md)."),
    groups: Optional[str] = typer.Option(None, help="Run only these groups of the suite, comma-separated (e.g. N32_F128 of scale, line of launch); default: all."),
    steps: int = typer.Option(600, min=1, help="Control steps per rollout."),
    controllers: Optional[str] = typer.Option(None, help=f"Comma-separated subset of {','.join(NAMES)} (default: {','.join(DEFAULT)}, those with a checkpoint); KIND:NAME=PATH adds a learned controller with its own checkpoint, e.g. madp:r4=runs/r4/policy.safetensors (shown as madp:r4)."),
    lpac: Optional[Path] = typer.Option(None, help="LPAC-K3 policy.safetensors (default: the shipped one)."),
    madp: Optional[Path] = typer.Option(None, help="MADP policy.safetensors (default: the shipped one)."),
    sampler: Optional[str] = typer.Option(None, help="MADP sampler: ddim | dpm++ (DPM-Solver++(2M)); default: the measured best (docs/reports/2026-12-01-sampler-steps.md)."),
    sampling_steps: Optional[int] = typer.Option(None, min=1, help="Sampler steps S for MADP; default: the measured best."),
    ddim_steps: Optional[int] = typer.Option(None, min=1, hidden=True, help="Old spelling of --sampler ddim --sampling-steps S."),
    eta: Optional[float] = typer.Option(None, min=0.0, max=1.0, help="DDIM η (default 0; DPM-Solver++ is deterministic: 0 only)."),
    fixed_noise: bool = typer.Option(False, "--fixed-noise", help="MADP: draw each robot's initial noise once per episode, not every step."),
    sampling: Optional[str] = SAMPLING,
    frame: Optional[str] = typer.Option(None, help="MADP: d4 (the default: a random rotation/reflection of the world per step, shared by the swarm) | world (the world's own axes)."),
    select: Optional[str] = SELECT,
    candidates: Optional[int] = CANDIDATES,
    precision: Optional[str] = typer.Option(None, help="MADP: fp32 (the default) | bf16 (the transformer's linear layers in bfloat16, the rest in float32: faster on CPUs with bfloat16 instructions; actions within bf16 rounding of fp32's)."),
    workers: int = typer.Option(0, min=0, help="Worker processes (0: all cores)."),
    record: int = typer.Option(0, min=0, help="Write the first K environments' rollouts as MCAP (Foxglove)."),
    video: int = typer.Option(0, min=0, help="Write MP4 videos of K environments per controller, spread over the suite's groups (each group's first, then each group's second, ...; cities: the first K cities) to OUT/<suite>/videos/."),
    cities: Optional[Path] = typer.Option(None, help="Directory of city files (default: the 40 cities shipped with madp)."),
    out: Path = typer.Option(Path("runs/eval"), help="Output root; results go to OUT/<suite>/."),
    overwrite: bool = typer.Option(False, help="Replace results made with other settings: removes only the files madp wrote in OUT/<suite>/ (config, job files, recordings, tables and the report's files); any other file makes it refuse, naming the file."),
    ray: Optional[str] = ray_option(),
    device: str = typer.Option("cpu", help="Where the learned controllers' models run: cpu | cuda | cuda:I | auto (cuda when there is one). Each worker holds its own copy."),
    runtime: str = typer.Option("torch", help="How MADP (decentralized) runs: torch (the PyTorch policy) | onnx (every robot through the files of madp export and the torch-free robot runtime, with the same noise; docs/guides/export.md)."),
) -> None:
    """Evaluate controllers across a scenario suite: tables, plots, MCAP rollouts and MP4 videos.
    `madp eval compare RUN_A RUN_B …` compares finished evaluations."""
    if ctx.invoked_subcommand is not None:
        return
    from madp.eval.runner import EvalConfig, available_controllers, run_suite
    from madp.eval.suites import suite_names
    from madp.policies import SamplingSettings
    from madp.policies.device import resolve_device
    from madp.sampling import merge_sampling

    suites = suite_names(suite)
    requested, named = parse_controllers(controllers) if controllers else (DEFAULT, {})
    if ddim_steps is not None:
        sampler, sampling_steps = "ddim", ddim_steps
    sampling = SamplingSettings.of(**merge_sampling(sampling, sampler=sampler, sampling_steps=sampling_steps, eta=eta,
                                                    fixed_noise=fixed_noise or None, frame=frame, select=select,
                                                    candidates=candidates, precision=precision))
    cfg = EvalConfig(suite=suite, out=str(out), num_envs=num_envs, steps=steps, lpac=str(lpac) if lpac else None,
                     madp=str(madp) if madp else None, sampling=sampling, workers=workers, ray=ray,
                     record=record, video=video, cities=str(cities) if cities else None, device=resolve_device(device),
                     named=tuple(named.items()), groups=tuple(g.strip() for g in groups.split(",")) if groups else (),
                     runtime=runtime, paired_se=paired_se)
    cfg, used = available_controllers(cfg, requested, explicit=controllers is not None)
    if used != requested:
        skipped = ", ".join(c for c in requested if c not in used)
        typer.echo(f"note: no checkpoint for {skipped}; evaluating {', '.join(used)}")
    for c in used:  # a policy file without the learned network its rule reads runs the rule's fallback
        fitted = cfg.sampling_of(c).select
        if fitted != cfg.sampling.select:
            typer.echo(f"note: {c}'s policy file carries no {RULES[cfg.sampling.select].needs}; it chooses by "
                       f"{fitted} ({NEEDS[RULES[cfg.sampling.select].needs].made_by} adds one)")
    for s in suites:
        run_suite(cfg, s, overwrite=overwrite)
        typer.echo((Path(cfg.out) / s / "summary.md").read_text())


@app.command("export")
def export_cmd(
    policy: Path = typer.Argument(..., help="MADP policy.safetensors (e.g. madp/checkpoints/madp-cpu.safetensors)."),
    out: Path = typer.Option(..., help="Directory for the graphs and runtime.json (created)."),
    sampling: Optional[str] = typer.Option(None, "--sampling", help=sampling_help("The export fixes sampler (dpm++), steps and precision (fp32); madp swarm and madp-robot may change its rule, k and frame.")),
    sampling_steps: Optional[int] = typer.Option(None, min=1, help="DPM-Solver++(2M) steps S in runtime.json (default: the evaluation default, 3)."),
    frame: Optional[str] = typer.Option(None, help="d4 (the default) | world (as madp eval --frame)."),
    select: Optional[str] = SELECT,
    candidates: Optional[int] = CANDIDATES,
    overwrite: bool = typer.Option(False, help="Replace an earlier export in --out (any other file there makes it refuse)."),
) -> None:
    """Write MADP's networks of one robot's step as ONNX graphs (perception, encoder, denoiser) and runtime.json, for the torch-free robot runtime (docs/guides/export.md)."""
    from madp.export.onnx import export_policy
    from madp.policies import SamplingSettings
    from madp.sampling import merge_sampling

    settings = {"sampler": "dpm++", **merge_sampling(sampling, sampling_steps=sampling_steps, frame=frame, select=select,
                                                     candidates=candidates)}
    spec = export_policy(policy, out, SamplingSettings.of(**settings), overwrite=overwrite)
    typer.echo(f"{policy} -> {out}: {', '.join(spec['graphs'].values())}, runtime.json ({spec['sampler']['name']} "
               f"S = {spec['sampler']['steps']}, {spec['selection']['rule']} among K = {spec['selection']['candidates']}, "
               f"frame {spec['selection']['frame']}; sha256 {spec['source']['sha256'][:12]})")


@scenario_app.command("import")
def scenario_import_cmd(
    source: Path = typer.Argument(..., help="Traffic signals: CSV (lat,lon), GeoJSON points or Overpass JSON."),
    out: Path = typer.Option(..., help="Scenario JSON to write."),
    seed: int = typer.Option(0, min=0, help="Seed for σ, peaks and robot start positions."),
    num_robots: int = typer.Option(32, min=1, help="Robots, launched uniformly."),
    sigma: Tuple[float, float] = typer.Option((40.0, 60.0), help="σ range (m)."),
    peak: Tuple[float, float] = typer.Option((0.6, 1.0), help="Peak-height range."),
) -> None:
    """Turn traffic-signal locations into a scenario file (the 1024 m square with the most signals)."""
    from madp.cities.importer import city_scenario
    from madp.sim import SimParams

    sc, src = city_scenario(source, seed, SimParams(num_robots=num_robots, sigma_range_m=sigma, peak_range=peak))
    sc.save(out)
    typer.echo(f"{src.name}: {src.num_signals_in_square} of {src.num_signals_total} signals in the best 1024 m "
               f"square (centre {src.square_center_latlon[0]:.5f}, {src.square_center_latlon[1]:.5f}) -> {out}")


def _add_commands() -> None:
    """The commands kept in modules of their own, so this one stays small."""
    from madp.commands.bench import bench_app  # the benchmark commands (madp bench ...)
    from madp.commands.data import dataset_import_cmd  # madp dataset import: a run's log back into data
    from madp.commands.report import report_cmd  # madp eval report: the documentation's results tables
    from madp.commands.swarm import swarm_cmd  # madp swarm: one process per robot over Zenoh
    from madp.commands.value import value_app  # madp value: the value rule's learned map prior
    from madp.commands.compare import compare_cmd  # madp eval compare: finished evaluations, paired
    from madp.commands.critic import critic_app  # madp critic: the learned critic of MADP's joint copies
    app.add_typer(bench_app, name="bench")
    app.add_typer(value_app, name="value")
    app.add_typer(critic_app, name="critic")
    dataset_app.command("import")(dataset_import_cmd)
    eval_app.command("report")(report_cmd)
    eval_app.command("compare")(compare_cmd)
    app.command("swarm")(swarm_cmd)


_add_commands()


def main(argv: Optional[List[str]] = None) -> None:
    """Entry point (:func:`madp.commands.main.run`): a user's mistake is one line, exit status 2; a bug its
    traceback and a request to report it, exit status 1."""
    from madp.commands.main import run

    run(app, sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    main()
