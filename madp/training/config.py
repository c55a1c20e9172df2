"""Training configuration and its two presets.

``paper`` (SPEC §4): MADP with AdamW, lr 8.5e-5, weight decay 2.1e-12, batch 196, up to 1000 epochs,
early stop after 500 epochs without a 1e-4 improvement of the validation loss; LPAC-K3 with Adam,
lr 1e-4, weight decay 1e-3 (the library's settings) — but *decoupled* (AdamW): with Adam's coupled L2
decay every graph unit whose ReLU stopped firing had its weights driven to zero within a few hundred
steps, and 20–60% of LPAC-K3's units were dead (docs/reports/2026-12-03-relabelling.md); same batch and stopping rule.

``cpu``: the small models of :func:`madp.models.madp_config` / ``lpac_config`` ("cpu" preset),
batch 32, a higher learning rate (small models tolerate it and must learn within ~2 hours on two
cores) with 200 warm-up steps and a cosine decay to 5% over the planned steps (epochs × steps per
epoch), so a fixed time budget ends on small, low-noise updates; 30 epochs with patience 5. EMA decay 0.999 for MADP in both.

``distill`` (MADP, either preset): instead of the DDPM loss, the student learns to do in one step what
the teacher policy's DPM-Solver++(2M) does in ``distill_steps``: from the same pure noise U_K and
state, its predicted sample is fitted to the teacher's (:meth:`madp.models.MADP.one_step_loss`). It
starts from the teacher's weights (unless ``init`` names others) and keeps the teacher's action
statistics; it samples with ``--sampling-steps 1``.

``comm_dropout`` P (MADP's DDPM training, either preset; default 0: off): each training sample, with
probability P, loses links between its robots, as over a lossy network (:mod:`.comm_dropout`);
validation drops links the same way, with its own fixed draws, so the validation loss (and the
``best`` checkpoint) measures the objective trained.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from madp.errors import SettingError


@dataclass(frozen=True)
class TrainConfig:
    model: str = "madp"  # madp | lpac
    preset: str = "cpu"  # paper | cpu
    data: str = "data"  # the first dataset: its action statistics normalise, its val split validates
    more_data: tuple[str, ...] = ()  # further datasets mixed into training (DAgger rounds)
    data_weights: tuple[float, ...] = ()  # per dataset (data, *more_data), shards per epoch x weight; () = all 1
    out: str = "runs/madp-cpu"
    epochs: int = 30
    batch_size: int = 32
    lr: float = 3e-4
    lr_schedule: str = "constant"  # constant | cosine (to 5% of lr at the last planned step)
    warmup_steps: int = 0  # linear warm-up of the learning rate over the first steps
    weight_decay: float = 1e-6
    optimizer: str = "adamw"  # adamw | adam
    grad_clip: float = 1.0
    ema_decay: float = 0.999
    patience: int = 5  # epochs without improvement before stopping
    min_delta: float = 1e-4
    seed: int = 0
    num_workers: int = 1  # DataLoader worker processes per rank
    grad_accum: int = 1  # micro-batches per optimizer step (gradients averaged, as DDP averages over ranks)
    buffer_size: int = 512  # shuffle buffer (samples) per stream
    val_samples: int = 1024  # validation uses the first samples of the val split (fixed order)
    checkpoint_every: int = 200  # steps between 'latest' checkpoints (and at every epoch end)
    log_every: int = 10
    max_steps_per_epoch: int = 0  # 0: the whole split
    stop_after_steps: int = 0  # stop (after checkpointing) once this many steps are done; 0: never
    stop_after_minutes: float = 0.0  # stop (after checkpointing) at the first step after this many minutes of fit(); 0: never
    augment: str = "none"  # none | d4 (training samples only; see madp.models.symmetry)
    init: str = ""  # start from this policy.safetensors' weights (same model and preset), e.g. for DAgger rounds
    edge_weight: str = "binary"  # LPAC-K3's communication graph: binary (the library's) | gaussian
    compile: bool = False  # MADP through torch.compile (inductor): faster steps after a compile at the start
    distill: str = ""  # MADP: distil this policy file's sampler into one step (a model that predicts the sample)
    distill_steps: int = 3  # the teacher's DPM-Solver++(2M) steps S that the student learns to do in one
    comm_dropout: float = 0.0  # MADP: a sample's chance of losing links (madp.training.comm_dropout); 0: none

    def __post_init__(self) -> None:
        if self.model not in ("madp", "lpac"):
            raise SettingError("model", f"expected madp or lpac, got {self.model!r}")
        if self.preset not in ("paper", "cpu"):
            raise SettingError("preset", f"expected paper or cpu, got {self.preset!r}")
        for name in ("epochs", "batch_size", "checkpoint_every", "val_samples", "log_every", "buffer_size", "patience",
                     "grad_accum"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise SettingError(name, f"expected a positive integer, got {getattr(self, name)}")
        for name in ("max_steps_per_epoch", "num_workers", "stop_after_steps", "seed", "warmup_steps"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 0:
                raise SettingError(name, f"expected a non-negative integer, got {getattr(self, name)}")
        if not 0.0 <= self.ema_decay < 1.0 or not math.isfinite(self.min_delta) or self.min_delta < 0 \
                or not self.grad_clip >= 0 or not self.weight_decay >= 0:
            raise SettingError("ema_decay", message="ema_decay must lie in [0, 1); min_delta, grad_clip and weight_decay "
                                                     "must be >= 0")
        if self.lr_schedule not in ("constant", "cosine"):
            raise SettingError("lr_schedule", f"expected constant or cosine, got {self.lr_schedule!r}")
        if self.augment not in ("none", "d4"):
            raise SettingError("augment", f"expected none or d4, got {self.augment!r}")
        object.__setattr__(self, "more_data", tuple(str(d) for d in self.more_data))
        object.__setattr__(self, "data_weights", tuple(float(w) for w in self.data_weights))
        if self.data_weights and (len(self.data_weights) != 1 + len(self.more_data)
                                  or not all(math.isfinite(w) and w > 0 for w in self.data_weights)):
            raise SettingError("data_weights", f"expected {1 + len(self.more_data)} positive numbers (one per dataset), "
                                               f"got {list(self.data_weights)}")
        if self.compile and self.model != "madp":
            raise SettingError("compile", message="compile: only MADP compiles (torch_geometric's scatter in LPAC-K3 does not trace)")
        if self.distill and self.model != "madp":
            raise SettingError("distill", message="distill: only MADP distils its sampler (LPAC-K3 samples nothing)")
        if not isinstance(self.distill_steps, int) or self.distill_steps < 1:
            raise SettingError("distill_steps", f"expected a positive integer, got {self.distill_steps}")
        if self.edge_weight not in ("binary", "gaussian"):
            raise SettingError("edge_weight", f"expected binary or gaussian, got {self.edge_weight!r}")
        if not (math.isfinite(self.stop_after_minutes) and self.stop_after_minutes >= 0):
            raise SettingError("stop_after_minutes", f"expected a non-negative number, got {self.stop_after_minutes}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise SettingError("lr", f"expected a positive learning rate, got {self.lr}")
        if isinstance(self.comm_dropout, bool) or not isinstance(self.comm_dropout, (int, float)) \
                or not 0.0 <= self.comm_dropout <= 1.0:
            raise SettingError("comm_dropout", f"expected a probability in [0, 1], got {self.comm_dropout!r}")
        object.__setattr__(self, "comm_dropout", float(self.comm_dropout))
        if self.comm_dropout and (self.model != "madp" or self.distill):
            raise SettingError("comm_dropout", message="comm_dropout: only MADP's DDPM training drops links (not "
                                                        "LPAC-K3, not a distillation)")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def datasets(self) -> list[str]:
        return [self.data, *self.more_data]

    @property
    def weights(self) -> list[float]:
        return list(self.data_weights) or [1.0] * len(self.datasets)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


PRESET_DEFAULTS = {
    ("madp", "paper"): dict(epochs=1000, batch_size=196, lr=8.5e-5, weight_decay=2.1e-12, optimizer="adamw",
                            patience=500, min_delta=1e-4),
    ("lpac", "paper"): dict(epochs=1000, batch_size=196, lr=1e-4, weight_decay=1e-3, optimizer="adamw",
                            patience=500, min_delta=1e-4),
    ("madp", "cpu"): dict(epochs=30, batch_size=32, lr=3e-4, weight_decay=1e-6, optimizer="adamw",
                          patience=5, min_delta=1e-4, lr_schedule="cosine", warmup_steps=200),
    ("lpac", "cpu"): dict(epochs=30, batch_size=32, lr=3e-4, weight_decay=1e-3, optimizer="adamw",
                          patience=5, min_delta=1e-4, lr_schedule="cosine", warmup_steps=200),
}


def parse_weights(text: str) -> tuple[float, ...]:
    """``"1,0.5"`` -> ``(1.0, 0.5)``: one weight per dataset (``--data-weights``)."""
    try:
        return tuple(float(w) for w in text.split(","))
    except ValueError:
        raise SettingError("data_weights", f"expected comma-separated numbers, got {text!r}") from None


def resolve(model: str, preset: str, **overrides) -> TrainConfig:
    """The preset's defaults for ``model``, then any explicit overrides (None means 'keep')."""
    base = TrainConfig(model=model, preset=preset)
    if (model, preset) not in PRESET_DEFAULTS:
        base.__post_init__()  # raises the one-line error
    cfg = replace(base, **PRESET_DEFAULTS[(model, preset)], out=f"runs/{model}-{preset}")
    return replace(cfg, **{k: v for k, v in overrides.items() if v is not None})


def learning_rate(cfg: TrainConfig, step: int, total_steps: int) -> float:
    """The learning rate of update ``step`` (0-based) out of ``total_steps`` planned updates.

    A pure function of the step, so a resumed run follows exactly the same schedule."""
    lr = cfg.lr
    if cfg.warmup_steps:
        lr *= min(1.0, (step + 1) / cfg.warmup_steps)
    if cfg.lr_schedule == "cosine":
        frac = min(step / max(total_steps, 1), 1.0)
        lr *= 0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * frac))
    return lr
