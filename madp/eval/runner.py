"""Run a suite: every controller on every environment, resumable, in parallel; then tables and plots.

Layout of ``OUT/<suite>/``::

    config.json            suite, steps, controllers, MADP sampler settings, checkpoint paths and checksums
                           (per kind, ``lpac`` / ``madp``, and per named controller, ``madp:r4``)
    jobs/<env>-<controller>.npz   one finished rollout: cost curve, step times (written atomically;
                                  a named controller ``madp:r4`` is ``madp@r4`` in file names)
    curves.parquet         normalised cost per (group, env, controller, step)
    results.parquet        final cost, wall time per control step and, over a network, the bytes each robot
                           put on the air per step (``bytes_per_robot_step``) per (group, env, controller)
    summary.md, summary.json, *.png      from :mod:`madp.eval.report`
    rollouts/<env>-<controller>.mcap     with --record K: the first K environments, for Foxglove
    videos/<env>-<controller>.mp4        with --video K: K environments spread over the groups (:func:`video_envs`)

An interrupted evaluation resumes: finished jobs are kept, the rest run. The suite directory is
locked (:mod:`madp.io.lock`) while a run writes it, its worker processes die with it, and
``--overwrite`` removes only the files listed above (:func:`owned_files`), refusing any other.
With ``ray`` set (``--ray``) the same tasks (:func:`plan_jobs`, the pool's :func:`_worker`) run as
Ray tasks (:mod:`madp.io.ray_backend`) writing into ``OUT/<suite>/``, a path every node must see.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from madp.io.checksum import sha256_file
from madp.io.atomic import atomic_path, remove_temps, write_text_atomic
from madp.io.lock import locked_dir
from madp.io.owned import clear_owned
from madp.io.ray_backend import import_ray, ray_imap_unordered
from madp.io.workers import die_with_parent
from madp.controllers import CHECKPOINT_KINDS, CLASSICAL, CONTROLLERS, LEARNED, NAMES, controller_info, file_stem, \
    is_named, make_controller, resolve_checkpoint
from madp.errors import InputError, SettingError, check_extra
from madp.policies import SamplingSettings
from madp.policies.checkpoint import carried
from madp.sampling import ONNX_MODULES, RUNTIMES
from madp.sim import CoverageEnv
from madp.sim.rollout import Actions, Costs, Hook, Links, Positions, Samples, Timing, act_alone, run

from .suites import MAX_NUM_ENVS, EnvSpec, only_groups, suite_envs

#: Settings added after suites were first written: an older config.json without them had these values.
SETTING_DEFAULTS = {"noise": "torch", "fixed_noise": False, "frame": "world", "select": "none", "candidates": 1, "video": 0,
                    "device": "cpu", "runtime": "torch", "precision": "fp32"}

@dataclass(frozen=True)
class EvalConfig:
    suite: str
    out: str = "runs/eval"
    num_envs: int = 50
    steps: int = 600
    controllers: tuple[str, ...] = NAMES
    lpac: str | None = None  # checkpoint paths (None: the shipped ones, if any)
    madp: str | None = None
    named: tuple[tuple[str, str], ...] = ()  # (named controller "madp:r4", its checkpoint path)
    sampling: SamplingSettings = field(default_factory=SamplingSettings)  # MADP's sampler settings (checked)
    workers: int = 0
    ray: str | None = None  # run the jobs on Ray ("local", "auto" or an address: madp.io.ray_backend)
    record: int = 0
    video: int = 0
    cities: str | None = None
    record_every: int = 5
    record_samples: int = 4
    device: str = "cpu"  # where the learned controllers' models run ("cpu", "cuda", "cuda:I")
    groups: tuple[str, ...] = ()  # run only these groups of the suite (empty: all)
    runtime: str = "torch"  # RUNTIMES: "onnx" runs decentralized MADP through madp.robot (madp.export.swarm)
    paired_se: float | None = None  # run each suite's first environments for this SE of a paired difference

    def __post_init__(self) -> None:
        if self.runtime not in RUNTIMES:
            raise SettingError("runtime", f"expected one of {', '.join(RUNTIMES)}, got {self.runtime!r}")
        if self.runtime == "onnx":
            check_extra("runtime", "onnx", "onnx", ONNX_MODULES)
            if self.sampling.precision != "fp32":
                raise SettingError("precision", f"{self.sampling.precision} samples with the PyTorch policy; "
                                                "--runtime onnx runs the float32 export (use --runtime torch)")
        n = self.num_envs
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_NUM_ENVS:
            raise SettingError("num_envs", f"expected a whole number of environments per group in [1, {MAX_NUM_ENVS}], "
                                           f"got {n!r}")
        if self.ray is not None:
            import_ray()  # a one-line error now when Ray is not installed

    def checkpoint(self, controller: str) -> str | None:
        """The checkpoint this evaluation gives ``controller``: a named one's own (``madp:r4``), else its
        kind's (``lpac`` / ``madp``; None: classical or the shipped one)."""
        named = dict(self.named)
        if controller in named:
            return named[controller]
        if is_named(controller):
            raise SettingError("controllers", f"{controller}: no checkpoint given; expected {controller}=PATH")
        info = controller_info(controller)
        return getattr(self, info.kind) if info.learned else None

    def sampling_of(self, controller: str) -> SamplingSettings:
        """The sampling ``controller`` runs: this evaluation's, fitted to its policy file (the rule's
        fallback where the file lacks the network the rule reads: :meth:`SamplingSettings.fitted`)."""
        if not controller_info(controller).samples:
            return self.sampling
        return self.sampling.fitted(carried(resolve_checkpoint(controller, self.checkpoint(controller))))

    def controller(self, name: str, spec: EnvSpec):
        """Controller ``name`` as this suite runs it (:func:`madp.controllers.make_controller`), MADP's
        noise seeded by the environment's seed; with ``runtime="onnx"`` decentralized MADP runs robot by robot
        through the export of its checkpoint (:class:`madp.export.swarm.OnnxMADPPolicy`, the same noise)."""
        info = controller_info(name)
        if self.runtime == "onnx" and info.samples:
            if info.mode != "decentralized":
                raise SettingError("runtime", f"onnx runs MADP robot by robot (decentralized), not {name}")
            from madp.export.swarm import OnnxMADPPolicy

            return OnnxMADPPolicy(resolve_checkpoint(name, self.checkpoint(name)), self.sampling_of(name), seed=spec.seed)
        return make_controller(name, self.checkpoint(name), seed=spec.seed, sampling=self.sampling, device=self.device)


