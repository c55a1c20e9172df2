"""``madp``: the command line. Thin commands that parse options and call the layers.

User mistakes (a bad flag or value, a missing or malformed file, a wrong schema version, an output
directory another job is writing) end with one line ``madp: error: …`` on stderr and exit status 2;
set MADP_DEBUG=1 to see the traceback instead.
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

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, rich_markup_mode=None,
                  help="Multi-agent diffusion policies for coverage control: datasets, training, evaluation.")
bench_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Benchmarks (medians, with a baseline measured in the same run).")
app.add_typer(bench_app, name="bench")


class UserError(Exception):
    """A mistake in what the user asked for; printed as one line."""


def _user_errors() -> tuple[type[BaseException], ...]:
    from madp.io.lock import DirectoryLocked
    from madp.io.owned import NotOwned
    from madp.io.ray_backend import RayUnavailable
    from madp.sim.scenario import ScenarioError

    errors: list[type[BaseException]] = [UserError, ScenarioError, ValueError, OSError, DirectoryLocked, NotOwned,
                                         RayUnavailable]
    try:
        from madp.data_schema import DataError

        errors.append(DataError)
    except ImportError:  # pragma: no cover - data_schema is part of the package
        pass
    return tuple(errors)


def _write_json(path: Path, obj: object) -> None:
    from madp.io.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(obj, indent=1) + "\n")


# --- rollout ---------------------------------------------------------------------------------
@app.command()
def rollout(
    scenario: Path = typer.Option(..., "--scenario", help="Scenario JSON (features, robots, optional params)."),
    controller: str = typer.Option("clairvoyant", help="clairvoyant | dcvt | lpac | madp | madp_central"),
    checkpoint: Optional[Path] = typer.Option(None, help="Checkpoint of a learned controller (default: the shipped one)."),
    seed: Optional[int] = typer.Option(None, help="MADP's sampling-noise seed (default: the scenario's seed, else 0, as madp eval)."),
    steps: int = typer.Option(600, min=0, help="Control steps to run."),
    out: Path = typer.Option(Path("result.json"), help="Where to write the result JSON."),
    video: Optional[Path] = typer.Option(None, help="Also write the rollout as an MP4 video (steps + 1 frames: map, Voronoi cells, trails, robots, step and J(t)/J(0))."),
    device: str = typer.Option("cpu", help="Where a learned controller's model runs: cpu | cuda | cuda:I | auto (cuda when there is one)."),
) -> None:
    """Run one controller on one scenario; write J(t)/J(0) for t = 0..steps and the final positions."""
    from madp.controllers import NAMES, make_controller
    from madp.policies.device import resolve_device
    from madp.sim import CoverageEnv, Scenario
    from madp.sim import rollout as run

    if controller not in NAMES:
        raise UserError(f"--controller: expected one of {', '.join(NAMES)}, got {controller!r}")
    if checkpoint is not None and controller in ("clairvoyant", "dcvt"):
        raise UserError(f"--checkpoint: the {controller} controller takes no checkpoint")
    device = resolve_device(device)
    if video is not None:
        from madp.video import check_video_path

        try:
            check_video_path(video)  # before the rollout, not after it
        except ValueError as e:
            raise UserError(f"--video: {e}") from None
    sc = Scenario.load(scenario)
    noise_seed = seed if seed is not None else (sc.seed if sc.seed is not None else 0)
    ctrl = make_controller(controller, str(checkpoint) if checkpoint else None, seed=noise_seed, device=device)
    env = CoverageEnv(sc)
    result = run(env, ctrl, steps)
    _write_json(out, result.to_json(controller))
    typer.echo(f"{controller}: J({steps})/J(0) = {result.normalized_cost[-1]:.4f}"
               f" (converged at {result.converged_at}) -> {out}")
    if video is not None:
        from madp.video import write_rollout_video

        v = write_rollout_video(video, env.world_map, result.positions_m, result.normalized_cost, progress=True)
        typer.echo(f"video: {v['frames']} frames, {v['width']}x{v['height']}, {v['bytes'] / 1e6:.1f} MB -> {video}")


# --- datagen and datasets --------------------------------------------------------------------
dataset_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Inspect, verify, convert and merge datasets.")
app.add_typer(dataset_app, name="dataset")


#: ``--ray`` of datagen and eval; given alone, main() supplies ``local`` (madp.io.ray_backend.RAY_LOCAL).
RAY_HELP = ("Run the tasks on Ray: alone, a Ray started on this machine; 'auto': the cluster running here "
            "(ray start); HOST:PORT or ray://HOST:10001: that cluster. The output directory must be on a "
            "filesystem every node sees. Never changes the results. Needs madp[ray].")


def _ray_option(help: str = RAY_HELP):
    return typer.Option(None, "--ray", metavar="[ADDRESS]", help=help)


def _parse_shards(spec: Optional[str]) -> Optional[tuple[int, int]]:
    if spec is None:
        return None
    try:
        i, j = (int(v) for v in spec.split(":"))
    except ValueError:
        raise UserError(f"--shards: expected I:J (two integers), got {spec!r}") from None
    return i, j


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
    comm_radius: float = typer.Option(256.0, help="Communication radius r_c (m)."),
    world_size: int = typer.Option(1024, help="World side (m); 1 m cells."),
    samples_per_shard: int = typer.Option(512, min=1, help="Samples per shard (the last of a split holds the rest)."),
    shards: Optional[str] = typer.Option(None, help="Run only shard tasks I:J of the plan (merge parts later)."),
    overwrite: bool = typer.Option(False, help="Replace a dataset made with other parameters: removes only the files madp wrote there (its manifest, shard records and the shards they list); any other file makes it refuse, naming the file."),
    policy: Optional[Path] = typer.Option(None, help="Expert relabelling (DAgger): this policy.safetensors (MADP decentralized or LPAC-K3) drives; every sample keeps the expert's label."),
    beta: float = typer.Option(0.0, help="With --policy: probability that a step executes the expert's action instead."),
    max_steps: Optional[int] = typer.Option(None, min=1, help="Steps per episode at most (default 2100 for the expert, which stops when converged; exactly 600, the evaluation horizon, with --policy)."),
    launch: str = typer.Option("uniform", help="Where swarms start: uniform (anywhere) | packed (random boxes, bands and clusters; README Datasets)."),
    ray: Optional[str] = _ray_option(),
) -> None:
    """Generate (U0, X, O) samples from clairvoyant-CVT rollouts (or a learned policy's, relabelled by the expert) as MCAP or Parquet shards."""
    from madp.datagen import DatagenConfig, run_datagen
    from madp.sim import SimParams

    params = SimParams(world_size=world_size, num_robots=num_robots, num_features=num_features,
                       sigma_range_m=sigma, peak_range=peak, comm_radius_m=comm_radius)
    learner: dict = {}
    if policy is not None:
        from madp.data_schema.manifest import sha256_file
        from madp.training.checkpoint import load_policy

        _, meta = load_policy(policy)
        learner = {"path": str(policy.resolve()), "sha256": sha256_file(policy), "kind": meta["kind"],
                   "beta": beta,
                   "parent": {k: v for k, v in meta.get("dataset", {}).items() if k in ("root", "num_samples", "created_by", "more")}}
    elif beta:
        raise ValueError("--beta: only meaningful with --policy")
    cfg = DatagenConfig(num_samples=n, seed=seed, format=format, samples_per_shard=samples_per_shard, params=params,
                        policy=learner, max_steps=max_steps or (600 if policy is not None else 2100), launch=launch)
    run_datagen(cfg, out, workers=workers, shards=_parse_shards(shards), overwrite=overwrite, ray=_ray_address(ray))


@dataset_app.command("info")
def dataset_info_cmd(root: Path = typer.Argument(..., help="Dataset directory."),
                     json_out: bool = typer.Option(False, "--json", help="Print JSON instead of a table.")) -> None:
    """Counts, sizes, parameters and action statistics."""
    from madp.data_schema.dataset import dataset_info

    info = dataset_info(root)
    if json_out:
        typer.echo(json.dumps(info, indent=1))
        return
    typer.echo(f"{info['root']}: {info['num_samples']} samples, N = {info['num_robots']}, {info['format']}, "
               f"schema v{info['schema_version']}, code {info['code_version']}")
    typer.echo(f"  {'split':<6}{'samples':>9}{'episodes':>10}{'shards':>8}{'MB':>10}")
    for name in ("train", "val", "test"):
        s = info["splits"][name]
        typer.echo(f"  {name:<6}{s['samples']:>9}{s['episodes']:>10}{s['shards']:>8}{s['bytes'] / 1e6:>10.1f}")
    typer.echo(f"  {info['bytes'] / 1e6:.1f} MB on disk, {info['bytes_per_sample'] / 1e3:.1f} kB per sample")
    st = info["action_stats"]
    if st:
        typer.echo(f"  actions (train): mean {st['mean'][0]:+.4f} {st['mean'][1]:+.4f} m/s, "
                   f"std {st['std'][0]:.4f} {st['std'][1]:.4f} m/s over {st['count']} robot-samples")
    typer.echo(f"  made by: {info['created_by']}")


@dataset_app.command("verify")
def dataset_verify_cmd(root: Path = typer.Argument(..., help="Dataset directory.")) -> None:
    """Checksums of every shard and a full decode of every sample; non-zero exit naming any fault."""
    from madp.data_schema.dataset import verify_dataset

    n = verify_dataset(root)
    typer.echo(f"{root}: ok, {n} samples verified")


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


# --- training ----------------------------------------------------------------------------------
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
    compile: bool = typer.Option(False, "--compile", help="MADP: run the model through torch.compile (README, Training speed)."),
    stop_after_steps: Optional[int] = typer.Option(None, hidden=True),
    stop_after_minutes: Optional[float] = typer.Option(None, help="Stop (with a checkpoint) at the first optimizer step after this many minutes of training (a time budget; the lr schedule is not shortened)."),
) -> None:
    """Train MADP or LPAC-K3 on a dataset; checkpoints, metrics.jsonl, resume; DDP under torchrun."""
    from madp.training import resolve, train as run_train

    if threads:
        import torch

        torch.set_num_threads(threads)

    try:
        weights = tuple(float(w) for w in data_weights.split(",")) if data_weights else None
    except ValueError:
        raise ValueError(f"--data-weights: expected comma-separated numbers, got {data_weights!r}") from None
    cfg = resolve(model, preset, data=str(data[0]), more_data=tuple(str(d) for d in data[1:]), data_weights=weights,
                  out=str(out) if out else None, epochs=epochs, batch_size=batch_size,
                  lr=lr, seed=seed, num_workers=workers, grad_accum=grad_accum, val_samples=val_samples,
                  max_steps_per_epoch=max_steps_per_epoch, checkpoint_every=checkpoint_every,
                  stop_after_steps=stop_after_steps, stop_after_minutes=stop_after_minutes, augment=augment, edge_weight=edge_weight,
                  init=str(init) if init else None, compile=compile or None)
    res = run_train(cfg, resume=resume)
    if int(os.environ.get("RANK", "0")) == 0:
        typer.echo(f"{cfg.model}/{cfg.preset}: {res['stopped']} at step {res['step']}; "
                   f"best val loss {res.get('best_val_loss', float('nan')):.5f} -> {cfg.out}")


