"""The paper's figures as the paper draws them: the cities heat map marks each city's best deployable
controller and the summary counts "best in k of n cities" (Fig. 5), the scale suite draws both panels
of Fig. 7 on one colour scale, and the uniform plot shades the 95 % band of Fig. 3. Each is checked on
the numbers the figure is drawn from, against a direct computation on the synthetic results table."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from matplotlib.collections import PathCollection, PolyCollection

from madp.eval.plots import BEST_MARKER, cities_heatmap_figure, color_map, cost_figure, scale_improvement_figure, \
    scale_limit
from madp.eval.report import write_report
from madp.eval.stats import best_per_group, cost_curve_bands, scale_improvement_matrix, summarize
from madp.eval.tables import markdown_table
from scipy import stats as scipy_stats
from tests.eval.test_report import columns, make_suite, strict_json, write_suite

CITIES = ("Alameda", "Boston", "Cupertino", "Dallas", "El Centro", "Fremont", "Honolulu")


def direct_best(results: pa.Table, oracle: str = "clairvoyant") -> tuple[dict[str, set[str]], dict[str, int]]:
    """Each city's controllers with the lowest mean final cost (the oracle left out), and the counts."""
    df = results.to_pandas()
    means = df[df.controller != oracle].groupby(["group", "controller"]).final_cost.mean().unstack()
    best = {g: set(row.index[row == row.min()]) for g, row in means.iterrows()}
    return best, {c: sum(c in b for b in best.values()) for c in means.columns}


def test_best_in_k_of_n_cities_equals_a_direct_count(tmp_path):
    groups = {name: {"city": name} for name in CITIES}
    curves, results = make_suite("cities", groups, controllers=("clairvoyant", "dcvt", "lpac", "madp", "madp:r4"),
                                 n_envs=2, steps=5, seed=3)
    col = columns(results)
    assert (col["final_cost"][col["controller"] == "clairvoyant"] < 0.6).any()  # it would win some cities
    # make the clairvoyant the lowest of every city: still never counted
    cost = np.where(col["controller"] == "clairvoyant", 0.01, col["final_cost"])
    results = results.set_column(results.column_names.index("final_cost"), "final_cost", pa.array(cost))
    want_best, want_counts = direct_best(results)
    summary = summarize(results, "cities")
    best = summary["best"]
    assert {g: set(cs) for g, cs in best["best"].items()} == want_best
    assert best["counts"] == {c: want_counts.get(c, 0) for c in ("dcvt", "lpac", "madp", "madp:r4")}
    assert best["groups"] == len(CITIES) and sum(best["counts"].values()) == len(CITIES)
    assert best["excluded"] == ["clairvoyant"]

    md = markdown_table(summary)
    for c, k in best["counts"].items():
        name = {"dcvt": "DCVT", "lpac": "LPAC-K3", "madp": "MADP", "madp:r4": "MADP:r4"}[c]
        assert f"| {name} | {k} of {len(CITIES)} cities |" in md
    assert "Clairvoyant (an oracle" in md and "not counted" in md

    # The heat map: one red dot per (city, best controller), at that cell.
    fig = cities_heatmap_figure(summary, "cities")
    dots = [c for c in fig.axes[0].collections if isinstance(c, PathCollection)]
    assert len(dots) == 1 and np.allclose(dots[0].get_facecolor()[0][:3], [0xE4 / 255, 0x1A / 255, 0x1C / 255])
    at = {(round(x - 0.32), round(y)) for x, y in dots[0].get_offsets()}
    ctrl, grp = summary["controllers"], summary["groups"]
    assert at == {(ctrl.index(c), grp.index(g)) for g, cs in want_best.items() for c in cs}
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert labels[0] == "Clairvoyant\n(not counted)"
    assert labels[ctrl.index("madp")] == f"MADP\nbest in {want_counts.get('madp', 0)}/{len(CITIES)}"

    # write_report puts it in summary.json and summary.md
    files = write_report(write_suite(tmp_path / "cities", curves, results), "cities")
    doc = strict_json(files["summary.json"])
    assert doc["best"]["counts"] == best["counts"]
    assert "Best controller per city" in files["summary.md"].read_text()
    assert BEST_MARKER["color"] == "#e41a1c"