def video_envs(envs: list[EnvSpec], k: int) -> list[EnvSpec]:
    """The environments ``--video K`` films: K of them, taken across the suite's groups in turn (every
    group's first environment, then every group's second, …), so a suite of G groups gets one video
    per group at K = G; for ``uniform`` these are the first K environments, for ``cities`` the first
    K cities."""
    groups = list(dict.fromkeys(e.group for e in envs))
    return sorted(envs, key=lambda e: (e.index, groups.index(e.group)))[:k]


def video_path(suite_dir: Path, spec: EnvSpec, controller: str) -> Path:
    return suite_dir / "videos" / f"{spec.key}-{file_stem(controller)}.mp4"


def job_path(suite_dir: Path, spec: EnvSpec, controller: str) -> Path:
    """The job file of ``controller`` on one environment (:func:`madp.controllers.file_stem`)."""
    return suite_dir / "jobs" / f"{spec.key}-{file_stem(controller)}.npz"


def run_job(cfg: EvalConfig, spec: EnvSpec, controller: str, suite_dir: Path, record: bool = False,
            video: bool = False) -> dict:
    """Roll one controller out on one environment; write its job file (and an MCAP if ``record``, an
    MP4 if ``video``)."""
    scenario = spec.scenario()
    env = CoverageEnv(scenario, network=spec.network)
    ctrl = cfg.controller(controller, spec)
    info, steps = controller_info(controller), cfg.steps
    costs, timing = Costs(steps), Timing(steps)
    hooks: list[Hook] = [costs, timing]
    if record:
        positions, actions, links = Positions(steps), Actions(steps), Links(steps)
        hooks += [positions, actions] + ([links] if spec.network is not None else [])
        if info.samples:
            import torch

            viz_generator = torch.Generator().manual_seed(spec.seed ^ 0x5A5A)  # leaves the rollout's noise alone
            samples = Samples(steps, cfg.record_samples, cfg.record_every,
                              lambda e: ctrl.sample(e, cfg.record_samples, viz_generator))
            hooks.append(samples)
    if video:
        from madp.video import Frames

        frames = Frames(video_path(suite_dir, spec, controller), steps)
        hooks.append(frames)
    run([env], act_alone(ctrl), hooks, steps)
    if record:
        from madp.recordings.record import write_rollout_mcap

        (suite_dir / "rollouts").mkdir(parents=True, exist_ok=True)
        write_rollout_mcap(suite_dir / "rollouts" / f"{spec.key}-{file_stem(controller)}.mcap", env.world_map,
                           positions.positions_m[0], actions.actions_mps[0], controller, env.params.dt_s,
                           samples_mps=samples.samples_mps if info.samples else None, every=cfg.record_every,
                           title=f"{spec.suite}/{spec.group} #{spec.index} ({scenario.name})",
                           extra_metadata={**info.settings(cfg.sampling_of(controller)), **_network_metadata(spec)},
                           links=links.links if spec.network is not None else None)
    if video:
        frames.write()
    _save_job(job_path(suite_dir, spec, controller), costs.cost[0], timing.step_s, env.num_robots,
              len(scenario.features), _traffic(env, steps))
    return {"key": spec.key, "controller": controller}