# --- evaluation ----------------------------------------------------------------------------------
scenario_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Scenario files.")
app.add_typer(scenario_app, name="scenario")


eval_app = typer.Typer(invoke_without_command=True, no_args_is_help=False, rich_markup_mode=None)
app.add_typer(eval_app, name="eval")


@eval_app.callback()
def eval_cmd(
    ctx: typer.Context,
    suite: str = typer.Option("uniform", help="uniform | sigma | cities | launch | scale | all, or a comma-separated list (uniform,cities); symmetry (the launch layouts' rotations and reflections) runs by name only"),
    num_envs: int = typer.Option(50, min=1, help="Environments per group (cities: at most this many cities)."),
    steps: int = typer.Option(600, min=1, help="Control steps per rollout."),
    controllers: Optional[str] = typer.Option(None, help="Comma-separated subset of clairvoyant,dcvt,lpac,madp,madp_central (default: every one available)."),
    lpac: Optional[Path] = typer.Option(None, help="LPAC-K3 policy.safetensors (default: the shipped one)."),
    madp: Optional[Path] = typer.Option(None, help="MADP policy.safetensors (default: the shipped one)."),
    sampler: Optional[str] = typer.Option(None, help="MADP sampler: ddim | dpm++ (DPM-Solver++(2M)); default: the measured best (README, Fast sampling)."),
    sampling_steps: Optional[int] = typer.Option(None, min=1, help="Sampler steps S for MADP; default: the measured best."),
    ddim_steps: Optional[int] = typer.Option(None, min=1, hidden=True, help="Old spelling of --sampler ddim --sampling-steps S."),
    eta: float = typer.Option(0.0, min=0.0, max=1.0, help="DDIM η (DPM-Solver++ is deterministic: 0 only)."),
    fixed_noise: bool = typer.Option(False, "--fixed-noise", help="MADP: draw each robot's initial noise once per episode, not every step."),
    workers: int = typer.Option(0, min=0, help="Worker processes (0: all cores)."),
    record: int = typer.Option(0, min=0, help="Write the first K environments' rollouts as MCAP (Foxglove)."),
    video: int = typer.Option(0, min=0, help="Write MP4 videos of K environments per controller, spread over the suite's groups (each group's first, then each group's second, ...; cities: the first K cities) to OUT/<suite>/videos/."),
    cities: Optional[Path] = typer.Option(None, help="Directory of city files (default: the 40 cities shipped with madp)."),
    out: Path = typer.Option(Path("runs/eval"), help="Output root; results go to OUT/<suite>/."),
    overwrite: bool = typer.Option(False, help="Replace results made with other settings: removes only the files madp wrote in OUT/<suite>/ (config, job files, recordings, tables and the report's files); any other file makes it refuse, naming the file."),
    ray: Optional[str] = _ray_option(),
    device: str = typer.Option("cpu", help="Where the learned controllers' models run: cpu | cuda | cuda:I | auto (cuda when there is one). Each worker holds its own copy."),
) -> None:
    """Evaluate controllers across a scenario suite: tables, plots, MCAP rollouts and MP4 videos.
    `madp eval compare RUN_A RUN_B …` compares finished evaluations."""
    if ctx.invoked_subcommand is not None:
        return
    from madp.eval.runner import ORDER, EvalConfig, available_controllers, run_suite
    from madp.eval.suites import EXTRA_SUITES, SUITES
    from madp.policies.device import resolve_device

    suites = list(SUITES) if suite == "all" else [s.strip() for s in suite.split(",")]
    if any(s not in SUITES + EXTRA_SUITES for s in suites):
        raise UserError(f"--suite: expected one of {list(SUITES) + ['all'] + list(EXTRA_SUITES)} or a comma-separated "
                        f"list, got {suite!r}")
    requested = tuple(c.strip() for c in controllers.split(",")) if controllers else ("clairvoyant", "dcvt", "lpac", "madp")
    from madp.models.samplers import DEFAULT_SAMPLER, DEFAULT_SAMPLING_STEPS, check_sampler

    if ddim_steps is not None:
        sampler, sampling_steps = "ddim", ddim_steps
    sampler = sampler or DEFAULT_SAMPLER
    sampling_steps = sampling_steps or DEFAULT_SAMPLING_STEPS
    check_sampler(sampler, sampling_steps, eta)
    cfg = EvalConfig(suite=suite, out=str(out), num_envs=num_envs, steps=steps, lpac=str(lpac) if lpac else None,
                     madp=str(madp) if madp else None, sampler=sampler, sampling_steps=sampling_steps, eta=eta,
                     fixed_noise=fixed_noise, workers=workers, ray=_ray_address(ray), record=record, video=video,
                     cities=str(cities) if cities else None, device=resolve_device(device))
    cfg, used = available_controllers(cfg, requested, explicit=controllers is not None)
    skipped = [c for c in requested if c not in used]
    if skipped:
        typer.echo(f"note: no checkpoint for {', '.join(skipped)}; evaluating {', '.join(used)}")
    for s in suites:
        summary = run_suite(cfg, s, overwrite=overwrite)
        typer.echo((Path(cfg.out) / s / "summary.md").read_text())


