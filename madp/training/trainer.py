"""``madp train``: stream shards into MADP or LPAC-K3; checkpoints, metrics, resume, DDP.

One loop for both models (nanoGPT-style: read it top to bottom). Determinism: the data order is a
function of (seed, epoch) (see :mod:`.stream`), the diffusion noise of step s is drawn from a
generator seeded with (seed, s), its communication dropout (``--comm-dropout``) from another
(:func:`.loss.step_links`), and the checkpoint holds everything else (weights, optimizer, EMA,
position, counters), so a resumed run continues exactly as an uninterrupted one.

Run directory::

    config.json            the resolved TrainConfig, model config, dataset and action statistics
    metrics.jsonl          one line per logged step ({"step", "epoch", "loss", ...}) and per epoch
                           ({"epoch", "val_loss", ...}); TensorBoard events too when installed
    checkpoints/latest/    see :mod:`.checkpoint`
    checkpoints/best/      lowest validation loss so far

Before anything is trained, every shard the run reads is checked against its manifest (size,
sha256, counts), a run that would do no step is refused, and the run directory is locked
(:mod:`madp.io.lock`) until the run ends; a resume refuses a damaged checkpoint by name.
"""

from __future__ import annotations

import functools
import json
import math
import os
import time
from contextlib import nullcontext
from pathlib import Path

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader

from madp.data_schema.dataset import check_shards, open_dataset
from madp.io.checksum import sha256_file
from madp.errors import InputError, SettingError
from madp.io.atomic import named, write_text_atomic
from madp.io.lock import locked_dir
from madp.io.workers import die_with_parent
from madp.models import EMA, MADP, lpac_config, madp_config

from .checkpoint import load_checkpoint_state, recover_checkpoints, save_checkpoint
from .config import TrainConfig, learning_rate
from .distill import load_teacher, teacher_action_stats
from .loss import TRAIN_STREAM, VAL_LINKS_STREAM, VAL_STREAM, batch_loss, step_generator, step_links, step_noise
from .optim import make_optimizer
from .progress import EpochBar
from .stream import ShardStream, StreamPosition, collate_swarms