def _network_metadata(spec: EnvSpec) -> dict:
    """The network's settings for a recording's metadata (``network.loss``, …), none without one."""
    return {} if spec.network is None else {f"network.{k}": v for k, v in spec.network.as_dict().items()}


def _traffic(env: CoverageEnv, steps: int) -> dict[str, float]:
    """The mean bytes each robot put on the air per step, per channel and ``total``
    (:meth:`madp.sim.network.Network.bytes_per_robot_step`); none without a network."""
    return {} if env.network is None else env.network.bytes_per_robot_step(steps)


def _save_job(job_file: Path, costs: np.ndarray, step_s: np.ndarray, num_robots: int, num_features: int,
              traffic: dict[str, float]) -> None:
    """One job file: the cost curve, the step times, the sizes and the bytes on the air per robot and
    step (``bytes_channels`` [C] names, ``bytes_per_robot_step`` [C]; empty without a network)."""
    job_file.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(job_file, ".npz", fsync=False) as tmp:  # a full disk: the error names the job file
        np.savez(tmp, cost=costs, step_s=step_s, num_robots=num_robots, num_features=num_features,
                 bytes_channels=np.array(list(traffic), dtype=str),
                 bytes_per_robot_step=np.array(list(traffic.values()), dtype=np.float64))


def run_batch(cfg: EvalConfig, specs: list[EnvSpec], controller: str, suite_dir: Path,
              video: frozenset[str] = frozenset()) -> list[dict]:
    """Roll a learned controller out on several environments (same N) in lockstep, one policy call
    per control step for all of them; write one job file per environment.

    Each environment keeps its own sampling noise (MADP: a generator seeded as in :func:`run_job`),
    so a batch differs from lone rollouts only by float rounding. ``step_s`` is the batch's wall
    time per control step divided by the batch size (the amortised cost per environment). The
    environments whose keys are in ``video`` are filmed (MP4), in the batch, so filming changes no result."""
    from madp.policies import noise_generator

    envs = [CoverageEnv(s.scenario(), network=s.network) for s in specs]
    if len({e.num_robots for e in envs}) != 1:
        raise ValueError("run_batch: environments of one batch must have the same number of robots")
    ctrl = cfg.controller(controller, specs[0])
    generators = [noise_generator(s.seed) for s in specs]
    costs, timing = Costs(cfg.steps), Timing(cfg.steps)
    hooks: list[Hook] = [costs, timing]
    if any(s.key in video for s in specs):
        from madp.video import Frames

        filmed = [Frames(video_path(suite_dir, s, controller), cfg.steps, index=i) for i, s in enumerate(specs)
                  if s.key in video]
        hooks += filmed
    run(envs, lambda es: ctrl.act_batch(es, generators), hooks, cfg.steps)
    for f in hooks[2:]:
        f.write()
    for i, (spec, env) in enumerate(zip(specs, envs)):
        _save_job(job_path(suite_dir, spec, controller), costs.cost[i], timing.step_s, env.num_robots,
                  len(env.scenario.features), _traffic(env, cfg.steps))
    return [{"key": s.key, "controller": controller} for s in specs]