@eval_app.command("compare")
def eval_compare_cmd(
    runs: List[str] = typer.Argument(..., metavar="RUN", help="Two or more finished suite directories of madp eval (OUT/<suite>/), each PATH or NAME=PATH."),
    baseline: Optional[str] = typer.Option(None, help="The run the others are compared with: a name or a path (default: the first)."),
    out: Optional[Path] = typer.Option(None, help="Where compare.md, compare.json and compare.png go (default runs/compare/<suite>)."),
) -> None:
    """Compare evaluations of one suite on the same environments: each run's mean, the paired difference to the baseline (SE, 95% interval) and wins k/n per controller and group."""
    from madp.eval.compare import compare_runs, load_run, markdown, name_runs, parse_run_argument, write_compare

    if len(runs) < 2:
        raise UserError(f"compare: expected at least two run directories, got {len(runs)}")
    loaded = name_runs([load_run(path, name) for name, path in map(parse_run_argument, runs)])
    cmp = compare_runs(loaded, baseline)
    files = write_compare(cmp, out or Path("runs/compare") / cmp["suite"])
    typer.echo(markdown(cmp))
    typer.echo(f"-> {', '.join(str(p) for p in files.values())}")


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
    import numpy as np

    from madp.eval.cities import import_city
    from madp.sim import Scenario, SimParams

    src = import_city(source, seed=seed, sigma_range=sigma, peak_range=peak)
    params = SimParams(num_robots=num_robots, num_features=len(src.features), sigma_range_m=sigma, peak_range=peak)
    robots = np.random.default_rng([seed, 1]).uniform(1e-4, params.world_size - 1e-4, (num_robots, 2))
    sc = Scenario(src.features, robots, params, name=src.name, seed=seed,
                  source=f"{source.name}: {src.num_signals_in_square} of {src.num_signals_total} signals, "
                         f"square SW corner {src.square_origin_latlon}, centre {src.square_center_latlon}")
    sc.save(out)
    typer.echo(f"{src.name}: {src.num_signals_in_square} of {src.num_signals_total} signals in the best 1024 m "
               f"square (centre {src.square_center_latlon[0]:.5f}, {src.square_center_latlon[1]:.5f}) -> {out}")


