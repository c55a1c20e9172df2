"""Run a datagen plan: shard tasks on a process pool, resumable, then the manifest.

Directory layout::

    DIR/manifest.json                  written last, when every shard of the plan is present
    DIR/{train,val,test}/shard-NNNNN.{mcap,parquet}
    DIR/.datagen/plan.json             the configuration; a later run must match it
    DIR/.datagen/shards/<split>-NNNNN.json   one record per finished shard (count, sha256, stats)

Crash safety: the run holds the directory's lock (:mod:`madp.io.lock`) from start to end, and its
worker processes die with it. A shard is written to ``NAME.<pid>.tmp`` and renamed when complete;
its record is written the same way afterwards. On start, stray temporary files are removed and every
task without a record is (re)run, so after ``kill -9`` at any moment — of the whole process group or
of the parent alone — the same command finishes with exactly the bytes of an uninterrupted run.

``--overwrite`` removes only what madp wrote here (:func:`owned_files`); any other file makes it
refuse, naming the file.

``--ray``: the same shard tasks (the pool's :func:`_worker`) run as Ray tasks
(:mod:`madp.io.ray_backend`), each writing its shard and record into the directory as above; the
driver holds the lock, counts progress as tasks complete and writes the manifest. A task whose worker
dies is run again by Ray; the temporary file the dead attempt left is removed at the end.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Optional

from madp.data_schema import (
    ActionStatsAccumulator,
    DataError,
    Manifest,
    ShardInfo,
    SplitInfo,
    write_shard,
)
from madp.data_schema.manifest import MANIFEST_FILENAME, dumps_canonical
from madp.data_schema.shard_io import check_shard
from madp.errors import SettingError
from madp.io.atomic import remove_temps, temp_path, write_text_atomic
from madp.io.lock import LOCK_FILENAME, locked_dir
from madp.io.owned import clear_owned, foreign_files
from madp.io.ray_backend import import_ray, ray_imap_unordered
from madp.io.workers import die_with_parent

from .episodes import shard_episodes
from .plan import SPLITS, DatagenConfig, ShardTask, make_plan

STATE_DIR = ".datagen"


@dataclass
class ShardRecord:
    """What a finished shard task reports (stored as JSON beside the plan)."""

    task: str
    info: ShardInfo
    action_stats_state: dict | None  # exact accumulator state, train split only

    def to_dict(self) -> dict:
        return {"task": self.task, "shard": self.info.to_dict(), "action_stats_state": self.action_stats_state}

    @classmethod
    def from_dict(cls, d: dict, where: str) -> "ShardRecord":
        try:
            return cls(d["task"], ShardInfo.from_dict(d["shard"], where), d["action_stats_state"])
        except (KeyError, TypeError) as e:
            raise DataError.at(where, f"malformed shard record ({e})") from None


def run_shard(cfg: DatagenConfig, task: ShardTask, root: Path, on_sample: Callable[[], None] | None = None) -> ShardRecord:
    """Generate and write one shard, then its record. Deterministic in (cfg, task)."""
    acc = ActionStatsAccumulator() if task.split == "train" else None

    def episodes():
        for ep in shard_episodes(cfg, task, on_sample):
            if acc is not None:
                acc.add(ep.actions)
            yield ep

    info = write_shard(root / task.file(cfg.format), episodes(), cfg.format)
    info.file = task.file(cfg.format)
    if info.num_samples != task.num_samples:  # a bug, not a user error
        raise RuntimeError(f"{info.file}: wrote {info.num_samples} samples, planned {task.num_samples}")
    record = ShardRecord(task.name, info, acc.state() if acc is not None else None)
    write_text_atomic(root / STATE_DIR / "shards" / f"{task.name}.json", dumps_canonical(record.to_dict()))
    return record


# --- worker processes --------------------------------------------------------------------------
_queue = None


def _init_worker(queue, parent_pid: int) -> None:
    global _queue
    die_with_parent(parent_pid)
    _queue = queue


def _worker(args) -> dict:
    """One shard task in a worker process: the local pool's (progress through the queue) or a Ray
    task's (no queue: the driver advances when the task completes)."""
    cfg_dict, task, root = args
    cfg = DatagenConfig.from_dict(cfg_dict)
    if _queue is None:
        return run_shard(cfg, task, Path(root)).to_dict()
    pending = [0]

    def tick():
        pending[0] += 1
        if pending[0] >= 8:
            _queue.put(pending[0])
            pending[0] = 0

    rec = run_shard(cfg, task, Path(root), tick)
    if pending[0]:
        _queue.put(pending[0])
    return rec.to_dict()