def test_a_tie_counts_for_both_and_other_suites_count_nothing():
    s = {"suite": "cities", "controllers": ["dcvt", "madp"], "groups": ["a", "b"],
         "by_group": {"a": {"dcvt": {"mean": 0.4}, "madp": {"mean": 0.4}}, "b": {"dcvt": {"mean": 0.5}}}}
    assert best_per_group(s) == {"best": {"a": ["dcvt", "madp"], "b": ["dcvt"]}, "counts": {"dcvt": 2, "madp": 1},
                                 "groups": 2, "excluded": []}
    _, results = make_suite("sigma", {"sigma_5-10": {}}, n_envs=2)
    assert "best" not in summarize(results, "sigma")


def test_both_panels_of_fig7_share_one_scale_and_a_missing_baseline_is_skipped(tmp_path):
    groups = {f"N{n}_F{f}": {"num_robots": n, "num_features": f} for n in (16, 64) for f in (32, 128)}
    _, results = make_suite("scale", groups, controllers=("dcvt", "lpac", "madp"), n_envs=2)
    files = write_report(write_suite(tmp_path / "scale", None, results), "scale")
    assert {"scale_improvement_dcvt.png", "scale_improvement_lpac.png"} <= set(files)
    mats = [scale_improvement_matrix(results, b, "madp") for b in ("dcvt", "lpac")]
    lim = scale_limit(mats)
    assert lim == pytest.approx(max(np.nanmax(np.abs(m["improvement"])) for m in mats))
    for m in mats:
        norm = scale_improvement_figure(m, "scale", lim).axes[0].images[0].norm
        assert (norm.vmin, norm.vmax) == (-lim, lim)
    # no LPAC-K3 in the run: the DCVT panel alone, no error
    col = columns(results)
    no_lpac = results.filter(pa.array(col["controller"] != "lpac"))
    files2 = write_report(write_suite(tmp_path / "scale2", None, no_lpac), "scale")
    assert "scale_improvement_dcvt.png" in files2 and "scale_improvement_lpac.png" not in files2
    assert list(strict_json(files2["summary.json"])["scale_improvement"]) == ["dcvt"]