# --- benchmarks ------------------------------------------------------------------------------
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
        raise UserError(f"--library: {e}") from e
    for line in format_table(res):
        typer.echo(line)
    if out:
        _write_json(out, res)


@bench_app.command("datagen")
def bench_datagen_cmd(
    n: int = typer.Option(1024, "--n", min=64, help="Samples to generate for the timing."),
    workers: int = typer.Option(0, min=0, help="Worker processes (0: all cores)."),
    format: str = typer.Option("mcap", "--format", help="mcap | parquet"),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
    ray: Optional[str] = _ray_option("Measure the Ray backend's per-task overhead on this cluster ('auto', HOST:PORT) instead of a Ray started on this machine (measured whenever madp[ray] is installed)."),
) -> None:
    """End-to-end datagen rate at N = F = 32, the projected time for 100k samples, and the Ray backend's per-task overhead."""
    from madp.datagen.bench import bench_datagen, bench_ray_overhead
    from madp.io.ray_backend import RayUnavailable

    r = bench_datagen(n, workers, format)
    s = r["stages"]
    typer.echo(f"stage medians (one core): expert step {s['expert_step_ms']:.2f} ms, observations "
               f"{s['observations_ms']:.2f} ms, float16 {s['float16_ms']:.2f} ms -> {r['per_sample_ms_one_core']:.1f} ms/sample "
               f"(library: {r['library_per_sample_ms_one_core']:.0f} ms/sample, {r['stage_speedup_vs_library']:.1f}x)")
    typer.echo(f"datagen {n} samples ({format}): {r['wall_s']:.1f} s wall, {r['samples_per_s']:.1f} samples/s, "
               f"{r['bytes_per_sample'] / 1e3:.1f} kB/sample")
    typer.echo(f"projected 100k samples: {r['projected_100k_min']:.1f} min "
               f"(library cost model: {r['library_projected_100k_h']:.1f} h)")
    try:
        r["ray"] = x = bench_ray_overhead(ray, fmt=format)
    except RayUnavailable:
        if ray is not None:
            raise
        r["ray"] = None
        typer.echo('Ray backend: not measured (Ray is not installed; pip install "madp[ray]")')
    else:
        typer.echo(f"Ray backend ({x['address']}, {x['cpus']} CPUs): start {x['start_s']:.1f} s once per run; trivial task "
                   f"round trip {x['trivial_task_ms']:.1f} ms (median of {x['trivial_tasks']})")
        typer.echo(f"Ray shard task ({x['shard_samples']} samples): {x['shard_ray_s']:.2f} s on Ray vs {x['shard_local_s']:.2f} s "
                   f"in this process (medians of {x['repeats']}): {x['shard_ratio']:.3f}x ({1e3 * x['shard_overhead_s']:+.0f} ms); "
                   f"dispatch (round trip less the task's own time) {x['shard_dispatch_ms']:.1f} ms per task")
    if out:
        _write_json(out, r)


