"""Simulation parameters (SPEC §2). Every quantity the paper varies is a field here."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields


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
        if problems:
            raise ValueError("; ".join(problems))

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
            raise ValueError(f"unknown parameter(s) {unknown}; expected some of {sorted(known)}")
        return cls(**d)