# --- environment ---------------------------------------------------------------------------------
def setup_distributed() -> tuple[int, int, torch.device]:
    """(rank, world_size, device). Under torchrun: NCCL on GPUs, gloo on CPU. A process group the
    caller initialised already (e.g. a single-rank NCCL group) is used as it is: training then runs
    through DDP whatever its size."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    if dist.is_initialized():
        world, rank = dist.get_world_size(), dist.get_rank()
    if torch.cuda.is_available():
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        device = torch.device("cuda", local)
    else:
        device = torch.device("cpu")
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return rank, world, device


def build_model(cfg: TrainConfig, num_robots: int) -> torch.nn.Module:
    if cfg.model == "madp":  # a distilled student predicts the sample (madp.training.config)
        return MADP(madp_config(cfg.preset, **({"prediction": "sample"} if cfg.distill else {})))
    from madp.models.lpac import LPAC  # torch_geometric: seconds to import, so only for LPAC-K3

    return LPAC(lpac_config(cfg.preset, edge_weight=cfg.edge_weight))


# --- the run -------------------------------------------------------------------------------------
class Trainer:
    def __init__(self, cfg: TrainConfig, resume: bool = False, progress: bool = True):
        self.cfg = cfg
        self.rank, self.world, self.device = setup_distributed()
        self.ddp = dist.is_initialized()  # torchrun with several ranks, or a group the caller made
        self.is_main = self.rank == 0
        self.progress = progress and self.is_main
        self.out = Path(cfg.out)
        self.init_meta: dict = {}
        self.manifests = [open_dataset(d) for d in cfg.datasets]
        self.manifest = self.manifests[0]
        self.max_robots = max(m.num_robots for m in self.manifests)  # N of the largest swarms trained on
        if self.manifest.action_stats is None:
            raise InputError(f"{cfg.data}/manifest.json: no action statistics (regenerate with madp datagen)")
        for i, (d, m) in enumerate(zip(cfg.datasets, self.manifests)):
            check_shards(d, m, ("train", "val") if i == 0 else ("train",))  # one read each, before use
        if cfg.comm_dropout:  # the neighbour channels are redrawn with the model's r_c: the data's must be it
            for d, m in zip(cfg.datasets, self.manifests):
                r_c = m.params.get("params", {}).get("comm_radius_m")
                if r_c != madp_config(cfg.preset).comm_radius_m:
                    raise InputError(f"{d}/manifest.json: comm_radius_m = {r_c}, but --comm-dropout redraws the "
                                     f"neighbour channels with the model's {madp_config(cfg.preset).comm_radius_m}")
        for d, m in zip(cfg.more_data, self.manifests[1:]):
            sim, sim0 = m.params.get("params", {}), self.manifest.params.get("params", {})
            if sim.get("world_size") != sim0.get("world_size"):  # swarm sizes may differ (batched by size)
                raise InputError(f"{d}/manifest.json: world_size = {sim.get('world_size')}, but {cfg.data} has "
                                 f"{sim0.get('world_size')}; datasets trained together must share it")
        # Weights that stop receiving gradient decay towards zero (L2 weight decay) and turn
        # subnormal; on CPU every op on them then runs ~10x slower (LPAC-K3 fell from 106 to 14
        # samples/s as 35% of its weights went subnormal). Flushing them to zero costs nothing.
        torch.set_flush_denormal(True)
        torch.manual_seed(cfg.seed)
        self.raw = build_model(cfg, self.manifest.num_robots).to(self.device)
        stats = self.manifest.action_stats
        self.teacher, self.distill_meta = (None, {}) if not cfg.distill else \
            load_teacher(Path(cfg.distill), self.raw, cfg.distill_steps, self.device)
        if cfg.init:  # on resume the checkpoint holds the weights; the record of the start stays
            self._init_from(Path(cfg.init), load_weights=not resume)
        elif self.teacher is not None and not resume:  # a student starts as its teacher
            self.raw.load_state_dict(self.teacher.state_dict())
        if self.teacher is not None:  # the student's samples are the teacher's, in its normalisation
            self.raw.set_action_stats(self.teacher.action_mean, self.teacher.action_std)
        else:
            self.raw.set_action_stats(torch.tensor(stats.mean, dtype=torch.float32),
                                      torch.tensor(stats.std, dtype=torch.float32).clamp_min(1e-6))
        self.opt = make_optimizer(cfg, self.raw.parameters())
        self.ema = EMA(self.raw, cfg.ema_decay) if cfg.model == "madp" else None
        self.model = self.raw
        if self.ddp:
            self.model = torch.nn.parallel.DistributedDataParallel(
                self.raw, device_ids=[self.device.index] if self.device.type == "cuda" else None)
        if cfg.compile:  # the training forward only; validation and checkpoints use the plain module
            self.model = torch.compile(self.model)
        self.train_data = ShardStream(cfg.datasets, self.manifests, "train", cfg.seed, cfg.batch_size, cfg.buffer_size,
                                      self.rank, self.world, augment=cfg.augment, weights=cfg.weights)
        self._refuse_empty_epochs()
        self.step, self.epoch, self.batches_done = 0, 0, 0
        self.best_val, self.bad_epochs = math.inf, 0
        self.seen_ids: set = set()  # (episode, step) of trained samples, for the DDP check
        ckpt = self.out / "checkpoints" / "latest"
        if self.is_main and (self.out / "checkpoints").is_dir():
            recover_checkpoints(self.out / "checkpoints")
        if resume:
            self._load(ckpt)
        elif self.is_main and ckpt.exists():
            raise InputError(f"{self.out}: a run is already there; pass --resume to continue it or choose another --out")
        elif self.is_main:
            (self.out / "metrics.jsonl").unlink(missing_ok=True)  # a fresh start: lines of a run killed before its first checkpoint
        if self.is_main:
            self.out.mkdir(parents=True, exist_ok=True)
            self._write_config()
        self.tb = self._tensorboard() if self.is_main else None

    def _refuse_empty_epochs(self) -> None:
        """A run in which some epoch would do no step is a mistake in the flags: refuse it."""
        cfg = self.cfg
        for e in range(cfg.epochs):
            if self._epoch_batches(e) > 0:
                continue
            streams = self.world * max(cfg.num_workers, 1)
            _, per = self.train_data._plan(e, streams)
            raise SettingError("batch_size", message=f"batch_size {cfg.batch_size}: each of the {streams} training "
                               f"stream(s) (ranks x loader workers) gets {per} samples in epoch {e}, less than one batch, "
                               "so no step would run; use a smaller batch size or fewer workers")

    def _init_from(self, path: Path, load_weights: bool = True) -> None:
        """Warm start: the weights of a policy file of the same model (optimizer and counters fresh)."""
        from madp.policies.checkpoint import load_policy

        model, meta = load_policy(path)
        if meta["kind"] != self.cfg.model or meta["config"] != self.raw.config.to_dict():
            raise InputError(f"{path}: init needs a {self.cfg.model} checkpoint of the {self.cfg.preset} preset "
                             f"(it is a {meta['kind']} with another config)")
        if load_weights:
            self.raw.load_state_dict(model.state_dict())
        self.init_meta = {"path": str(path), "sha256": sha256_file(path), "step": meta.get("step")}

    # ---- bookkeeping
    def _meta(self, val_loss: float | None) -> dict:
        st = self.manifest.action_stats.to_dict() if self.teacher is None else teacher_action_stats(self.teacher)
        return {"action_stats": st, "train_config": self.cfg.to_dict(), "step": self.step,
                "epoch": self.epoch, "val_loss": val_loss, "dataset": {
                    "root": str(self.cfg.data), "num_samples": self.manifest.num_samples,
                    "created_by": self.manifest.created_by, "params": self.manifest.params,
                    "more": [{"root": d, "weight": w, "num_samples": m.num_samples, "created_by": m.created_by}
                             for d, w, m in zip(self.cfg.more_data, self.cfg.weights[1:], self.manifests[1:])]},
                "code_version": self.manifest.code_version, **({"init": self.init_meta} if self.init_meta else {}),
                **({"distill": self.distill_meta} if self.distill_meta else {})}

    def _write_config(self) -> None:
        d = {"train": self.cfg.to_dict(), "model": self.raw.config.to_dict(),
             "num_parameters": sum(p.numel() for p in self.raw.parameters()),
             "world_size": self.world, "device": str(self.device), **self._meta(None)}
        write_text_atomic(self.out / "config.json", json.dumps(d, indent=1) + "\n")

    def _tensorboard(self):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # tensorboard not installed: JSONL only
            return None
        return SummaryWriter(str(self.out / "tb"))

    def _log(self, record: dict) -> None:
        if not self.is_main:
            return
        try:
            with open(self.out / "metrics.jsonl", "a") as f:
                f.write(json.dumps(record) + "\n")
        except OSError as e:  # a full disk: say which file
            raise named(e, self.out / "metrics.jsonl") from None
        if self.tb is not None:
            for k, v in record.items():
                if isinstance(v, float) and k not in ("time",):
                    self.tb.add_scalar(k, v, self.step)

    def _state(self) -> dict:
        return {"optimizer": self.opt.state_dict(), "ema": self.ema.state_dict() if self.ema else {},
                "step": self.step, "epoch": self.epoch, "batches_done": self.batches_done,
                "best_val": self.best_val, "bad_epochs": self.bad_epochs, "torch_rng": torch.get_rng_state()}

    def _save(self, name: str, val_loss: float | None = None) -> None:
        if not self.is_main:
            return
        policy = self.raw
        if self.ema is not None:
            policy = build_model(self.cfg, self.manifest.num_robots).to(self.device)
            policy.load_state_dict(self.raw.state_dict())
            self.ema.copy_to(policy)
        save_checkpoint(self.out / "checkpoints" / name, self.raw, policy, self.cfg.model, self._meta(val_loss),
                        self._state())

    def _load(self, ckpt: Path) -> None:
        state = load_checkpoint_state(ckpt, self.raw, self.device)
        where = ckpt / "state.pt"
        try:
            self.opt.load_state_dict(state["optimizer"])
            for group in self.opt.param_groups:  # the optimizer's moments must have the weights' shapes
                for p in group["params"]:
                    for k, v in self.opt.state.get(p, {}).items():
                        if isinstance(v, torch.Tensor) and v.dim() and v.shape != p.shape:
                            raise ValueError(f"optimizer '{k}' of shape {list(v.shape)} for a weight of shape {list(p.shape)}")
            if self.ema is not None:
                shadow = state["ema"].get("shadow", {})
                for k, v in self.ema.shadow.items():
                    if not isinstance(shadow.get(k), torch.Tensor) or shadow[k].shape != v.shape:
                        raise ValueError(f"EMA weight '{k}' is missing or of another shape")
                self.ema.load_state_dict(state["ema"])
            torch.set_rng_state(state["torch_rng"].cpu())
        except (ValueError, KeyError, TypeError, AttributeError, RuntimeError) as e:
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise InputError(f"{where}: does not fit this run's model and optimizer ({msg})") from None
        self.step, self.epoch = int(state["step"]), int(state["epoch"])
        self.batches_done = int(state["batches_done"])
        self.best_val, self.bad_epochs = float(state["best_val"]), int(state["bad_epochs"])
        # The log may run ahead of the checkpoint after a crash: drop lines past its step, and a
        # line torn by a kill.
        log = self.out / "metrics.jsonl"
        if self.is_main and log.exists():
            keep = []
            for ln in log.read_text().splitlines():
                try:
                    d = json.loads(ln)
                except json.JSONDecodeError:
                    continue
                if d.get("step", 0) <= self.step and not ("val_loss" in d and d["epoch"] >= self.epoch):
                    keep.append(ln)
            write_text_atomic(log, "".join(k + "\n" for k in keep))

    def _check_sync(self) -> None:
        """All ranks hold the same weights; log their checksums, samples seen and any overlap."""
        flat = torch.cat([p.detach().double().flatten().cpu() for p in self.raw.parameters()])
        checksum = float((flat * torch.arange(1, flat.numel() + 1, dtype=torch.float64).sin()).sum())
        gathered: list = [None] * self.world
        dist.all_gather_object(gathered, (checksum, sorted(self.seen_ids)))
        sets = [set(map(tuple, g[1])) for g in gathered]
        overlap = len(set.intersection(*sets)) if len(sets) > 1 else 0
        self._log({"step": self.step, "ddp_param_checksums": [g[0] for g in gathered],
                   "ddp_samples_per_rank": [len(x) for x in sets], "ddp_overlap": overlap})
        dist.barrier()

    # ---- validation
    def _val_batches(self):
        """Batches of the first ``val_samples`` of the first dataset's val split, in a fixed order."""
        stream = ShardStream(self.cfg.data, self.manifest, "val", seed=12345, batch_size=1, buffer_size=1)
        n = 0
        for batch in DataLoader(stream, batch_size=self.cfg.batch_size, num_workers=0):
            yield batch
            n += batch["obs"].shape[0]
            if n >= self.cfg.val_samples:
                return

    @torch.no_grad()
    def validate(self) -> float:
        """Mean loss over the first ``val_samples`` of the val split, with fixed noise (EMA weights)."""
        self.raw.eval()
        ctx = self.ema.average_parameters(self.raw) if self.ema is not None else nullcontext()
        total, n = 0.0, 0
        with ctx:
            for i, batch in enumerate(self._val_batches()):
                g = step_generator(self.cfg.seed, i, self.device, stream=VAL_STREAM)
                draws = None
                if self.cfg.model == "madp":
                    k, noise = step_noise(self.raw, g, batch, 1)
                    draws = (k[0], noise[0])
                links = step_links(self.cfg, i, self.device, batch, 1, stream=VAL_LINKS_STREAM)
                b = batch["obs"].shape[0]
                total += float(batch_loss(self.raw, self.raw, batch, self.cfg, draws, self.device, self.teacher,
                                          None if links is None else links[0])) * b
                n += b
        self.raw.train()
        return total / max(n, 1)

    @torch.no_grad()
    def dead_units(self) -> dict:
        """LPAC-K3's health on the validation samples: per graph layer, the fraction of ReLU units
        that fire for no robot (``dead_units``) and of TAGConv weights below 1e-6 (``tiny_weights``)."""
        self.raw.eval()
        fired = None
        for batch in self._val_batches():
            f = self.raw.units_fired(batch["obs"].to(self.device), batch["pos_m"].to(self.device))
            fired = f if fired is None else fired | f
        self.raw.train()
        tiny = [float(torch.cat([p.detach().abs().flatten() for p in conv.parameters() if p.dim() > 1]).lt(1e-6)
                      .float().mean()) for conv in self.raw.gnn]
        return {"dead_units": [round(float(x), 4) for x in (~fired).float().mean(1)],
                "tiny_weights": [round(x, 4) for x in tiny]}

    # ---- training
    def _epoch_batches(self, epoch: int) -> int:
        """Micro-batches this rank trains on in ``epoch``: whole optimizer steps of ``grad_accum`` each."""
        cfg = self.cfg
        batches = self.train_data.samples_per_stream(cfg.num_workers, epoch) * max(cfg.num_workers, 1) // cfg.batch_size
        steps = batches // cfg.grad_accum
        steps = min(steps, cfg.max_steps_per_epoch) if cfg.max_steps_per_epoch else steps
        return steps * cfg.grad_accum

    def planned_steps(self) -> int:
        """Updates in the whole run if it is not stopped early (the horizon of the lr schedule)."""
        return sum(self._epoch_batches(e) for e in range(self.cfg.epochs)) // self.cfg.grad_accum

    def _stop_reason(self, t_fit: float) -> str | None:
        """Why the run stops at this step (``stop_after_steps``, ``stop_after_minutes`` counted from
        :meth:`fit`'s start in this process), or None. Under DDP rank 0's clock decides for all."""
        cfg = self.cfg
        if cfg.stop_after_steps and self.step >= cfg.stop_after_steps:
            return "stop_after_steps"
        if not cfg.stop_after_minutes:
            return None
        late = time.monotonic() - t_fit >= 60.0 * cfg.stop_after_minutes
        if self.ddp:
            flag = torch.tensor(float(late), device=self.device)
            dist.broadcast(flag, src=0)
            late = bool(flag)
        return "stop_after_minutes" if late else None

    def fit(self) -> dict:
        cfg = self.cfg
        stop_reason = "epochs"
        t_fit = time.monotonic()
        total_steps = self.planned_steps() if cfg.lr_schedule != "constant" else 0
        if cfg.model == "lpac" and self.step == 0 and self.is_main:
            self._log({"step": 0, "epoch": 0, **self.dead_units()})  # the initial health, to compare with
        while self.epoch < cfg.epochs:
            batches = self._epoch_batches(self.epoch)
            # Round-robin over workers: batch b comes from worker b % W, its (b // W)-th batch.
            w = max(cfg.num_workers, 1)
            accum = cfg.grad_accum
            unit = math.lcm(w, accum)  # checkpoints fall where a worker round and an optimizer step both end
            done_per_worker = -(-self.batches_done // w)  # workers advance in lockstep (equal counts)
            if self.batches_done % unit:
                raise RuntimeError("checkpoint position is not at a worker round and optimizer step boundary")
            self.train_data.set_position(StreamPosition(self.epoch, done_per_worker * cfg.batch_size))
            loader = DataLoader(self.train_data, batch_size=cfg.batch_size, num_workers=cfg.num_workers,
                                collate_fn=collate_swarms,
                                pin_memory=self.device.type == "cuda", persistent_workers=False,
                                worker_init_fn=functools.partial(_loader_worker_init, os.getpid()))
            bar = EpochBar(self.progress, batches, self.batches_done, f"epoch {self.epoch + 1}/{cfg.epochs}")
            t_last, seen, loss_sum = time.perf_counter(), 0, 0.0
            for batch in loader:
                if self.batches_done >= batches:
                    break
                micro = self.batches_done % accum
                if micro == 0:  # a new optimizer step
                    g = step_generator(cfg.seed, self.step, self.device, stream=TRAIN_STREAM)
                    step_draws = step_noise(self.raw, g, batch, self.world * accum, self.max_robots) \
                        if cfg.model == "madp" else None
                    links = step_links(cfg, self.step, self.device, batch, self.world * accum, self.max_robots)
                    self.opt.zero_grad(set_to_none=True)
                    loss_sum = 0.0
                part = self.rank * accum + micro
                draws = None if step_draws is None else (step_draws[0][part], step_draws[1][part])
                last = micro == accum - 1
                sync = self.model.no_sync() if self.ddp and not last else nullcontext()
                with sync:  # DDP averages the gradients over ranks at the step's last micro-batch
                    loss = batch_loss(self.model, self.raw, batch, cfg, draws, self.device, self.teacher,
                                      None if links is None else links[part])
                    (loss / accum).backward()
                self.batches_done += 1
                seen += batch["obs"].shape[0] * self.world
                if self.ddp:
                    self.seen_ids.update(zip(batch["episode_id"].tolist(), batch["step"].tolist()))
                loss_sum += float(loss.detach())
                if not last:
                    continue
                for group in self.opt.param_groups:
                    group["lr"] = learning_rate(cfg, self.step, total_steps)
                if cfg.grad_clip:
                    torch.nn.utils.clip_grad_norm_(self.raw.parameters(), cfg.grad_clip)
                self.opt.step()
                if self.ema is not None:
                    self.ema.update(self.raw)
                self.step += 1
                loss_v = loss_sum / accum
                if not math.isfinite(loss_v):
                    raise FloatingPointError(f"training loss became {loss_v} at step {self.step}")
                stop = self._stop_reason(t_fit) if self.batches_done % unit == 0 else None
                if self.step % cfg.log_every == 0 or self.batches_done == batches or stop:  # a stopped run logs its last step
                    now = time.perf_counter()
                    rate = seen / max(now - t_last, 1e-9)
                    self._log({"step": self.step, "epoch": self.epoch, "loss": loss_v,
                               "lr": self.opt.param_groups[0]["lr"], "samples_per_s": rate})
                    t_last, seen = now, 0
                    bar.update(self.batches_done, loss_v, rate)
                if stop or self.batches_done % (cfg.checkpoint_every * unit) == 0:
                    self._save("latest")
                if stop:
                    bar.close()
                    return {"stopped": stop, "step": self.step}
            bar.close()
            val = self.validate()
            improved = val < self.best_val - cfg.min_delta
            self.best_val = min(self.best_val, val) if improved else self.best_val
            self.bad_epochs = 0 if improved else self.bad_epochs + 1
            self.epoch += 1
            self.batches_done = 0
            health = self.dead_units() if self.cfg.model == "lpac" and self.is_main else {}
            self._log({"epoch": self.epoch - 1, "step": self.step, "val_loss": val, "best_val_loss": self.best_val,
                       "improved": improved, **health})
            if self.progress:
                print(f"epoch {self.epoch}: val loss {val:.5f} (best {self.best_val:.5f})")
            if improved:
                self._save("best", val)
            self._save("latest", val)
            if self.bad_epochs >= cfg.patience:
                stop_reason = f"early stop: no improvement > {cfg.min_delta} for {cfg.patience} epochs"
                break
        if self.ddp:
            self._check_sync()
        return {"stopped": stop_reason, "step": self.step, "epoch": self.epoch, "best_val_loss": self.best_val}


def _loader_worker_init(parent_pid: int, worker_id: int) -> None:
    """DataLoader workers end with the training process at once (the kernel's parent-death signal),
    not only at torch's 5 s watchdog check, which a busy worker reaches late."""
    die_with_parent(parent_pid)


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> dict:
    """Train (or resume) the run ``cfg.out``; rank 0 holds the run directory's lock throughout."""
    lock = locked_dir(cfg.out) if int(os.environ.get("RANK", "0")) == 0 else nullcontext()
    try:
        with lock:
            return Trainer(cfg, resume=resume, progress=progress).fit()
    finally:
        if dist.is_initialized():
            dist.destroy_process_group()