def plan_jobs(envs: list[EnvSpec], controllers: tuple[str, ...], suite_dir: Path, record: int,
              batch: int = 8) -> list[tuple[str, list[EnvSpec], bool]]:
    """The unfinished work as ``(controller, envs, record)`` tasks.

    Learned controllers run ``batch`` environments with the same number of robots at a time (fixed
    chunks of the suite's order, so a rerun forms the same batches); classical controllers and the first ``record``
    environments (recorded as MCAP) run one environment per task."""
    finished = {p.name for p in (suite_dir / "jobs").glob("*.npz")}

    def done(e: EnvSpec, c: str) -> bool:
        return job_path(suite_dir, e, c).name in finished

    tasks = []
    for c in controllers:
        chunk: list[EnvSpec] = []
        for i, e in enumerate(envs):
            if c in CLASSICAL or i < record:
                if not done(e, c):
                    tasks.append((c, [e], i < record))
                continue
            if chunk and (len(chunk) == batch or chunk[0].params.num_robots != e.params.num_robots):
                tasks.append((c, chunk, False))
                chunk = []
            chunk.append(e)
        if chunk:
            tasks.append((c, chunk, False))
    return [(c, [e for e in es if not done(e, c)], rec) for c, es, rec in tasks if any(not done(e, c) for e in es)]


def run_task(cfg: EvalConfig, controller: str, specs: list[EnvSpec], suite_dir: Path, record: bool,
             video: frozenset[str] = frozenset()) -> int:
    """Run one task of :func:`plan_jobs`; film the environments whose keys are in ``video``."""
    if len(specs) == 1:
        run_job(cfg, specs[0], controller, suite_dir, record, specs[0].key in video)
    else:
        run_batch(cfg, specs, controller, suite_dir, video)
    return len(specs)


def _worker(args):
    cfg, controller, specs, suite_dir, record, video = args
    import torch

    torch.set_num_threads(1)
    return run_task(cfg, controller, specs, Path(suite_dir), record, video)


