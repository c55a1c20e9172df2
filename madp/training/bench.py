"""``madp bench train``: training throughput by phase, against this machine's own matmul peak.

One timed step is exactly one optimizer step of ``madp train`` with one micro-batch, cut into four
phases that are timed separately (device-synchronised):

* ``data``: the next batch from the training stream (shard read, decode, float16 -> float32,
  collate) in this process. ``madp train`` does this in its loader workers (``--workers``, default
  1) while the model computes, so it costs wall time only when it is slower than the other three.
* ``forward``: the loss of the batch (:func:`.trainer.batch_loss`, noise draw included).
* ``backward``: ``loss.backward()``.
* ``optimizer``: gradient clipping, the optimizer step, the EMA update (MADP) and zeroing the
  gradients, with the optimizer :func:`.trainer.make_optimizer` builds.

``samples_per_s`` is the batch size over the median of forward + backward + optimizer (what one
training process achieves when its loader keeps up). The FLOPs of forward + backward are counted
by ``torch.utils.flop_counter`` (matmuls, convolutions, attention; element-wise work is not
counted), and the same run measures the float32 matmul FLOP/s of the same thread count
(:func:`madp.models.bench.matmul_flops_per_s`, sampled after every round of steps, median):
``fraction_of_matmul`` is the achieved share of that
physical limit and ``samples_per_matmul_gflop`` the machine-normalised throughput (samples/s per
GFLOP/s of matmul), which moves less with the machine's load than samples/s do.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterator

import torch

from madp.errors import InputError, SettingError
from madp.models.bench import count_flops, sync_device, torch_threads, matmul_flops_per_s

from .config import TrainConfig, resolve

__all__ = ["TrainBenchCase", "bench_train", "format_train_bench", "bench_dataset"]

PHASES = ("data", "forward", "backward", "optimizer")


@dataclass(frozen=True)
class TrainBenchCase:
    """One row of the table: a model, a preset and a thread count (batch: the preset's unless set)."""

    model: str
    preset: str
    threads: int
    batch_size: int | None = None
    compile: bool = False
    optimizer_impl: str = "default"  # default (what madp train uses) | loop | foreach | fused


def bench_dataset(out: Path, samples: int = 256, seed: int = 0) -> Path:
    """A small expert dataset (``madp datagen`` on one worker) for the data phase."""
    from madp.datagen.plan import DatagenConfig
    from madp.datagen.runner import run_datagen

    run_datagen(DatagenConfig(samples, seed=seed, samples_per_shard=128), out, workers=1, progress=False)
    return out


def _batches(cfg: TrainConfig) -> Iterator[dict]:
    """Batches of the training stream, forever (epoch after epoch), decoded in this process."""
    from madp.data_schema.dataset import open_dataset

    from .stream import ShardStream, StreamPosition, collate_swarms

    stream = ShardStream(cfg.datasets, [open_dataset(d) for d in cfg.datasets], "train", cfg.seed, cfg.batch_size,
                         cfg.buffer_size)
    epoch = 0
    while True:
        stream.set_position(StreamPosition(epoch, 0))
        chunk: list[dict] = []
        for sample in stream:
            chunk.append(sample)
            if len(chunk) == cfg.batch_size:
                yield collate_swarms(chunk)
                chunk = []
        epoch += 1


class _CaseRun:
    """One case's model, optimizer and batch stream, stepped one training step at a time."""

    def __init__(self, case: TrainBenchCase, data: Path, seed: int, device: torch.device):
        from madp.data_schema.dataset import open_dataset

        from .optim import make_optimizer
        from .trainer import EMA, build_model

        self.case, self.device = case, device
        cfg = self.cfg = resolve(case.model, case.preset, data=str(data), batch_size=case.batch_size, seed=seed)
        with torch_threads(case.threads):
            torch.manual_seed(seed)
            raw = self.raw = build_model(cfg, 0).to(device)
            stats = open_dataset(data).action_stats
            raw.set_action_stats(torch.tensor(stats.mean, dtype=torch.float32),
                                 torch.tensor(stats.std, dtype=torch.float32).clamp_min(1e-6))
            raw.train()
            self.opt = make_optimizer(cfg, raw.parameters(), impl=case.optimizer_impl)
            self.ema = EMA(raw, cfg.ema_decay) if cfg.model == "madp" else None
            self.model = torch.compile(raw) if case.compile else raw
        self.batches = _batches(cfg)
        self.times: dict[str, list[float]] = {p: [] for p in PHASES}
        self.steps_done = 0

    def _clock(self, t0: float) -> float:
        sync_device(self.device)
        return time.perf_counter() - t0

    def _loss(self, model, batch: dict, step: int) -> torch.Tensor:
        from .loss import batch_loss, step_generator, step_noise

        draws = None
        if self.cfg.model == "madp":
            k, noise = step_noise(self.raw, step_generator(self.cfg.seed, step, self.device), batch, 1)
            draws = (k[0], noise[0])
        return batch_loss(model, self.raw, batch, self.cfg, draws, self.device)

    def step(self, timed: bool) -> None:
        with torch_threads(self.case.threads):
            t = time.perf_counter()
            batch = next(self.batches)
            d_data = self._clock(t)
            t = time.perf_counter()
            loss = self._loss(self.model, batch, self.steps_done)
            d_fwd = self._clock(t)
            t = time.perf_counter()
            loss.backward()
            d_bwd = self._clock(t)
            t = time.perf_counter()
            if self.cfg.grad_clip:
                torch.nn.utils.clip_grad_norm_(self.raw.parameters(), self.cfg.grad_clip)
            self.opt.step()
            if self.ema is not None:
                self.ema.update(self.raw)
            self.opt.zero_grad(set_to_none=True)
            d_opt = self._clock(t)
        self.steps_done += 1
        if timed:
            for p, v in zip(PHASES, (d_data, d_fwd, d_bwd, d_opt)):
                self.times[p].append(v)

    def report(self, matmul_flops: float | None) -> dict[str, Any]:
        cfg, case = self.cfg, self.case
        with torch_threads(case.threads):
            batch = next(self.batches)
            flops = count_flops(lambda: self._loss(self.raw, batch, 0).backward())
            self.opt.zero_grad(set_to_none=True)
            compute = [f + b + o for f, b, o in zip(self.times["forward"], self.times["backward"],
                                                    self.times["optimizer"])]
            step_s = statistics.median(compute)
            out: dict[str, Any] = {
                "model": case.model, "preset": case.preset, "threads": torch.get_num_threads(),
                "batch_size": cfg.batch_size, "num_robots": int(batch["pos_m"].shape[1]), "compile": case.compile,
                "optimizer_impl": case.optimizer_impl, "device": str(self.device), "steps": len(compute),
                "params": sum(p.numel() for p in self.raw.parameters()),
                "phase_s": {p: statistics.median(v) for p, v in self.times.items()},
                "step_s": step_s, "samples_per_s": cfg.batch_size / step_s,
                "flops_per_step": flops, "achieved_flops_per_s": flops / step_s,
            }
            if matmul_flops:
                mm = matmul_flops
                out.update(matmul_flops_per_s=mm, fraction_of_matmul=flops / step_s / mm,
                           samples_per_matmul_gflop=out["samples_per_s"] / (mm / 1e9))
        return out


def bench_train(cases: list[TrainBenchCase], data: Path, steps: int = 10, warmup: int = 3, seed: int = 0,
                device: torch.device | str = "cpu", measure_matmul: bool = True) -> list[dict[str, Any]]:
    """Time ``steps`` training steps of every case on the dataset ``data`` (after ``warmup`` untimed
    ones), the cases taking turns step by step, so that a change of the machine's load falls on all
    of them alike and their ratios stay fair.

    Returns one dict per case: the case, ``samples_per_s``, the median seconds of each phase
    (``phase_s``), ``step_s`` (median of forward + backward + optimizer), ``flops_per_step`` and,
    with ``measure_matmul``, ``matmul_flops_per_s``, ``fraction_of_matmul`` and
    ``samples_per_matmul_gflop``."""
    runs = [_CaseRun(c, data, seed, torch.device(device)) for c in cases]
    thread_counts = sorted({c.threads for c in cases})
    matmul: dict[int, list[float]] = {t: [] for t in thread_counts}
    for i in range(warmup + steps):
        for r in runs:
            r.step(timed=i >= warmup)
        if measure_matmul and i >= warmup:  # the peak is sampled between the steps, under the same load
            for t in thread_counts:
                with torch_threads(t):
                    matmul[t].append(matmul_flops_per_s(n=1024, reps=1, device=device))
    return [r.report(statistics.median(matmul[r.case.threads]) if measure_matmul else None) for r in runs]


def run_train_bench(cases: list[TrainBenchCase], data: Path | None = None, steps: int = 10, warmup: int = 3,
                    device: torch.device | str = "cpu") -> list[dict[str, Any]]:
    """Every case of ``cases`` on ``data`` (default: a 256-sample dataset made in a temporary directory)."""
    if data is not None and not (Path(data) / "manifest.json").is_file():
        raise InputError(f"{data}: no manifest.json (expected a madp dataset)")
    with tempfile.TemporaryDirectory(prefix="madp-bench-train-") as tmp:
        if data is None:
            data = bench_dataset(Path(tmp) / "data")
        return bench_train(cases, data, steps=steps, warmup=warmup, device=device)


def format_train_bench(rows: list[dict[str, Any]]) -> list[str]:
    """The table ``madp bench train`` prints (milliseconds per step by phase)."""
    head = (f"{'model':<6}{'preset':<7}{'thr':>4}{'batch':>6}{'variant':>16}{'samples/s':>11}"
            f"{'data':>8}{'fwd':>8}{'bwd':>8}{'opt':>8}{'GFLOP':>7}{'GFLOP/s':>9}{'matmul':>8}{'share':>7}{'s/GF':>6}")
    lines = [head, "-" * len(head)]
    for r in rows:
        ph = r["phase_s"]
        variant = ("compile," if r["compile"] else "") + r["optimizer_impl"]
        mm = r.get("matmul_flops_per_s")
        tail = (f"{mm / 1e9:>8.1f}{100 * r['fraction_of_matmul']:>6.0f}%{r['samples_per_matmul_gflop']:>6.2f}"
                if mm else f"{'-':>8}{'-':>7}{'-':>6}")
        lines.append(f"{r['model']:<6}{r['preset']:<7}{r['threads']:>4}{r['batch_size']:>6}{variant:>16}"
                     f"{r['samples_per_s']:>11.1f}" + "".join(f"{1e3 * ph[p]:>8.1f}" for p in PHASES)
                     + f"{r['flops_per_step'] / 1e9:>7.2f}{r['achieved_flops_per_s'] / 1e9:>9.1f}" + tail)
    lines.append("phases in ms per step (data: decoded in this process; madp train decodes in its loader "
                 "workers); share = achieved / matmul GFLOP/s; s/GF = samples/s per matmul GFLOP/s")
    return lines


def parse_cases(models: str, presets: str, threads: str, ablate: bool = False) -> list[TrainBenchCase]:
    """The cases of ``madp bench train``: every (preset, model, thread count) of the comma-separated
    lists, or with ``ablate`` :func:`ablation_cases` of both models."""
    if ablate:
        return [c for m in ("madp", "lpac") for c in ablation_cases(m)]

    def items(value: str, setting: str, expected: str, ok) -> list[str]:
        out = [v.strip() for v in value.split(",") if v.strip()]
        if not out or not all(ok(v) for v in out):
            raise SettingError(setting, f"expected comma-separated {expected}, got {value!r}")
        return out

    counts = [int(t) for t in items(threads, "threads", "positive integers", lambda v: v.isdigit() and int(v) > 0)]
    return default_cases(items(models, "models", "madp, lpac", {"madp", "lpac"}.__contains__),
                         items(presets, "presets", "cpu, paper", {"cpu", "paper"}.__contains__), counts)


def default_cases(models: list[str], presets: list[str], threads: list[int], compile: bool = False,
                  optimizer_impl: str = "default") -> list[TrainBenchCase]:
    return [TrainBenchCase(m, p, t, compile=compile, optimizer_impl=optimizer_impl)
            for p in presets for m in models for t in threads]


def ablation_cases(model: str, preset: str = "cpu", threads: int = 1) -> list[TrainBenchCase]:
    """The speed options, one at a time, beside ``madp train``'s default (same process, same data)."""
    base = TrainBenchCase(model, preset, threads)
    return [base, replace(base, optimizer_impl="loop"), replace(base, optimizer_impl="foreach"),
            replace(base, optimizer_impl="fused"), replace(base, compile=True)]
