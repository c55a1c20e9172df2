"""Evaluation suites: named, documented, seeded sets of environments (the paper's suites and madp's own).

| suite   | groups                                          | environments                          |
|---------|-------------------------------------------------|---------------------------------------|
| uniform | uniform                                         | num_envs random maps, N = F = 32,     |
|         |                                                 | σ ∈ [40, 60], uniform launch          |
| sigma   | sigma_30-40, sigma_20-30, sigma_10-20, sigma_5-10 | num_envs per σ range (out of training) |
| cities  | one per city file (name from the file)          | the 1024 m square with most signals,  |
|         |                                                 | a feature per signal, N = 32 uniform  |
|         |                                                 | launch; at most num_envs cities       |
| launch  | uniform, square, line                           | num_envs per layout: square x, y ∈    |
|         |                                                 | [115.25, 217.25]; line x ∈ [0, 1024], |
|         |                                                 | y ∈ [96, 352]                         |
| scale   | N{n}_F{f} for n, f ∈ {16, 32, 64, 128}           | num_envs per (N, F)                   |
| all     | every suite above                               |                                       |
| symmetry | {line,square}_d4-{g}, g = 0..7                 | the launch suite's line and square    |
|         | (not part of all)                               | environments and their 7 images under |
|         |                                                 | the world's rotations and reflections |
| faults  | ideal, loss_10, loss_30, loss_50, burst_30,     | the uniform suite's environments, each |
|         | no_comm, distance, bandwidth, delay_1s,         | group over its network (:data:`FAULTS`) |
|         | delay_5s, fail_25, survivors_25, noise_5m       |                                       |
|         | (not part of all)                               |                                       |

Seeds: an environment's scenario seed is a hash of (suite, group, index) with bit 62 set, and
dataset seeds always have it clear (:mod:`madp.datagen.plan`), so evaluation never replays a
training scenario. Every controller of a suite runs on exactly these scenarios and start positions.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from madp.errors import InputError, SettingError
from madp.sim import Scenario, SimParams
from madp.sim.launch import D4_SIZE
from madp.sim.network import NetworkSettings

EVAL_SEED_BIT = 1 << 62
SUITES = ("uniform", "sigma", "cities", "launch", "scale")
EXTRA_SUITES = ("symmetry", "faults")  # diagnostic suites, run by name only (not by ``all``)
#: Steps a kept message may outlive its delay in the faults suite (1 s): a lost message is bridged by
#: the sender's last one for up to a second.
FAULTS_KEEP_STEPS = 5
#: Mean length of burst_30's bursts of lost messages (steps: 1 s), longer than a kept message bridges.
FAULTS_BURST_STEPS = 5
#: The faults suite's groups: the network between the robots (:mod:`madp.sim.network`) of each.
#:
#: * ``loss_*``: i.i.d. loss; ``burst_30``: loss_30's mean loss in bursts of 1 s on average
#:   (Gilbert-Elliott); ``no_comm``: every message lost, each robot alone;
#: * ``distance``: loss rising as (d / r_c)² to 60 % at r_c (30 % over a uniformly filled disc, as loss_30);
#: * ``bandwidth``: at most 2000 bytes per robot per step (80 kbit/s): a position beacon is 35 bytes,
#:   MADP's token message 171, an LPAC-K3 round up to 1043 (:func:`madp.sim.network.message_bytes`);
#: * ``fail_25``: 8 of 32 robots stop at step 200; ``survivors_25``: the same 24 survivors, alone from
#:   the start (the 8 stop at step 0). Both are J of the survivors over J(0) of all 32, so
#:   survivors_25 − ideal is the capacity lost and fail_25 − survivors_25 what the failure costs beyond it.
FAULTS = {
    "ideal": NetworkSettings(),
    "loss_10": NetworkSettings(loss=0.1, max_age_steps=FAULTS_KEEP_STEPS),
    "loss_30": NetworkSettings(loss=0.3, max_age_steps=FAULTS_KEEP_STEPS),
    "loss_50": NetworkSettings(loss=0.5, max_age_steps=FAULTS_KEEP_STEPS),
    "burst_30": NetworkSettings(loss=0.3, burst_len=FAULTS_BURST_STEPS, max_age_steps=FAULTS_KEEP_STEPS),
    "no_comm": NetworkSettings(loss=1.0),
    "distance": NetworkSettings(loss_at_range=0.6, max_age_steps=FAULTS_KEEP_STEPS),
    "bandwidth": NetworkSettings(max_bytes_per_step=2000),
    "delay_1s": NetworkSettings(delay_steps=5, max_age_steps=5 + FAULTS_KEEP_STEPS),
    "delay_5s": NetworkSettings(delay_steps=25, max_age_steps=25 + FAULTS_KEEP_STEPS),
    "fail_25": NetworkSettings(fail_fraction=0.25, fail_step=200),
    "survivors_25": NetworkSettings(fail_fraction=0.25, fail_step=0),
    "noise_5m": NetworkSettings(position_noise_m=5.0),
}
#: The most environments a group may have: a larger number is a mistake, refused before anything runs.
MAX_NUM_ENVS = 10_000
SYMMETRY_LAYOUTS = ("line", "square")
SIGMA_RANGES = ((30, 40), (20, 30), (10, 20), (5, 10))
LAUNCHES = {"uniform": None, "square": (115.25, 115.25, 217.25, 217.25), "line": (0.0, 96.0, 1024.0, 352.0)}
SCALE_SIZES = (16, 32, 64, 128)


def default_cities_dir() -> Path:
    """The traffic-signal files shipped with madp (40 U.S. cities, OpenStreetMap data, ODbL)."""
    return Path(str(resources.files("madp.cities") / "data"))


def eval_seed(suite: str, group: str, index: int) -> int:
    a, b = np.random.SeedSequence([0x5EED, zlib.crc32(suite.encode()), zlib.crc32(group.encode()), index]).generate_state(2, np.uint32)
    return int(((int(a) << 32 | int(b)) & (EVAL_SEED_BIT - 1)) | EVAL_SEED_BIT)


@dataclass(frozen=True)
class EnvSpec:
    """One evaluation environment. ``scenario()`` builds it (deterministically)."""

    suite: str
    group: str
    index: int
    params: SimParams
    launch: str = "uniform"
    city_file: str = ""
    d4: int = 0  # element of the world's symmetry group applied to the scenario (madp.sim.launch)
    network: NetworkSettings | None = None  # the network between the robots (None: they read the true state)

    @property
    def seed(self) -> int:
        """The scenario seed; an image of the symmetry suite shares its launch environment's."""
        if self.suite == "symmetry":
            return eval_seed("launch", self.launch, self.index)
        if self.suite == "faults":  # the uniform suite's environments
            return eval_seed("uniform", "uniform", self.index)
        return eval_seed(self.suite, self.group, self.index)

    @property
    def key(self) -> str:
        slug = "".join(c if c.isalnum() or c in "-_" else "_" for c in self.group)
        return f"{slug}-{self.index:03d}"

    def scenario(self) -> Scenario:
        if not self.city_file:
            base = Scenario.random(self.seed, self.params, LAUNCHES[self.launch])
            return replace(base.d4_image(self.d4) if self.d4 else base, name=f"{self.suite}/{self.key}")
        from madp.cities.importer import city_scenario

        return city_scenario(self.city_file, self.seed, self.params)[0]


