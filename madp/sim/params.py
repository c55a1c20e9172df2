"""Simulation parameters (SPEC §2). Every quantity the paper varies is a field here."""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import asdict, dataclass, fields

from madp.errors import SettingError


def physical_memory_bytes() -> int | None:
    """This machine's physical memory, or None where the OS does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def _is_number(v: object) -> bool:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:  # an integer beyond float range
        return False


@dataclass(frozen=True)
class SimParams:
    """The coverage world's constants; defaults are the paper's training setting.

    Lengths in metres on a 1 m grid; speeds in m/s; times in s.
    """

    world_size: int = 1024  # world is [0, world_size)² m, one cell per m²
    num_robots: int = 32
    num_features: int = 32
    sigma_range_m: tuple[float, float] = (40.0, 60.0)
    peak_range: tuple[float, float] = (0.6, 1.0)
    truncation_sigmas: float = 2.0
    comm_radius_m: float = 256.0
    sensor_size: int = 64  # sensed square, cells c-32 .. c+31
    local_map_size: int = 256  # local window, cells c-128 .. c+127
    obs_size: int = 32  # observation maps are obs_size x obs_size
    max_speed_mps: float = 5.0
    dt_s: float = 0.2
    history_size: int = 20  # positions kept for the oscillation check
    check_oscillations: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):  # types first: a JSON file may hold anything
            v = getattr(self, f.name)
            if f.name in ("sigma_range_m", "peak_range"):
                if not isinstance(v, (tuple, list)) or len(v) != 2 or not all(_is_number(x) for x in v):
                    raise SettingError(f.name, message=f"{f.name} must be a (low, high) pair of finite numbers, got {v!r}")
            elif f.type in ("int", int):
                if not isinstance(v, numbers.Integral) or isinstance(v, bool):
                    raise SettingError(f.name, message=f"{f.name} must be an integer, got {v!r}")
                object.__setattr__(self, f.name, int(v))  # numpy integers too
            elif f.type in ("float", float) and not _is_number(v):
                raise SettingError(f.name, message=f"{f.name} must be a finite number, got {v!r}")
            elif f.type in ("bool", bool) and not isinstance(v, bool):
                raise SettingError(f.name, message=f"{f.name} must be true or false, got {v!r}")
        object.__setattr__(self, "sigma_range_m", tuple(float(v) for v in self.sigma_range_m))
        object.__setattr__(self, "peak_range", tuple(float(v) for v in self.peak_range))
        problems = []
        if self.world_size < self.local_map_size or self.world_size % 16:
            problems.append(f"world_size must be a multiple of 16 and >= local_map_size, got {self.world_size}")
        if self.num_robots < 1:
            problems.append(f"num_robots must be >= 1, got {self.num_robots}")
        if self.num_features < 0:
            problems.append(f"num_features must be >= 0, got {self.num_features}")
        lo, hi = self.sigma_range_m
        if not (0 < lo <= hi):
            problems.append(f"sigma_range_m must satisfy 0 < lo <= hi, got {self.sigma_range_m}")
        lo, hi = self.peak_range
        if not (0 < lo <= hi):
            problems.append(f"peak_range must satisfy 0 < lo <= hi, got {self.peak_range}")
        for name in ("comm_radius_m", "max_speed_mps", "dt_s"):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)}")
        if self.local_map_size % 16 or self.sensor_size % 2:
            problems.append("local_map_size must be a multiple of 16 and sensor_size even")
        for name in ("truncation_sigmas", "sensor_size", "local_map_size", "obs_size", "history_size"):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)}")
        if problems:
            raise SettingError(problems[0].split()[0], message="; ".join(problems))  # each names its parameter

    def env_bytes(self) -> int:
        """The least memory one environment takes: every robot's zero-padded map (float32), the
        world map with its prefix sums (float64) and the features."""
        padded = self.world_size + self.local_map_size
        return 4 * self.num_robots * padded * padded + 48 * self.world_size * self.world_size + 32 * self.num_features

    def check_fits(self, where: str) -> None:
        """Refuse, before anything is allocated, sizes whose environment cannot fit in this machine's
        memory (``where`` names the settings or the file that chose them)."""
        need, have = self.env_bytes(), physical_memory_bytes()
        if have is not None and need > have:
            raise SettingError(where, message=f"{where}: N = {self.num_robots} robots and F = {self.num_features} features on a "
                             f"{self.world_size} m world need at least {need / 2**30:.1f} GiB for one environment, "
                             f"more than this machine's {have / 2**30:.1f} GiB")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["sigma_range_m"] = list(self.sigma_range_m)
        d["peak_range"] = list(self.peak_range)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SimParams":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise SettingError("params", message=f"unknown parameter(s) {unknown}; expected some of {sorted(known)}")
        return cls(**d)
