"""One scenario type for rollouts, datagen, eval and the city importer, and its JSON form.

The minimal hand-written file::

    {"features": [{"mean": [x, y], "sigma": s, "peak": p}, ...],
     "robots": [[x, y], ...]}

Optional keys: ``"params"`` (overrides of :class:`SimParams`, e.g. ``{"comm_radius_m": 128}``),
``"name"``, ``"seed"``, ``"source"``. Everything not given takes the SPEC default. ``num_robots`` and
``num_features`` follow the lists. Errors are one line naming the file and field. A scenario must
fit in memory and have importance to cover: its sizes are checked before anything is allocated,
and a scenario whose J(0) would be 0 (no features, features outside the world, σ too small to put
importance on a cell) is refused with the reason, since J(t)/J(0) is then undefined.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from madp.errors import InputError
from madp.io.atomic import write_text_atomic

from .idf import importance_map, random_features
from .launch import d4_points
from .params import SimParams

BORDER_EPS_M = 1e-4


class ScenarioError(InputError):
    """A scenario file or dict that does not describe a valid scenario (one-line message)."""


@dataclass(frozen=True)
class Scenario:
    """Features [F, 4] (μx, μy, σ, peak), robot start positions [N, 2] (m), and parameters."""

    features: np.ndarray
    robots_m: np.ndarray
    params: SimParams = field(default_factory=SimParams)
    name: str = ""
    seed: int | None = None
    source: str = ""

    @classmethod
    def random(
        cls,
        seed: int,
        params: SimParams | None = None,
        launch: tuple[float, float, float, float] | None = None,
        name: str = "",
    ) -> "Scenario":
        """Draw a scenario from ``numpy.random.default_rng(seed)``: features first, then robots.

        ``launch`` = (x0, y0, x1, y1) is the rectangle robots start in (default: the whole world,
        1e-4 m inside its border, as the library draws them).
        """
        params = params or SimParams()
        rng = np.random.default_rng(seed)
        feats = random_features(rng, params.num_features, params.world_size, params.sigma_range_m, params.peak_range)
        w = float(params.world_size)
        x0, y0, x1, y1 = launch if launch is not None else (BORDER_EPS_M, BORDER_EPS_M, w - BORDER_EPS_M, w - BORDER_EPS_M)
        robots = np.column_stack([rng.uniform(x0, x1, params.num_robots), rng.uniform(y0, y1, params.num_robots)])
        return cls(feats, robots, params, name=name, seed=seed)

    def d4_image(self, g: int) -> "Scenario":
        """The image of this scenario under element ``g`` of the square world's symmetry group
        (:func:`madp.sim.launch.d4_points`): feature means and robots moved, σ and peaks kept."""
        w = float(self.params.world_size)
        features = np.array(self.features, dtype=np.float64, copy=True)
        features[:, :2] = d4_points(features[:, :2], g, w)
        return replace(self, features=features, robots_m=d4_points(self.robots_m, g, w),
                       name=f"{self.name}@d4-{g}" if self.name else f"d4-{g}")

    # --- JSON ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        defaults = SimParams().to_dict()
        overrides = {k: v for k, v in self.params.to_dict().items()
                     if v != defaults[k] and k not in ("num_robots", "num_features")}
        d: dict = {
            "features": [
                {"mean": [float(f[0]), float(f[1])], "sigma": float(f[2]), "peak": float(f[3])}
                for f in self.features
            ],
            "robots": [[float(x), float(y)] for x, y in self.robots_m],
        }
        if overrides:
            d["params"] = overrides
        for key in ("name", "source"):
            if getattr(self, key):
                d[key] = getattr(self, key)
        if self.seed is not None:
            d["seed"] = int(self.seed)
        return d

    def save(self, path: str | Path) -> None:
        write_text_atomic(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def from_dict(cls, d: object, where: str = "scenario") -> "Scenario":
        if not isinstance(d, dict):
            raise ScenarioError(f"{where}: expected a JSON object with 'features' and 'robots'")
        unknown = sorted(set(d) - {"features", "robots", "params", "name", "seed", "source"})
        if unknown:
            raise ScenarioError(f"{where}: unknown key(s) {unknown}")
        feats = _features(d.get("features"), where)
        robots = _points(d.get("robots"), where, "robots")
        if len(robots) == 0:
            raise ScenarioError(f"{where}: field 'robots' must list at least one [x, y]")
        overrides = d.get("params", {})
        if not isinstance(overrides, dict):
            raise ScenarioError(f"{where}: field 'params' must be an object")
        try:
            params = SimParams.from_dict({**overrides, "num_robots": len(robots), "num_features": len(feats)})
        except (TypeError, ValueError) as e:
            raise ScenarioError(f"{where}: field 'params': {e}") from None
        w = params.world_size
        outside = np.nonzero(~((robots >= 0) & (robots <= w)).all(axis=1))[0]
        if len(outside):
            i = int(outside[0])
            raise ScenarioError(f"{where}: field 'robots[{i}]' = {robots[i].tolist()} is outside the world [0, {w}]")
        seed = d.get("seed")
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
            raise ScenarioError(f"{where}: field 'seed' must be an integer")
        try:
            params.check_fits(where)
        except ValueError as e:
            raise ScenarioError(str(e)) from None
        check_coverable(feats, params, where)
        return cls(feats, robots, params, name=str(d.get("name", "")), seed=seed, source=str(d.get("source", "")))

    @classmethod
    def load(cls, path: str | Path) -> "Scenario":
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise ScenarioError(f"{path}: cannot read scenario file ({e.strerror or e})") from None
        except UnicodeDecodeError as e:
            raise ScenarioError(f"{path}: not UTF-8 text (byte {e.start}); expected a JSON scenario") from None
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise ScenarioError(f"{path}: not valid JSON (line {e.lineno}: {e.msg})") from None
        return cls.from_dict(d, str(path))

    def with_params(self, **changes) -> "Scenario":
        return replace(self, params=replace(self.params, **changes))


def check_coverable(features: np.ndarray, params: SimParams, where: str) -> None:
    """Raise :class:`ScenarioError` with the reason if the features put no importance on the world
    (the map is 0 everywhere, so J(0) = 0 and J(t)/J(0) is undefined)."""
    why = None
    if len(features) == 0:
        why = "it has no features"
    elif not importance_map(features, params.world_size, params.truncation_sigmas).any():
        w, reach = params.world_size, params.truncation_sigmas * features[:, 2]
        outside = ((features[:, 0] + reach < 0) | (features[:, 0] - reach > w)
                   | (features[:, 1] + reach < 0) | (features[:, 1] - reach > w))
        why = (f"every feature lies outside the world [0, {w}]² (beyond {params.truncation_sigmas:g} σ)" if outside.all()
               else f"its features' σ (smallest {features[:, 2].min():.3g} m) or peaks are too small to give any cell importance")
    if why:
        raise ScenarioError(f"{where}: the importance map is 0 everywhere ({why}), so J(0) = 0 and J(t)/J(0) is undefined")


def _number(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ScenarioError(f"{what} must be a finite number, got {v!r}")
    try:
        x = float(v)
    except OverflowError:  # an integer beyond float range
        x = math.inf
    if not math.isfinite(x):
        raise ScenarioError(f"{what} must be a finite number, got {str(v)[:20]}{'…' if len(str(v)) > 20 else ''}")
    return x


def _points(v: object, where: str, name: str) -> np.ndarray:
    if not isinstance(v, list):
        raise ScenarioError(f"{where}: field '{name}' must be a list of [x, y] pairs")
    out = np.empty((len(v), 2))
    for i, p in enumerate(v):
        what = f"{where}: field '{name}[{i}]'"
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            raise ScenarioError(f"{what} must be [x, y], got {p!r}")
        out[i] = [_number(c, what) for c in p]
    return out


def _features(v: object, where: str) -> np.ndarray:
    if not isinstance(v, list):
        raise ScenarioError(f"{where}: field 'features' must be a list of {{mean, sigma, peak}} objects")
    out = np.empty((len(v), 4))
    for i, f in enumerate(v):
        what = f"{where}: field 'features[{i}]'"
        if not isinstance(f, dict) or not {"mean", "sigma", "peak"} <= set(f):
            raise ScenarioError(f"{what} must be an object with 'mean', 'sigma' and 'peak'")
        if not isinstance(f["mean"], list):
            raise ScenarioError(f"{what}.mean must be [x, y], got {f['mean']!r}")
        mean = _points([f["mean"]], where, f"features[{i}].mean")[0]
        sigma = _number(f["sigma"], f"{what}.sigma")
        peak = _number(f["peak"], f"{what}.peak")
        if sigma <= 0 or peak <= 0:
            raise ScenarioError(f"{what}: sigma and peak must be > 0, got sigma={sigma}, peak={peak}")
        if not math.isfinite(2.0 * math.pi * sigma * sigma * peak):
            raise ScenarioError(f"{what}: sigma and peak are too large (the feature's mass 2πσ²·peak overflows)")
        out[i] = [mean[0], mean[1], sigma, peak]
    return out