def suite_names(suite: str) -> list[str]:
    """The suites ``suite`` names: one, a comma-separated list (``uniform,cities``), or every one of
    :data:`SUITES` for ``"all"`` (the :data:`EXTRA_SUITES` run by name only)."""
    names = list(SUITES) if suite == "all" else [s.strip() for s in suite.split(",")]
    if any(s not in SUITES + EXTRA_SUITES for s in names):
        raise SettingError("suite", f"expected one of {list(SUITES) + ['all'] + list(EXTRA_SUITES)} or a "
                                    f"comma-separated list, got {suite!r}")
    return names


def only_groups(envs: list[EnvSpec], groups: tuple[str, ...]) -> list[EnvSpec]:
    """The environments of ``envs`` in ``groups`` (all of them when ``groups`` is empty), in suite order.
    A name that is not a group of the suite is a one-line error naming the suite's groups."""
    if not groups:
        return envs
    known = list(dict.fromkeys(e.group for e in envs))
    unknown = [g for g in groups if g not in known]
    if unknown:
        suite = envs[0].suite if envs else "?"
        raise SettingError("groups", f"{', '.join(unknown)}: not a group of suite {suite!r}; expected some of {known}")
    return [e for e in envs if e.group in groups]


def suite_envs(suite: str, num_envs: int = 50, cities_dir: str | Path | None = None) -> list[EnvSpec]:
    """The environments of a suite, in a fixed order."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or not 1 <= num_envs <= MAX_NUM_ENVS:
        raise SettingError("num_envs", f"expected a whole number of environments per group in [1, {MAX_NUM_ENVS}], "
                                       f"got {num_envs!r}")
    base = SimParams()
    if suite == "uniform":
        return [EnvSpec(suite, "uniform", i, base) for i in range(num_envs)]
    if suite == "sigma":
        return [EnvSpec(suite, f"sigma_{lo}-{hi}", i, replace(base, sigma_range_m=(lo, hi)))
                for lo, hi in SIGMA_RANGES for i in range(num_envs)]
    if suite == "launch":
        return [EnvSpec(suite, name, i, base, launch=name) for name in LAUNCHES for i in range(num_envs)]
    if suite == "scale":
        return [EnvSpec(suite, f"N{n}_F{f}", i, replace(base, num_robots=n, num_features=f))
                for n in SCALE_SIZES for f in SCALE_SIZES for i in range(num_envs)]
    if suite == "symmetry":
        return [EnvSpec(suite, f"{name}_d4-{g}", i, base, launch=name, d4=g)
                for name in SYMMETRY_LAYOUTS for g in range(D4_SIZE) for i in range(num_envs)]
    if suite == "faults":
        return [EnvSpec(suite, name, i, base, network=net) for name, net in FAULTS.items() for i in range(num_envs)]
    if suite == "cities":
        from madp.cities.importer import load_city_dir

        directory = Path(cities_dir) if cities_dir else default_cities_dir()
        files = load_city_dir(directory)
        if not files:
            raise InputError(f"{directory}: no city files (.csv, .geojson, .json) found")
        return [EnvSpec(suite, Path(f).name.split(".")[0], 0, base, city_file=str(f)) for f in files[:num_envs]]
    raise SettingError("suite", f"expected one of {list(SUITES) + ['all'] + list(EXTRA_SUITES)}, got {suite!r}")