# --- the run ------------------------------------------------------------------------------------
def owned_files(root: Path) -> list[str]:
    """What madp wrote in a dataset directory (relative paths): the manifest and the shards it
    lists, the plan, the shard records and the shards they name. What ``--overwrite`` may remove."""
    out = [MANIFEST_FILENAME, f"{STATE_DIR}/plan.json"]
    try:
        m = Manifest.load(root / MANIFEST_FILENAME)
        out += [s.file for sp in m.splits.values() for s in sp.shards]
    except DataError:
        pass
    for p in sorted((root / STATE_DIR / "shards").glob("*.json")):
        out.append(f"{STATE_DIR}/shards/{p.name}")
        try:
            out.append(ShardRecord.from_dict(json.loads(p.read_text()), str(p)).info.file)
        except (DataError, ValueError, OSError):
            pass
    return out


def prepare_dir(cfg: DatagenConfig, root: Path, overwrite: bool) -> None:
    """Check ``root`` (locked by the caller) is empty or belongs to this plan; clean stray temporary files.

    With ``overwrite``, a directory of another plan is cleared of madp's files (:func:`owned_files`);
    any other file is refused by name and nothing is removed."""
    plan_path = root / STATE_DIR / "plan.json"
    want = dumps_canonical(cfg.to_dict())
    if any(p.name != LOCK_FILENAME for p in root.iterdir()):
        have = plan_path.read_text() if plan_path.exists() else None
        if have != want:
            if not have:
                foreign = foreign_files(root, owned_files(root))
                if foreign:
                    raise DataError.at(root, f"is not empty and holds no madp dataset plan ({foreign[0].relative_to(root)} "
                                             "is not madp's); choose another --out")
            if not overwrite:
                why = "was made with other parameters" if have else "holds madp files but no datagen plan"
                raise DataError.at(root, f"{why}; choose another --out or pass --overwrite")
            clear_owned(root, owned_files(root))
    remove_temps(root)
    if not plan_path.exists():
        write_text_atomic(plan_path, want)


def load_records(root: Path, tasks: Iterable[ShardTask]) -> dict[str, ShardRecord]:
    """Records of the finished tasks whose shard file is present with the recorded size."""
    out = {}
    for t in tasks:
        p = root / STATE_DIR / "shards" / f"{t.name}.json"
        if not p.exists():
            continue
        rec = ShardRecord.from_dict(json.loads(p.read_text()), str(p))
        f = root / rec.info.file
        if f.exists() and f.stat().st_size == rec.info.bytes:
            out[t.name] = rec
    return out


def build_manifest(cfg: DatagenConfig, records: dict[str, ShardRecord], tasks: list[ShardTask]) -> Manifest:
    splits = {s: SplitInfo() for s in SPLITS}
    acc = ActionStatsAccumulator()
    for t in tasks:
        rec = records[t.name]
        splits[t.split].shards.append(rec.info)
        if rec.action_stats_state is not None:
            acc.merge(ActionStatsAccumulator.from_state(rec.action_stats_state))
    params = cfg.to_dict()
    return Manifest(format=cfg.format, num_robots=cfg.params.num_robots, params=params, splits=splits,
                    action_stats=acc.result(), created_by=cfg.command())


def parse_shards(spec: Optional[str]) -> Optional[tuple[int, int]]:
    """``"I:J"`` -> ``(I, J)``, the part of the plan to run (``--shards``); None stays None."""
    if spec is None:
        return None
    try:
        i, j = (int(v) for v in spec.split(":"))
    except ValueError:
        raise SettingError("shards", f"expected I:J (two integers), got {spec!r}") from None
    return i, j