def available_controllers(cfg: EvalConfig, requested: tuple[str, ...], explicit: bool) -> tuple[EvalConfig, tuple[str, ...]]:
    """Resolve checkpoints; drop learned controllers without one unless they were asked for. A named
    controller (``madp:r4``) must have its checkpoint in ``cfg.named``; each checkpoint is loaded once
    here, so a missing or incompatible file is a one-line error before anything runs."""
    from madp.policies import load, shipped_checkpoint

    unknown = [c for c in requested if not is_named(c) and c not in NAMES]
    if unknown:
        raise SettingError("controllers", f"unknown {unknown}; expected some of {list(NAMES)}")
    for c in filter(is_named, requested):
        try:
            controller_info(c)
        except SettingError as e:
            raise SettingError("controllers", str(e).partition(": ")[2]) from None
    if len(set(requested)) != len(requested):
        raise SettingError("controllers", f"a controller is given twice in {list(requested)}")
    paths = {k: getattr(cfg, k) for k in CHECKPOINT_KINDS}  # EvalConfig has a field per checkpoint kind
    keep = []
    for c in requested:
        kind = controller_info(c).kind
        if is_named(c):
            try:
                load(cfg.checkpoint(c), kind)
            except FileNotFoundError:
                raise InputError(f"{cfg.checkpoint(c)}: checkpoint not found (controller {c})") from None
        elif kind in paths:
            path = paths[kind] or (str(shipped_checkpoint(kind)) if shipped_checkpoint(kind) else None)
            if path is None:
                if explicit:
                    raise SettingError("controllers", message=f"controllers {c}: no {kind} checkpoint given and none ships "
                                                              "with this install")
                continue
            load(path, kind)  # a missing or incompatible checkpoint is a one-line error now
            paths[kind] = path
        keep.append(c)
    return replace(cfg, **paths, controllers=tuple(keep)), tuple(keep)


def owned_files(suite_dir: Path) -> list[str]:
    """What madp wrote in a suite directory (relative paths): its config, job files, recordings,
    tables and every file the report lists in ``summary.json``. What ``--overwrite`` may remove."""
    out = ["config.json", "curves.parquet", "results.parquet", "summary.md", "summary.json"]
    out += [f"jobs/{p.name}" for p in (suite_dir / "jobs").glob("*.npz")]
    out += [f"rollouts/{p.name}" for p in (suite_dir / "rollouts").glob("*.mcap")]
    out += [f"videos/{p.name}" for p in (suite_dir / "videos").glob("*.mp4")]
    try:
        files = json.loads((suite_dir / "summary.json").read_text())["metadata"]["files"]
        out += [f for f in files if isinstance(f, str) and "/" not in f]
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return out