def test_the_uniform_plot_shades_the_95_percent_band_of_its_curves():
    curves, _ = make_suite("uniform", {"uniform": {}}, controllers=("dcvt", "madp", "madp:r4"), n_envs=5, steps=8)
    col = columns(curves)
    bands = cost_curve_bands(col["controller"], col["env"], col["step"], col["cost"])
    assert list(bands) == ["dcvt", "madp", "madp:r4"]
    for c, b in bands.items():  # mean ± 1.96·SE over the five environments, at every step
        cube = np.full((5, 9), np.nan)
        m = col["controller"] == c
        cube[col["env"][m], col["step"][m]] = col["cost"][m]
        se = cube.std(axis=0, ddof=1) / np.sqrt(5)
        np.testing.assert_allclose(b["se"], se, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(b["hi"] - b["mean"], 1.959963984540054 * se, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(b["mean"] - b["lo"], 1.959963984540054 * se, rtol=1e-9, atol=1e-15)
    fig = cost_figure(bands, "uniform", color_map(list(bands)))
    ax = fig.axes[0]
    shaded = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert len(shaded) == len(bands)
    for poly, (name, b) in zip(shaded, bands.items()):
        xy = poly.get_paths()[0].vertices
        assert np.all(b["hi"][1:] - b["lo"][1:] > 0)  # five environments: a band, not a line (J(0)/J(0) = 1)
        for x, lo, hi in zip(b["step"], b["lo"], b["hi"]):  # the polygon runs along lo and back along hi
            ys = xy[np.isclose(xy[:, 0], x), 1]
            assert np.isclose(ys.min(), lo) and np.isclose(ys.max(), hi)
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend[2].startswith("MADP:r4 (final ")
    assert "mean ± 1.96·SE" in ax.get_legend().get_title().get_text()


def test_symmetry_check_against_pandas_and_in_the_report(tmp_path):
    """The symmetry suite's check: each image's mean against the layout's mean over its images,
    within the image's SE or not, counted per layout; in summary.json, summary.md and symmetry.png."""
    groups = {f"{lay}_d4-{g}": {"launch": lay} for lay in ("line", "square") for g in range(8)}
    curves, results = make_suite("symmetry", groups, controllers=("lpac", "madp"), n_envs=4, steps=3, seed=5)
    df = results.to_pandas()
    df["layout"] = df.group.str.split("_d4-").str[0]
    df["image"] = df.group.str.split("_d4-").str[1].astype(int)
    summary = summarize(results, "symmetry")
    check = summary["symmetry"]
    assert set(check) == {"lpac", "madp"} and set(check["madp"]) == {"line", "square"}
    for (c, lay), x in df.groupby(["controller", "layout"]):
        per = x.groupby("image").final_cost.agg(["mean", "std", "count"])
        layout_mean = per["mean"].mean()
        se = per["std"] / np.sqrt(per["count"])
        got = check[c][lay]
        assert got["mean"] == pytest.approx(layout_mean, rel=1e-12)
        for g, row in per.iterrows():
            r = got["by_image"][g]
            assert r["deviation"] == pytest.approx(row["mean"] - layout_mean, abs=1e-12)
            assert r["se"] == pytest.approx(se[g], rel=1e-9)
            assert r["within_se"] == (abs(row["mean"] - layout_mean) <= se[g])
        assert got["within"] == int((np.abs(per["mean"] - layout_mean) <= se).sum()) and got["images"] == 8
        cube = x.pivot(index="env", columns="image", values="final_cost")  # env by env: image g vs the others
        d = cube.sub((cube.sum(axis=1).to_numpy()[:, None] - cube) / 7)
        for g in range(8):
            p = got["by_image"][g]["paired"]
            assert p["diff"] == pytest.approx(d[g].mean(), abs=1e-12) and p["n"] == 4
            assert p["se"] == pytest.approx(d[g].std() / 2, rel=1e-9)
            assert p["z"] == pytest.approx(d[g].mean() / (d[g].std() / 2), rel=1e-9)
        zmax = (d.mean() / (d.std() / 2)).abs().max()
        assert got["max_abs_z"] == pytest.approx(zmax, rel=1e-9)
        assert got["familywise_p"] == pytest.approx(1 - (1 - 2 * scipy_stats.t.sf(zmax, 3)) ** 8, rel=1e-9)
    # some images in, some out: the synthetic costs are noise, so the test can tell the two apart
    flags = [r["within_se"] for per in check.values() for lay in per.values() for r in lay["by_image"].values()]
    assert any(flags) and not all(flags)
    # a policy that costs the same on every image is within on all of them
    cost = df.final_cost.to_numpy() * 0 + df.env.to_numpy() * 0.1 + 0.2
    flat = results.set_column(results.column_names.index("final_cost"), "final_cost", pa.array(cost))
    flat_check = summarize(flat, "symmetry")["symmetry"]
    assert all(lay["within"] == 8 for per in flat_check.values() for lay in per.values())
    # one image costing more in every environment stands out paired, although within its SE unpaired
    shifted = cost + np.where(df.group.to_numpy() == "line_d4-3", 0.01, 0.0) + df.env.to_numpy() * 0.05
    shifted = results.set_column(results.column_names.index("final_cost"), "final_cost", pa.array(shifted))
    line = summarize(shifted, "symmetry")["symmetry"]["madp"]["line"]
    assert line["by_image"][3]["within_se"] and line["by_image"][3]["paired"]["z"] > 1e6
    assert line["familywise_p"] < 1e-6
    assert "symmetry" not in summarize(make_suite("launch", {"line": {"launch": "line"}}, n_envs=2)[1], "launch")

    files = write_report(write_suite(tmp_path / "symmetry", curves, results), "symmetry")
    assert "symmetry.png" in files
    doc = strict_json(files["summary.json"])
    assert doc["symmetry"]["madp"]["line"]["within"] == check["madp"]["line"]["within"]
    md = files["summary.md"].read_text()
    assert f"| MADP | line | {check['madp']['line']['mean']:.3f} |" in md
    assert f"{check['madp']['square']['within']} of 8 |" in md