def run_datagen(
    cfg: DatagenConfig,
    root: Path,
    workers: int = 0,
    shards: Optional[tuple[int, int]] = None,
    overwrite: bool = False,
    progress: bool = True,
    ray: Optional[str] = None,
) -> Optional[Manifest]:
    """Generate the dataset (or the part ``shards`` = (I, J) of its task list) into ``root``.

    ``ray``: run the shard tasks on Ray instead of local worker processes (``"local"``, ``"auto"``
    or a cluster address: :mod:`madp.io.ray_backend`); ``root`` must then be a path every node sees.
    Returns the manifest once every task of the plan is done (None for an incomplete part).
    """
    if ray is not None:
        import_ray()  # a one-line error now when Ray is not installed
    root = Path(root)
    plan = make_plan(cfg)
    lo, hi = shards if shards is not None else (0, len(plan))
    if not (0 <= lo <= hi <= len(plan)):
        raise SettingError("shards", f"expected I:J within 0:{len(plan)}, got {lo}:{hi}")
    with locked_dir(root):
        return _run_locked(cfg, root, plan, lo, hi, workers, overwrite, progress, ray)


def _run_locked(cfg: DatagenConfig, root: Path, plan: list[ShardTask], lo: int, hi: int, workers: int,
                overwrite: bool, progress: bool, ray: Optional[str] = None) -> Optional[Manifest]:
    prepare_dir(cfg, root, overwrite)
    selected = plan[lo:hi]
    done = load_records(root, selected)
    todo = [t for t in selected if t.name not in done]
    workers = workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(todo))) if todo else 1
    total = sum(t.num_samples for t in selected)
    finished = sum(done[t].info.num_samples for t in done)
    t0 = time.perf_counter()
    with _Progress(total, finished, progress) as bar:
        if ray is not None and todo:
            # absolute: a relative --out is the driver's folder, not one under each Ray worker's own directory
            for d in ray_imap_unordered(_worker, [(cfg.to_dict(), t, str(root.absolute())) for t in todo], ray):
                rec = ShardRecord.from_dict(d, "ray task result")
                done[rec.task] = rec
                bar.advance(rec.info.num_samples)
            remove_temps(root)  # what a worker killed mid-shard left (Ray ran its task again)
        elif workers == 1:
            for t in todo:
                rec = run_shard(cfg, t, root, lambda: bar.advance(1))
                done[t.name] = rec
        else:
            ctx = mp.get_context("spawn")
            queue = ctx.Queue()
            env_threads = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
            os.environ.update({k: "1" for k in env_threads})  # one BLAS thread per worker process
            try:
                with ctx.Pool(workers, initializer=_init_worker, initargs=(queue, os.getpid())) as pool:
                    args = [(cfg.to_dict(), t, str(root)) for t in todo]
                    results = pool.imap_unordered(_worker, args)
                    remaining = len(todo)
                    while remaining:
                        while not queue.empty():
                            bar.advance(queue.get())
                        try:
                            d = results.next(timeout=0.2)
                        except mp.TimeoutError:
                            continue
                        rec = ShardRecord.from_dict(d, "worker result")
                        done[rec.task] = rec
                        remaining -= 1
                    while not queue.empty():
                        bar.advance(queue.get())
            finally:
                for k, v in env_threads.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v
    elapsed = time.perf_counter() - t0
    made = total - finished
    all_done = load_records(root, plan)
    if len(all_done) < len(plan):
        if progress:
            print(f"part {lo}:{hi} done: {total} samples in {hi - lo} shards ({made / max(elapsed, 1e-9):.1f} samples/s); "
                  f"{len(plan) - len(all_done)} of {len(plan)} shards of the plan still missing")
        return None
    manifest = build_manifest(cfg, all_done, plan)
    manifest.save(root / MANIFEST_FILENAME)
    if progress:
        size = sum(s.bytes for sp in manifest.splits.values() for s in sp.shards)
        c = manifest.counts()
        print(f"{manifest.num_samples} samples (train {c['train']}, val {c['val']}, test {c['test']}) in "
              f"{len(plan)} {cfg.format} shards, {size / 1e6:.1f} MB ({size / manifest.num_samples / 1e3:.1f} kB/sample); "
              f"{made} made in {elapsed:.1f} s ({made / max(elapsed, 1e-9):.1f} samples/s) -> {root}")
    return manifest