def _read_config(cfg_file: Path) -> dict | None:
    """The suite's config.json, or None when there is none (or a kill left it unreadable)."""
    try:
        old = json.loads(cfg_file.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        raise InputError(f"{cfg_file}: unreadable; pass --overwrite to start the suite afresh") from None
    if not isinstance(old, dict):
        raise InputError(f"{cfg_file}: expected a JSON object; pass --overwrite to start the suite afresh")
    return old


def run_suite(cfg: EvalConfig, suite: str, overwrite: bool = False, progress: bool = True) -> dict:
    """Run (or resume) one suite and write its tables and plots. Returns the report's summary. With
    ``cfg.paired_se`` the suite's first environments per group, as many as that standard error of a
    paired difference needs (:func:`madp.eval.paired_se.envs_for_se`, at most ``cfg.num_envs``)."""
    if cfg.paired_se is not None:
        from .paired_se import envs_for_se

        groups = len(cfg.groups) or len({e.group for e in suite_envs(suite, 1, cfg.cities)})
        cfg = replace(cfg, num_envs=envs_for_se(suite, cfg.paired_se, groups, cfg.num_envs))
    envs = only_groups(suite_envs(suite, cfg.num_envs, cfg.cities), cfg.groups)
    suite_dir = Path(cfg.out) / suite
    with locked_dir(suite_dir):
        return _run_suite_locked(cfg, suite, envs, suite_dir, overwrite, progress)


def _run_suite_locked(cfg: EvalConfig, suite: str, envs: list[EnvSpec], suite_dir: Path, overwrite: bool,
                      progress: bool) -> dict:
    # MADP's sampling as flat keys (sampler, sampling_steps, eta, …), as earlier suites wrote them.
    settings = {"suite": suite, "num_envs": cfg.num_envs, "steps": cfg.steps, **cfg.sampling.as_dict(),
                "record": cfg.record, "video": cfg.video, "env_keys": [e.key for e in envs],
                "env_seeds": [e.seed for e in envs], "device": cfg.device,
                "runtime": cfg.runtime, "noise": "torch"}  # every runtime draws the torch generators' noise here
    # The checkpoints this run uses: per kind (the plain controllers') and per named controller.
    plain_kinds = {controller_info(c).kind for c in cfg.controllers if not is_named(c)}
    used = [(k, getattr(cfg, k)) for k in CHECKPOINT_KINDS if getattr(cfg, k) and k in plain_kinds]
    used += [(c, cfg.checkpoint(c)) for c in cfg.controllers if is_named(c)]
    checkpoints = {k: {"path": path, "sha256": sha256_file(path)} for k, path in used}
    cfg_file = suite_dir / "config.json"
    try:
        old = _read_config(cfg_file)
    except ValueError:
        if not overwrite:
            raise
        old = {"checkpoints": {}}  # differs in every setting: the suite starts afresh
    if old is not None:
        # Controllers may be added to a finished suite. A new checkpoint invalidates only the controllers
        # that use it; any other setting that differs invalidates the whole suite.
        changed = {k for k in settings if old.get(k, SETTING_DEFAULTS.get(k)) != settings[k]}
        retrained = {k for k, v in checkpoints.items() if k in old.get("checkpoints", {})
                     and old["checkpoints"][k]["sha256"] != v["sha256"]}
        if changed or retrained:
            if not overwrite:
                what = ", ".join(sorted(changed | {f"{k} checkpoint" for k in retrained}))
                raise InputError(f"{suite_dir}: holds an evaluation with other settings ({what}); "
                                 "pass --overwrite or another --out")
            if changed:
                clear_owned(suite_dir, owned_files(suite_dir))
            else:
                stale = [c for c in LEARNED if CONTROLLERS[c].kind in retrained] + [c for c in retrained if is_named(c)]
                for c in map(file_stem, stale):
                    for f in [*suite_dir.glob(f"jobs/*-{c}.npz"), *suite_dir.glob(f"rollouts/*-{c}.mcap"),
                              *suite_dir.glob(f"videos/*-{c}.mp4")]:
                        f.unlink()
        if not changed:
            checkpoints = {**old.get("checkpoints", {}), **checkpoints}
    suite_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(cfg_file, json.dumps({**settings, "checkpoints": checkpoints}, indent=1) + "\n")
    remove_temps(suite_dir)
    # The first --record environments of the suite (in suite order) are recorded as MCAP; --video K
    # films K environments across the groups (in their batches: a video changes no result).
    tasks = plan_jobs(envs, cfg.controllers, suite_dir, cfg.record)
    filmed = frozenset(e.key for e in video_envs(envs, cfg.video))
    total = len(envs) * len(cfg.controllers)
    pending = sum(len(es) for _, es, _ in tasks)
    workers = cfg.workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(tasks))) if tasks else 1
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(TextColumn(f"eval {suite}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  TextColumn("ETA"), TimeRemainingColumn(), disable=not progress) as bar:
        task = bar.add_task(suite, total=total, completed=total - pending)
        if cfg.ray is not None and tasks:
            for n in ray_imap_unordered(_worker, [(cfg, c, es, str(suite_dir.absolute()), rec, filmed) for c, es, rec in tasks],
                                        cfg.ray):
                bar.advance(task, n)
            remove_temps(suite_dir)  # what a worker killed mid-job left (Ray ran its task again)
        elif workers == 1:
            from madp.models.bench import torch_threads

            with torch_threads(1):  # one torch thread, as in every pool worker: two evaluations side by side
                for c, es, rec in tasks:  # do not fight over the cores, and --workers changes no bit
                    bar.advance(task, run_task(cfg, c, es, suite_dir, rec, filmed))
        else:
            os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
            with mp.get_context("spawn").Pool(workers, initializer=die_with_parent, initargs=(os.getpid(),)) as pool:
                for n in pool.imap_unordered(_worker, [(cfg, c, es, str(suite_dir), rec, filmed) for c, es, rec in tasks]):
                    bar.advance(task, n)
    write_tables(envs, cfg, suite_dir)
    from .report import write_report

    return write_report(suite_dir, suite)


def _job_bytes(job) -> float | None:
    """A job file's total bytes on the air per robot and step (None, a null in ``results.parquet``,
    without a network or from a job file written before they were counted)."""
    if "bytes_channels" not in job.files:
        return None
    names = [str(c) for c in job["bytes_channels"]]
    return float(job["bytes_per_robot_step"][names.index("total")]) if "total" in names else None


def write_tables(envs: list[EnvSpec], cfg: EvalConfig, suite_dir: Path) -> None:
    """curves.parquet and results.parquet from the job files, in suite order."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    curves = {k: [] for k in ("suite", "group", "env", "scenario_seed", "controller", "step", "cost")}
    results = {k: [] for k in ("suite", "group", "env", "scenario_seed", "controller", "final_cost", "steps",
                               "mean_step_ms", "num_robots", "num_features", "sigma_lo", "sigma_hi", "city", "launch",
                               "sampler", "sampling_steps", "fixed_noise", "frame", "select", "candidates",
                               "precision", "noise", "bytes_per_robot_step")}
    sampling = {c: controller_info(c).settings(cfg.sampling_of(c)) for c in cfg.controllers}
    for e in envs:
        for c in cfg.controllers:
            d = np.load(job_path(suite_dir, e, c))
            cost = d["cost"]
            t = len(cost)
            for k, v in (("suite", [e.suite] * t), ("group", [e.group] * t), ("env", np.full(t, e.index)),
                         ("scenario_seed", np.full(t, e.seed)), ("controller", [c] * t), ("step", np.arange(t)),
                         ("cost", cost)):
                curves[k].append(v)
            row = dict(suite=e.suite, group=e.group, env=e.index, scenario_seed=e.seed, controller=c,
                       final_cost=float(cost[-1]), steps=t - 1, mean_step_ms=float(d["step_s"].mean() * 1e3),
                       num_robots=int(d["num_robots"]), num_features=int(d["num_features"]),
                       sigma_lo=e.params.sigma_range_m[0], sigma_hi=e.params.sigma_range_m[1],
                       city=e.group if e.city_file else "", launch=e.launch,
                       sampler=sampling[c].get("sampler", ""), sampling_steps=sampling[c].get("sampling_steps", 0),
                       fixed_noise=sampling[c].get("fixed_noise", False), frame=sampling[c].get("frame", ""),
                       select=sampling[c].get("select", ""), candidates=sampling[c].get("candidates", 0),
                       precision=sampling[c].get("precision", ""), noise="torch" if sampling[c] else "",
                       bytes_per_robot_step=_job_bytes(d))
            for k, v in row.items():
                results[k].append(v)
    types = {"env": pa.int32(), "step": pa.int32(), "steps": pa.int32(), "num_robots": pa.int32(),
             "sampling_steps": pa.int32(), "candidates": pa.int32(),
             "num_features": pa.int32(), "scenario_seed": pa.int64(), "bytes_per_robot_step": pa.float64()}
    ctab = pa.table({k: pa.array(np.concatenate([np.asarray(x) for x in v]), type=types.get(k)) for k, v in curves.items()})
    rtab = pa.table({k: pa.array(v, type=types.get(k)) for k, v in results.items()})
    for name, tab in (("curves", ctab), ("results", rtab)):
        with atomic_path(suite_dir / f"{name}.parquet", fsync=False) as tmp:
            pq.write_table(tab, tmp, compression="zstd")
