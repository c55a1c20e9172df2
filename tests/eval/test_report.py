"""Tests of the evaluation report (``madp.eval.report`` and its ``stats``, ``tables``, ``plots`` and
``paper``): statistics, tables, JSON and plots.

Synthetic ``curves`` / ``results`` tables are built with pyarrow in ``tmp_path``; every statistic is
checked against a direct NumPy / SciPy computation on the same numbers.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy import stats

from madp.eval.paper import PAPER_RESULTS
from madp.eval.plots import group_slug
from madp.eval.report import write_report
from madp.eval.stats import cost_curve_bands, order_controllers, order_groups, scale_improvement_matrix, summarize
from madp.eval.tables import markdown_table

RATES = {"clairvoyant": 0.30, "dcvt": 0.08, "lpac": 0.15, "madp": 0.20, "madp_central": 0.22}


def make_suite(
    suite: str,
    groups: dict[str, dict],
    controllers: tuple[str, ...] = ("dcvt", "lpac", "madp"),
    n_envs: int = 3,
    steps: int = 10,
    seed: int = 0,
    shuffle: bool = True,
) -> tuple[pa.Table, pa.Table]:
    """Curves and results tables: one decaying noisy curve per (group, env, controller).

    ``groups`` maps a group name to its scenario parameters (num_robots, num_features, sigma_lo,
    sigma_hi, city, launch; defaults N = F = 32, σ ∈ [40, 60], uniform launch). Rows are shuffled
    so the report cannot rely on the row order.
    """
    rng = np.random.default_rng(seed)
    cur: dict[str, list] = {k: [] for k in ("suite", "group", "env", "scenario_seed", "controller", "step", "cost")}
    res: dict[str, list] = {k: [] for k in ("suite", "group", "env", "scenario_seed", "controller", "final_cost",
                                            "steps", "mean_step_ms", "num_robots", "num_features", "sigma_lo",
                                            "sigma_hi", "city", "launch")}
    t = np.arange(steps + 1)
    for gi, (g, p) in enumerate(groups.items()):
        for e in range(n_envs):
            sseed = 1000 * gi + e
            for c in controllers:
                rate = RATES.get(c, 0.1) * rng.uniform(0.7, 1.3)
                floor = rng.uniform(0.1, 0.5)
                cost = floor + (1 - floor) * np.exp(-rate * t) + np.r_[0.0, rng.normal(0, 0.01, steps)]
                cur["suite"] += [suite] * t.size
                cur["group"] += [g] * t.size
                cur["env"] += [e] * t.size
                cur["scenario_seed"] += [sseed] * t.size
                cur["controller"] += [c] * t.size
                cur["step"] += t.tolist()
                cur["cost"] += cost.tolist()
                res["suite"].append(suite)
                res["group"].append(g)
                res["env"].append(e)
                res["scenario_seed"].append(sseed)
                res["controller"].append(c)
                res["final_cost"].append(float(cost[-1]))
                res["steps"].append(steps)
                res["mean_step_ms"].append(float(rng.uniform(1, 50)))
                res["num_robots"].append(p.get("num_robots", 32))
                res["num_features"].append(p.get("num_features", 32))
                res["sigma_lo"].append(float(p.get("sigma_lo", 40.0)))
                res["sigma_hi"].append(float(p.get("sigma_hi", 60.0)))
                res["city"].append(p.get("city", ""))
                res["launch"].append(p.get("launch", "uniform"))
    cur_types = {"env": pa.int32(), "scenario_seed": pa.int64(), "step": pa.int32(), "cost": pa.float64()}
    res_types = {"env": pa.int32(), "scenario_seed": pa.int64(), "final_cost": pa.float64(), "steps": pa.int32(),
                 "mean_step_ms": pa.float64(), "num_robots": pa.int32(), "num_features": pa.int32(),
                 "sigma_lo": pa.float64(), "sigma_hi": pa.float64()}

    def table(cols: dict[str, list], types: dict) -> pa.Table:
        n = len(cols["suite"])
        perm = rng.permutation(n) if shuffle else np.arange(n)
        return pa.table({k: pa.array([v[i] for i in perm], type=types.get(k, pa.string())) for k, v in cols.items()})

    return table(cur, cur_types), table(res, res_types)


def write_suite(directory: Path, curves: pa.Table | None, results: pa.Table) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    if curves is not None:
        pq.write_table(curves, directory / "curves.parquet")
    pq.write_table(results, directory / "results.parquet")
    return directory


def numpy_stats(x: np.ndarray) -> dict[str, float]:
    """The oracle: mean, SE = std(ddof=1)/sqrt(n), Student-t 95 % interval, median."""
    n = x.size
    mean = x.mean()
    se = x.std(ddof=1) / math.sqrt(n) if n > 1 else math.nan
    half = stats.t.ppf(0.975, n - 1) * se if n > 1 else 0.0
    return {"n": n, "mean": mean, "se": se, "ci_lo": mean - half, "ci_hi": mean + half, "median": np.median(x)}


def columns(table: pa.Table) -> dict[str, np.ndarray]:
    return {name: np.asarray(table.column(name).to_pylist()) for name in table.column_names}


def strict_json(path: Path) -> dict:
    """Parse JSON rejecting NaN / Infinity (which are not JSON)."""
    def bad(token):
        raise ValueError(f"non-JSON constant {token}")
    return json.loads(path.read_text(), parse_constant=bad)


def assert_png(path: Path, shape: tuple[int, ...] | None = None) -> np.ndarray:
    assert path.is_file(), path
    assert path.stat().st_size > 5000, (path, path.stat().st_size)
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[2] in (3, 4)
    if shape is not None:
        assert img.shape == shape
    assert img[..., :3].std() > 0.05  # not a blank canvas
    return img


# --------------------------------------------------------------------------------------------------
# Ordering and names
# --------------------------------------------------------------------------------------------------


def test_orderings_and_slugs():
    assert order_controllers(["zeta", "madp", "alpha", "dcvt", "madp_central", "clairvoyant", "lpac", "madp"]) == [
        "clairvoyant", "dcvt", "lpac", "madp", "madp_central", "alpha", "zeta"]
    assert order_groups(["sigma_20-30", "sigma_5-10", "sigma_10-20", "sigma_30-40"]) == [
        "sigma_5-10", "sigma_10-20", "sigma_20-30", "sigma_30-40"]
    assert order_groups(["N32_F16", "N16_F128", "N16_F32", "N128_F16"]) == ["N16_F32", "N16_F128", "N32_F16", "N128_F16"]
    assert order_groups(["boston, MA", "Austin, TX", "Chicago, IL"]) == ["Austin, TX", "boston, MA", "Chicago, IL"]
    assert group_slug("Boston, MA") == "boston-ma"
    assert group_slug("sigma_10-20") == "sigma_10-20"
    assert group_slug("N32_F64") == "n32_f64"
    assert group_slug("São Paulo / SP") == "s-o-paulo-sp"
    assert group_slug("???") == "group"


# --------------------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------------------


def test_summary_matches_numpy():
    _, results = make_suite("uniform", {"uniform": {}, "other": {}}, controllers=("madp", "clairvoyant", "dcvt"))
    s = summarize(results)
    assert s["suite"] == "uniform"
    assert s["controllers"] == ["clairvoyant", "dcvt", "madp"]
    assert s["groups"] == ["other", "uniform"]
    col = columns(results)
    for g in s["groups"]:
        assert list(s["by_group"][g]) == s["controllers"]
        for c in s["controllers"]:
            m = (col["group"] == g) & (col["controller"] == c)
            want = numpy_stats(col["final_cost"][m])
            got = s["by_group"][g][c]
            assert got["n"] == want["n"] == 3
            for k in ("mean", "se", "ci_lo", "ci_hi", "median"):
                assert got[k] == pytest.approx(want[k], rel=1e-12, abs=1e-14), (g, c, k)
            assert got["std"] == pytest.approx(col["final_cost"][m].std(ddof=1), rel=1e-12)
            assert got["mean_step_ms"] == pytest.approx(col["mean_step_ms"][m].mean(), rel=1e-12)
    for c in s["controllers"]:
        m = col["controller"] == c
        want = numpy_stats(col["final_cost"][m])
        got = s["overall"][c]
        assert got["n"] == 6
        for k in ("mean", "se", "ci_lo", "ci_hi", "median"):
            assert got[k] == pytest.approx(want[k], rel=1e-12), (c, k)
        assert got["mean_step_ms"] == pytest.approx(col["mean_step_ms"][m].mean(), rel=1e-12)
    meta = s["groups_meta"]["uniform"]
    assert meta == {"num_robots": 32, "num_features": 32, "sigma_lo": 40.0, "sigma_hi": 60.0, "city": "",
                    "launch": "uniform"}


def test_summary_independent_of_row_order():
    _, a = make_suite("uniform", {"b": {}, "a": {}}, seed=3, shuffle=False)
    b = a.take(pa.array(np.random.default_rng(1).permutation(a.num_rows)))
    sa, sb = summarize(a), summarize(b)
    assert json.dumps(sa, default=str) == json.dumps(sb, default=str)


def test_summary_single_env_and_uneven_counts():
    _, results = make_suite("uniform", {"uniform": {}}, controllers=("dcvt", "madp"), n_envs=2)
    # Drop MADP's env 1: dcvt has 2 envs, madp one.
    col = columns(results)
    keep = ~((col["controller"] == "madp") & (col["env"] == 1))
    results = results.filter(pa.array(keep))
    s = summarize(results)
    madp = s["by_group"]["uniform"]["madp"]
    assert madp["n"] == 1 and math.isnan(madp["se"]) and math.isnan(madp["std"])
    assert madp["ci_lo"] == madp["ci_hi"] == madp["mean"] == madp["median"]
    assert s["by_group"]["uniform"]["dcvt"]["n"] == 2
    md = markdown_table(s, "uniform")
    assert f"{madp['mean']:.3f} (n=1)" in md
    assert "| uniform | 1–2 |" in md


def test_summary_rejects_duplicates_and_foreign_suites():
    _, results = make_suite("uniform", {"uniform": {}}, n_envs=2)
    with pytest.raises(ValueError, match="duplicate results row"):
        summarize(pa.concat_tables([results, results.slice(0, 1)]))
    with pytest.raises(ValueError, match="no rows of suite 'cities'"):
        summarize(results, "cities")
    _, other = make_suite("sigma", {"sigma_5-10": {}}, n_envs=1)
    both = pa.concat_tables([results, other])
    with pytest.raises(ValueError, match="pass suite="):
        summarize(both)
    assert summarize(both, "sigma")["groups"] == ["sigma_5-10"]


def test_cost_curve_bands_match_numpy():
    curves, _ = make_suite("uniform", {"uniform": {}}, controllers=("madp", "dcvt"), n_envs=4, steps=6)
    col = columns(curves)
    bands = cost_curve_bands(col["controller"], col["env"], col["step"], col["cost"])
    assert list(bands) == ["dcvt", "madp"]
    for c, b in bands.items():
        m = col["controller"] == c
        cube = np.full((4, 7), np.nan)
        cube[col["env"][m], col["step"][m]] = col["cost"][m]
        mean = cube.mean(axis=0)
        half = stats.norm.ppf(0.975) * cube.std(axis=0, ddof=1) / 2.0  # the paper's band: mean ± 1.96·SE
        np.testing.assert_array_equal(b["step"], np.arange(7))
        np.testing.assert_allclose(b["mean"], mean, rtol=1e-12)
        np.testing.assert_allclose(b["lo"], mean - half, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(b["hi"], mean + half, rtol=1e-12)
        np.testing.assert_array_equal(b["n"], 4)
    # One environment: the band collapses onto the mean.
    m = col["env"] == 2
    one = cost_curve_bands(col["controller"][m], col["env"][m], col["step"][m], col["cost"][m])
    for b in one.values():
        np.testing.assert_array_equal(b["lo"], b["mean"])
        np.testing.assert_array_equal(b["hi"], b["mean"])


def test_scale_improvement_matrix_by_hand():
    # N x F = {16, 64} x {32, 128}; the madp / dcvt / lpac means per cell are set by hand.
    rows = []
    finals = {  # (N, F): {controller: [final costs of two envs]}
        (16, 32): {"dcvt": [0.8, 0.6], "lpac": [0.5, 0.5], "madp": [0.35, 0.45]},
        (16, 128): {"dcvt": [0.9, 0.7], "lpac": [0.6, 0.4], "madp": [0.6, 0.6]},
        (64, 32): {"dcvt": [0.5, 0.5], "lpac": [0.3, 0.5], "madp": [0.5, 0.3]},
        (64, 128): {"dcvt": [0.7, 0.7], "madp": [0.8, 0.8]},  # lpac missing here
    }
    for (n, f), per in finals.items():
        for c, vals in per.items():
            rows += [(f"N{n}_F{f}", e, c, v, n, f) for e, v in enumerate(vals)]
    g, e, c, v, n, f = map(list, zip(*rows))
    table = pa.table({"suite": ["scale"] * len(rows), "group": g, "env": pa.array(e, pa.int32()), "controller": c,
                      "final_cost": v, "mean_step_ms": [1.0] * len(rows), "num_robots": pa.array(n, pa.int32()),
                      "num_features": pa.array(f, pa.int32())})
    m = scale_improvement_matrix(table, "dcvt", "madp")
    assert m["num_robots"] == [16, 64] and m["num_features"] == [32, 128]
    want = np.array([[(0.7 - 0.4) / 0.7, (0.8 - 0.6) / 0.8], [(0.5 - 0.4) / 0.5, (0.7 - 0.8) / 0.7]])
    np.testing.assert_allclose(m["improvement"], want, rtol=1e-12)
    np.testing.assert_array_equal(m["n_baseline"], 2)
    lp = scale_improvement_matrix(table, "lpac")
    np.testing.assert_allclose(lp["improvement"][0], [(0.5 - 0.4) / 0.5, (0.5 - 0.6) / 0.5], rtol=1e-12)
    assert lp["improvement"][1, 0] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(lp["improvement"][1, 1]) and lp["n_baseline"][1, 1] == 0
    s = summarize(table)
    assert set(s["scale_improvement"]) == {"dcvt", "lpac"}
    md = markdown_table(s, "scale")
    assert f"{want[0, 0]:+.1%}" in md and f"{want[1, 1]:+.1%}" in md


# --------------------------------------------------------------------------------------------------
# Report files
# --------------------------------------------------------------------------------------------------


def test_write_report_uniform(tmp_path):
    curves, results = make_suite("uniform", {"uniform": {}, "sigma_10-20": {}},
                                 controllers=("dcvt", "lpac", "madp"), n_envs=3, steps=10)
    d = write_suite(tmp_path / "uniform", curves, results)
    files = write_report(d, "uniform")
    assert set(files) == {"cost_uniform.png", "cost_sigma_10-20.png", "summary.md", "summary.json"}
    for p in files.values():
        assert p.parent == d and p.is_file()
    for name in ("cost_uniform.png", "cost_sigma_10-20.png"):
        assert_png(files[name], (600, 960, 4))

    doc = strict_json(files["summary.json"])
    s = summarize(results)
    assert doc["controllers"] == ["dcvt", "lpac", "madp"] == s["controllers"]
    assert doc["groups"] == ["sigma_10-20", "uniform"]
    for g in doc["groups"]:
        for c in doc["controllers"]:
            for k in ("n", "mean", "se", "ci_lo", "ci_hi", "median", "std", "mean_step_ms"):
                assert doc["by_group"][g][c][k] == pytest.approx(s["by_group"][g][c][k], rel=1e-12)
    assert set(doc["overall"]) == {"dcvt", "lpac", "madp"}
    meta = doc["metadata"]
    assert meta["results_rows"] == results.num_rows and meta["steps"] == [10]
    assert meta["curves"]["rows"] == curves.num_rows and meta["curves"]["max_step"] == 10
    assert meta["paper"] == PAPER_RESULTS["uniform"]
    assert set(meta["files"]) == set(files)

    md = files["summary.md"].read_text()
    assert md == markdown_table(s, "uniform") + "\nPlots:\n\n" + \
        "![cost_sigma_10-20](cost_sigma_10-20.png)\n![cost_uniform](cost_uniform.png)\n"
    for name in ("DCVT", "LPAC-K3", "MADP", "sigma_10-20", "uniform", "**all**"):
        assert name in md
    assert "paper DCVT / LPAC-K3 / MADP" in md and "0.72 / 0.48 / 0.46" in md
    m = s["by_group"]["uniform"]["madp"]
    assert f"{m['mean']:.3f} ± {m['se']:.3f} [{m['ci_lo']:.3f}, {m['ci_hi']:.3f}]" in md
    assert "Mean wall time per control step (ms)" in md
    assert f"{s['overall']['lpac']['mean_step_ms']:.2f}" in md


def test_write_report_single_env_launch(tmp_path):
    curves, results = make_suite("launch", {"line": {"launch": "line"}, "square": {"launch": "square"}},
                                 controllers=("clairvoyant", "madp", "madp_central"), n_envs=1, steps=5)
    files = write_report(write_suite(tmp_path / "launch", curves, results), "launch")
    assert {"cost_line.png", "cost_square.png", "summary.md", "summary.json"} == set(files)
    assert_png(files["cost_line.png"], (600, 960, 4))
    doc = strict_json(files["summary.json"])
    st = doc["by_group"]["line"]["madp"]
    assert st["n"] == 1 and st["se"] is None and st["std"] is None and st["ci_lo"] == st["ci_hi"] == st["mean"]
    assert doc["groups_meta"]["square"]["launch"] == "square"
    md = files["summary.md"].read_text()
    for name in ("Clairvoyant", "MADP", "MADP (central)", "line", "square"):
        assert name in md
    assert "0.76 / 0.20 / 0.17" in md and "0.71 / 0.46 / 0.44" in md


def test_write_report_sigma(tmp_path):
    groups = {f"sigma_{lo}-{hi}": {"sigma_lo": lo, "sigma_hi": hi} for lo, hi in ((20, 30), (5, 10), (10, 20))}
    curves, results = make_suite("sigma", groups, controllers=("dcvt", "lpac", "madp", "custom"), n_envs=4, steps=4)
    files = write_report(write_suite(tmp_path / "sigma", curves, results), "sigma")
    assert "sigma_boxplot.png" in files
    assert_png(files["sigma_boxplot.png"])
    assert {f"cost_sigma_{k}.png" for k in ("5-10", "10-20", "20-30")} <= set(files)
    doc = strict_json(files["summary.json"])
    assert doc["groups"] == ["sigma_5-10", "sigma_10-20", "sigma_20-30"]
    assert doc["controllers"] == ["dcvt", "lpac", "madp", "custom"]
    assert doc["groups_meta"]["sigma_5-10"]["sigma_lo"] == 5.0
    assert "paper" not in files["summary.md"].read_text().split("Mean wall time")[0]


def test_write_report_cities(tmp_path):
    groups = {name: {"city": name} for name in ("Boston, MA", "Austin, TX", "Denver, CO")}
    curves, results = make_suite("cities", groups, controllers=("dcvt", "lpac", "madp"), n_envs=1, steps=5)
    files = write_report(write_suite(tmp_path / "cities", curves, results), "cities", all_threshold=2)
    assert {"cost_boston-ma.png", "cost_austin-tx.png", "cost_denver-co.png", "cost_all.png",
            "cities_heatmap.png"} <= set(files)
    img = assert_png(files["cities_heatmap.png"])
    assert img.shape[0] > 300 and img.shape[1] > 600
    assert_png(files["cost_all.png"], (600, 960, 4))
    doc = strict_json(files["summary.json"])
    assert doc["metadata"]["curves"]["slugs"]["Boston, MA"] == "boston-ma"
    md = files["summary.md"].read_text()
    all_row = next(line for line in md.splitlines() if line.startswith("| **all** | 3 |"))
    assert all_row.endswith("| 0.63 / 0.45 / 0.39 |")


def test_write_report_scale_without_curves(tmp_path):
    groups = {f"N{n}_F{f}": {"num_robots": n, "num_features": f} for n in (16, 64) for f in (32, 128)}
    _, results = make_suite("scale", groups, controllers=("dcvt", "lpac", "madp"), n_envs=2)
    d = write_suite(tmp_path / "scale", None, results)
    files = write_report(d, "scale")
    assert set(files) == {"scale_improvement_dcvt.png", "scale_improvement_lpac.png", "summary.md", "summary.json"}
    assert_png(files["scale_improvement_dcvt.png"])
    doc = strict_json(files["summary.json"])
    assert doc["metadata"]["curves"] == {"present": False}
    imp = doc["scale_improvement"]["dcvt"]
    want = scale_improvement_matrix(results, "dcvt", "madp")["improvement"]
    np.testing.assert_allclose(np.array(imp["improvement"], dtype=float), want, rtol=1e-12)
    assert imp["num_robots"] == [16, 64] and imp["num_features"] == [32, 128]
    assert "Relative improvement" in files["summary.md"].read_text()

    # Only the centralized-masked MADP: it stands in for MADP in the matrices.
    col = columns(results)
    renamed = np.where(col["controller"] == "madp", "madp_central", col["controller"])
    central = results.set_column(results.column_names.index("controller"), "controller", pa.array(renamed))
    d3 = write_suite(tmp_path / "scale3", None, central)
    doc3 = strict_json(write_report(d3, "scale")["summary.json"])
    assert doc3["scale_improvement"]["dcvt"]["method"] == "madp_central"
    np.testing.assert_allclose(np.array(doc3["scale_improvement"]["dcvt"]["improvement"], dtype=float), want,
                               rtol=1e-12)

    # No MADP: nothing to compare, no improvement plots, no error.
    no_madp = results.filter(pa.array(col["controller"] != "madp"))
    d2 = write_suite(tmp_path / "scale2", None, no_madp)
    files2 = write_report(d2, "scale")
    assert set(files2) == {"summary.md", "summary.json"}
    assert "scale_improvement" not in strict_json(files2["summary.json"])