@bench_app.command("io")
def bench_io_cmd(
    n: int = typer.Option(512, "--n", min=16, help="Samples of real expert rollouts to encode and read."),
    repeats: int = typer.Option(5, min=1, help="Read passes per format (median)."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
) -> None:
    """Bytes per sample and decode throughput: MCAP, Parquet, and a float16 numpy memmap baseline."""
    import tempfile

    from madp.data_schema.bench import bench_io
    from madp.datagen.bench import real_episodes

    with tempfile.TemporaryDirectory() as d:
        r = bench_io(d, repeats=repeats, episodes=real_episodes(n))
    base = r["npy_memmap"]["read_samples_per_s"]
    typer.echo(f"{r['num_samples']} real samples, N = {r['num_robots']}, median of {repeats} warm reads")
    typer.echo(f"{'format':<12}{'kB/sample':>10}{'read samples/s':>16}{'vs memmap':>11}{'no-CRC samples/s':>18}")
    for fmt in ("mcap", "parquet", "npy_memmap"):
        x = r[fmt]
        nocrc = f"{x['read_samples_per_s_no_crc']:>18.0f}" if "read_samples_per_s_no_crc" in x else f"{'-':>18}"
        typer.echo(f"{fmt:<12}{x['bytes_per_sample'] / 1e3:>10.1f}{x['read_samples_per_s']:>16.0f}"
                   f"{x['read_samples_per_s'] / base:>10.2f}x{nocrc}")
    if out:
        _write_json(out, r)


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
    """Training samples/s by phase (data, forward, backward, optimizer) beside the matmul peak (see README)."""
    from madp.training.bench import ablation_cases, default_cases, format_train_bench, run_train_bench

    if ablate:
        cases = [c for m in ("madp", "lpac") for c in ablation_cases(m)]
    else:
        thread_counts = [int(t) for t in _csv(threads, "--threads", "positive integers", str.isdigit) if int(t) > 0]
        if not thread_counts:
            raise UserError(f"--threads: expected comma-separated positive integers, got {threads!r}")
        cases = default_cases(_csv(models, "--models", "madp, lpac", {"madp", "lpac"}.__contains__),
                              _csv(presets, "--presets", "cpu, paper", {"cpu", "paper"}.__contains__), thread_counts)
    if data is not None and not (data / "manifest.json").is_file():
        raise UserError(f"--data: {data}/manifest.json not found (expected a madp dataset)")
    rows = run_train_bench(cases, data, steps=steps, warmup=warmup)
    typer.echo(format_train_bench(rows))
    if out:
        _write_json(out, rows)


def _csv(value: str, flag: str, expected: str, ok) -> List[str]:
    """The comma-separated items of ``value``; one line naming ``flag`` unless every item is ``ok``."""
    items = [v.strip() for v in value.split(",") if v.strip()]
    if not items or not all(ok(v) for v in items):
        raise UserError(f"{flag}: expected comma-separated {expected}, got {value!r}")
    return items


@bench_app.command("infer")
def bench_infer_cmd(
    madp: Optional[Path] = typer.Option(None, help="Trained MADP checkpoint for the closed-loop sweep (default: shipped)."),
    envs: int = typer.Option(50, min=2, help="uniform-suite environments per sweep setting."),
    steps: int = typer.Option(600, min=1, help="Control steps per environment in the sweep."),
    grid: Optional[str] = typer.Option(None, help="Sweep settings 'sampler:S,...;...' (default dpm++:3,5,10,20;ddim:10,20,50; DDIM-50 is always run)."),
    sweep_out: Path = typer.Option(Path("runs/bench-infer"), help="Resumable sweep suites and the plot go here."),
    workers: int = typer.Option(0, min=0, help="Worker processes of the sweep (0: all cores)."),
    repeats: int = typer.Option(5, min=1, help="Timed calls per latency median."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here."),
    device: str = typer.Option("cpu", help="Where MADP runs, in the sweep and the latency: cpu | cuda | cuda:I | auto (cuda when there is one)."),
    presets: str = typer.Option("cpu,paper", help="Comma-separated presets whose latency is measured."),
    sweep: bool = typer.Option(True, "--sweep/--no-sweep", help="--no-sweep: no closed-loop sweep; the latency of every --grid setting instead."),
) -> None:
    """MADP: the fewest sampler steps S* that cost nothing in closed loop, and the latency per control step there."""
    from madp.eval.bench import bench_infer_all, parse_grid
    from madp.models.config import PRESETS
    from madp.policies.device import resolve_device

    names = tuple(p.strip() for p in presets.split(",") if p.strip())
    if not names or any(p not in PRESETS for p in names):
        raise UserError(f"--presets: expected a comma-separated subset of {','.join(PRESETS)}, got {presets!r}")
    r = bench_infer_all(str(madp) if madp else None, sweep_out, parse_grid(grid) if grid else None, envs=envs, steps=steps,
                        repeats=repeats, workers=workers, presets=names, device=resolve_device(device), sweep=sweep)
    sw = r["sweep"]
    if sw is None and not sweep:
        typer.echo("--no-sweep: latency of every --grid setting")
    elif sw is None:
        typer.echo("no trained MADP checkpoint: no closed-loop sweep (latency of DDIM-50 only)")
    else:
        b = sw["baseline"]
        typer.echo(f"decentralized MADP on uniform ({sw['envs']} envs, {sw['steps']} steps): mean J/J0 ± SE; "
                   f"DDIM-50 {b['mean']:.4f} ± {b['se']:.4f}")
        if not b["se_at_most_0.02"]:
            typer.echo(f"note: DDIM-50's SE {b['se']:.3f} > 0.02; about {b['envs_for_se_0.02']} environments would reach it "
                       f"(--envs)")
        typer.echo(f"{'sampler':<8}{'S':>4}{'mean':>9}{'SE':>8}{'diff vs DDIM-50':>22}{'within 1 SE':>13}{'eval ms/env-step':>18}")
        for x in sw["rows"]:
            typer.echo(f"{x['sampler']:<8}{x['steps']:>4}{x['mean']:>9.4f}{x['se']:>8.4f}"
                       f"{x['diff_vs_baseline']:>+13.4f} ± {x['diff_se']:.4f}{'yes' if x['within_one_se'] else 'no':>13}"
                       f"{x['eval_ms_per_env_step']:>18.1f}")
        c = sw["centralized_ddim50"]
        typer.echo(f"centralized-masked DDIM-50: {c['mean']:.4f}, {c['eval_ms_per_env_step']:.1f} eval ms/env-step; "
                   f"S* = {', '.join(f'{k}: {v}' for k, v in sw['s_star'].items())}; best: {r['best']['sampler']} "
                   f"S = {r['best']['steps']}; plot {r['plot']}")
    where = "2 threads" if r["device"] == "cpu" else r["device"]
    typer.echo(f"{'preset':<7}{'mode':<15}{'sampler':<8}{'S':>4}{'latency ms':>12}{'vs DDIM-50':>12}"
               f"   (median, N = 32, {where}; paper: {r['paper_latency_s']} s on an RTX 3090)")
    for x in r["latency"]:
        typer.echo(f"{x['preset']:<7}{x['mode']:<15}{x['sampler']:<8}{x['num_steps']:>4}{1e3 * x['latency_s']:>12.1f}"
                   f"{x['speedup_vs_ddim50']:>11.1f}x")
    if out:
        _write_json(out, r)


def _click_exceptions():
    """click's exception classes as typer raises them (recent typer vendors click as typer._click)."""
    import typer.core

    mod = getattr(typer.core, "_click", None)
    if mod is None:  # typer < 0.2x: click itself
        import click as mod
    return mod.exceptions


def _fail(msg: str) -> None:
    sys.stderr.write(f"madp: error: {' '.join(msg.split())}\n")
    sys.exit(2)


def _ray_address(ray: Optional[str]) -> Optional[str]:
    """The ``--ray`` value for the runners, checking first that Ray is installed (a one-line error)."""
    if ray is not None:
        from madp.io.ray_backend import import_ray

        import_ray()
    return ray


def _optional_ray_value(args: List[str]) -> List[str]:
    """``--ray`` followed by nothing or by another option means ``--ray local`` (click has no options
    with an optional value)."""
    from madp.io.ray_backend import RAY_LOCAL

    out = list(args)
    for i, a in enumerate(out):
        if a == "--":
            break
        if a == "--ray" and (i + 1 == len(out) or out[i + 1].startswith("-")):
            out.insert(i + 1, RAY_LOCAL)
            break
    return out


def main(argv: Optional[List[str]] = None) -> None:
    """Entry point: run the app, turning user mistakes into one line and exit status 2.

    Bad flags and values (typer's range checks included) are click exceptions: printed as one line,
    not click's usage box. Running a group without arguments still prints its help."""
    args = _optional_ray_value(sys.argv[1:] if argv is None else argv)
    cx = _click_exceptions()
    try:
        rv = app(args=args, prog_name="madp", standalone_mode=False)
    except getattr(cx, "NoArgsIsHelpError", ()) as e:
        e.show()
        sys.exit(e.exit_code)
    except cx.ClickException as e:
        if os.environ.get("MADP_DEBUG"):
            raise
        _fail(e.format_message())
    except typer.Abort as e:  # typer's translation of an EOFError (a file that ends early)
        if os.environ.get("MADP_DEBUG"):
            raise
        _fail(f"unexpected end of input ({type(e.__cause__).__name__ if e.__cause__ else 'aborted'})")
    except KeyboardInterrupt:
        sys.stderr.write("madp: interrupted\n")
        sys.exit(130)
    except _user_errors() as e:
        if os.environ.get("MADP_DEBUG"):
            raise
        _fail(str(e).splitlines()[0] if str(e) else type(e).__name__)
    if rv == 130:  # typer's translation of KeyboardInterrupt
        sys.stderr.write("madp: interrupted\n")
    if isinstance(rv, int) and rv:
        sys.exit(rv)


if __name__ == "__main__":
    main()