def merge_parts(parts: list[Path], root: Path) -> Optional[Manifest]:
    """Combine part directories made with ``--shards`` into ``root`` (copying shards and records).

    Every shard is checked against its record while it is copied (size, sha256, counts: one read),
    and a shard already in ``root`` is checked again before it is kept."""
    plans = {p: (p / STATE_DIR / "plan.json") for p in parts}
    texts = set()
    for p, f in plans.items():
        if not f.exists():
            raise DataError.at(p, "is not a madp datagen directory (no .datagen/plan.json)")
        texts.add(f.read_text())
    if len(texts) != 1:
        raise DataError.at(parts[0], "the parts were made with different parameters")
    cfg = DatagenConfig.from_dict(json.loads(texts.pop()))
    if any(Path(p).resolve() == Path(root).resolve() for p in parts):
        raise DataError.at(root, "--out must differ from every part directory")
    with locked_dir(root):
        return _merge_locked(cfg, parts, root)


def _merge_locked(cfg: DatagenConfig, parts: list[Path], root: Path) -> Optional[Manifest]:
    prepare_dir(cfg, root, overwrite=False)
    plan = make_plan(cfg)
    n = cfg.params.num_robots
    for p in parts:
        for name, rec in load_records(p, plan).items():
            dst = root / rec.info.file
            try:
                check_shard(dst, rec.info, num_robots=n)  # already merged and intact: keep it
            except DataError:
                dst.parent.mkdir(parents=True, exist_ok=True)
                tmp = temp_path(dst)
                try:
                    check_shard(p / rec.info.file, rec.info, num_robots=n, copy_to=tmp)
                    os.replace(tmp, dst)
                finally:
                    tmp.unlink(missing_ok=True)
            write_text_atomic(root / STATE_DIR / "shards" / f"{name}.json", dumps_canonical(rec.to_dict()))
    records = load_records(root, plan)
    if len(records) < len(plan):
        missing = [t.name for t in plan if t.name not in records]
        print(f"merged; still missing {len(missing)} shard(s), e.g. {missing[:3]}")
        return None
    manifest = build_manifest(cfg, records, plan)
    manifest.save(root / MANIFEST_FILENAME)
    return manifest


class _Progress:
    """Progress with samples/s and ETA: a rich bar on a terminal, a plain line every 30 s in a log."""

    def __init__(self, total: int, completed: int, enabled: bool):
        self.enabled = enabled
        self.total, self.completed = total, completed

    def __enter__(self):
        if not self.enabled:
            return self
        import sys

        self.t0, self.start, self.last_line = time.perf_counter(), self.completed, 0.0
        self.tty = sys.stdout.isatty()
        if self.tty:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TaskProgressColumn, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self.p = Progress(TextColumn("datagen"), BarColumn(), MofNCompleteColumn(), TaskProgressColumn(),
                              TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TextColumn("ETA"),
                              TimeRemainingColumn())
            self.p.__enter__()
            self.task = self.p.add_task("datagen", total=self.total, completed=self.completed, rate="")
        return self

    def advance(self, k: int) -> None:
        if not self.enabled:
            return
        self.completed += k
        now = time.perf_counter()
        rate = (self.completed - self.start) / max(now - self.t0, 1e-9)
        if self.tty:
            self.p.update(self.task, advance=k, rate=f"{rate:.1f} samples/s")
        elif now - self.last_line >= 30 or self.completed == self.total:
            eta = (self.total - self.completed) / max(rate, 1e-9)
            print(f"datagen {self.completed}/{self.total} ({100 * self.completed / self.total:.1f}%) "
                  f"{rate:.1f} samples/s, elapsed {now - self.t0:.0f} s, ETA {eta / 60:.1f} min", flush=True)
            self.last_line = now

    def __exit__(self, *exc):
        if self.enabled and self.tty:
            self.p.__exit__(*exc)
