"""The datagen plan: independent, deterministic shard tasks.

A dataset of N samples is split 70/20/10 into train/val/test by *sample count*
(n_val = round(0.2 N), n_test = round(0.1 N), n_train = the rest). Each split is cut into shards of
``samples_per_shard`` samples (the last one smaller). A shard task simulates fresh episodes — each
its own random scenario and clairvoyant rollout — until it holds exactly its share; the last
episode of a shard is cut where the shard is full, so episodes never straddle shards or splits.

Everything a task produces is a function of (dataset seed, split, shard index) and the parameters,
so tasks can run in any order, on any number of workers or machines, and a resumed run redoes only
the missing ones. Scenario seeds live in [0, 2⁶²); evaluation suites use [2⁶², 2⁶³), so evaluation
never meets a training scenario.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from madp.errors import SettingError
from madp.sim import SimParams
from madp.sim.launch import TRAINING_LAUNCHES

SPLITS = ("train", "val", "test")
SPLIT_FRACTIONS = {"val": 0.2, "test": 0.1}
DATASET_SEED_BITS = 62
#: Shards one split may have: episode ids are split·10⁹ + shard·10⁴ + episode (:func:`episode_id`).
MAX_SHARDS_PER_SPLIT = 100_000


@dataclass(frozen=True)
class DatagenConfig:
    """What to generate. ``params`` are the simulator's; the rest shape the dataset."""

    num_samples: int
    seed: int = 0
    format: str = "mcap"
    samples_per_shard: int = 512
    record_every: int = 5  # record every 5th simulation step (SPEC §3)
    max_steps: int = 2100  # an episode that has not converged by then ends
    params: SimParams = field(default_factory=SimParams)
    launch: str = "uniform"
    """Where each episode's swarm starts: ``uniform`` (anywhere, the default) or ``packed`` (boxes,
    bands and clusters of a training distribution: :func:`madp.sim.launch.draw_launch`)."""
    policy: dict = field(default_factory=dict)
    """Empty: the expert drives (the default). Otherwise the learned policy that drives, for expert
    relabelling (DAgger): ``{"path", "sha256", "kind", "beta", "parent"}`` and, for MADP choosing
    among its samples, ``"select"`` — the checkpoint, its sha256, ``madp`` (decentralized, the default
    sampler) or ``lpac``, the probability ``beta`` that a step executes the expert's action instead, the
    rule (absent: one sample per robot), and the dataset the policy was trained on (from the
    checkpoint's metadata). Episodes then run exactly ``max_steps`` steps (the expert's labels never
    end them), so late-episode states are recorded at the rate a rollout of that length visits them."""
    dart_sigma_mps: float = 0.0
    """DART noise (expert rollouts only; 0: off). Above 0, the swarm executes the expert's action plus
    Gaussian noise N(0, σ²) m/s per robot and axis, clipped to u_max, drawn from a stream of the
    episode's scenario seed (:func:`madp.datagen.episodes.dart_driver`); every sample keeps the
    expert's noiseless label at the state the noisy swarm reached."""

    def __post_init__(self) -> None:
        if self.num_samples < 1:
            raise SettingError("num_samples", f"expected a positive number of samples, got {self.num_samples}")
        if self.format not in ("mcap", "parquet"):
            raise SettingError("format", f"expected mcap or parquet, got {self.format!r}")
        if not 0 <= self.seed < 2**32:
            raise SettingError("seed", f"expected an integer in [0, 2^32), got {self.seed}")
        if self.samples_per_shard < 1 or self.record_every < 1 or self.max_steps < 1:
            raise SettingError("samples_per_shard", message="samples_per_shard, record_every and max_steps must be positive")
        shards = max(-(-n // self.samples_per_shard) for n in split_sizes(self.num_samples).values())
        if shards > MAX_SHARDS_PER_SPLIT:  # checked before a plan of that size is ever made
            raise SettingError("num_samples", f"{self.num_samples} samples make {shards} shards of {self.samples_per_shard} in one split, "
                             f"more than the {MAX_SHARDS_PER_SPLIT} a dataset's episode ids can number; "
                             "lower --n or raise --samples-per-shard")
        self.params.check_fits("num_robots/num_features/world_size")
        if self.launch not in TRAINING_LAUNCHES:
            raise SettingError("launch", f"expected one of {', '.join(TRAINING_LAUNCHES)}, got {self.launch!r}")
        if self.policy and not 0.0 <= float(self.policy.get("beta", -1)) <= 1.0:
            raise SettingError("beta", f"expected a probability in [0, 1], got {self.policy.get('beta')}")
        if not (math.isfinite(self.dart_sigma_mps) and self.dart_sigma_mps >= 0):
            raise SettingError("dart_sigma_mps", f"expected a finite speed >= 0 m/s, got {self.dart_sigma_mps}")
        if self.dart_sigma_mps and self.policy:
            raise SettingError("dart_sigma_mps", "only for expert rollouts; with --policy the learner drives")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["params"] = self.params.to_dict()
        if not self.policy:  # expert datasets keep the plan.json of before relabelling existed
            del d["policy"]
        if self.launch == "uniform":  # and uniform launches that of before --launch existed
            del d["launch"]
        if not self.dart_sigma_mps:  # and noiseless ones that of before --dart-sigma existed
            del d["dart_sigma_mps"]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "DatagenConfig":
        d = dict(d)
        d["params"] = SimParams.from_dict(d["params"])
        return cls(**d)

    def command(self) -> str:
        """A canonical command line that reproduces this dataset (no worker count: it is irrelevant)."""
        p, dflt = self.params, SimParams()
        parts = [f"madp datagen --n {self.num_samples} --seed {self.seed} --format {self.format}"]
        if p.num_robots != dflt.num_robots:
            parts.append(f"--num-robots {p.num_robots}")
        if p.num_features != dflt.num_features:
            parts.append(f"--num-features {p.num_features}")
        if p.sigma_range_m != dflt.sigma_range_m:
            parts.append(f"--sigma {p.sigma_range_m[0]:g} {p.sigma_range_m[1]:g}")
        if p.world_size != dflt.world_size:
            parts.append(f"--world-size {p.world_size}")
        if self.samples_per_shard != 512:
            parts.append(f"--samples-per-shard {self.samples_per_shard}")
        if self.launch != "uniform":
            parts.append(f"--launch {self.launch}")
        if self.policy:
            parts.append(f"--policy {self.policy['path']} --beta {self.policy['beta']:g} --max-steps {self.max_steps}")
            if "select" in self.policy:
                parts.append(f"--select {self.policy['select']}")
        elif self.max_steps != 2100:
            parts.append(f"--max-steps {self.max_steps}")
        if self.dart_sigma_mps:
            parts.append(f"--dart-sigma {self.dart_sigma_mps!r}")
        return " ".join(parts)


@dataclass(frozen=True)
class ShardTask:
    split: str
    index: int  # within the split
    num_samples: int

    @property
    def name(self) -> str:
        return f"{self.split}-{self.index:05d}"

    def file(self, fmt: str) -> str:
        """Path of the shard relative to the dataset root."""
        return f"{self.split}/shard-{self.index:05d}.{fmt}"


def split_sizes(num_samples: int) -> dict[str, int]:
    val = int(round(SPLIT_FRACTIONS["val"] * num_samples))
    test = int(round(SPLIT_FRACTIONS["test"] * num_samples))
    return {"train": num_samples - val - test, "val": val, "test": test}


def make_plan(cfg: DatagenConfig) -> list[ShardTask]:
    """All shard tasks in a fixed global order: train shards, then val, then test."""
    tasks = []
    for split, n in split_sizes(cfg.num_samples).items():
        full, rest = divmod(n, cfg.samples_per_shard)
        tasks += [ShardTask(split, i, cfg.samples_per_shard) for i in range(full)]
        if rest:
            tasks.append(ShardTask(split, full, rest))
    return tasks


def scenario_seed(dataset_seed: int, split: str, shard: int, episode: int) -> int:
    """The scenario seed of episode ``episode`` of a shard: a hash into [0, 2⁶²)."""
    a, b = np.random.SeedSequence([dataset_seed, SPLITS.index(split), shard, episode]).generate_state(2, np.uint32)
    return int(((int(a) << 32) | int(b)) & ((1 << DATASET_SEED_BITS) - 1))


def episode_id(split: str, shard: int, episode: int) -> int:
    """Readable, dataset-unique episode id: split·10⁹ + shard·10⁴ + episode."""
    return SPLITS.index(split) * 10**9 + shard * 10**4 + episode
