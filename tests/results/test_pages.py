"""``madp eval report``: the documentation's results tables come from kept results, and nothing else.

The generator is checked on a small results folder whose figures are computed here directly; the
repository's own pages are checked against its kept results (``docs/results/kept.json``)."""

from __future__ import annotations

import json
import re
import zlib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from madp.cli import app
from madp.errors import InputError
from madp.results.notes import AGREE
from madp.selection import DEFAULT_RULE
from madp.results.pages import END, load_kept, render, replace_blocks, update_pages

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", ROOT / "docs"]


def write_run(root: Path, rel: str, suite: str, groups: dict[str, int], costs: dict[str, np.ndarray],
              seeds_of: str | None = None, rules: dict[str, str] | None = None) -> None:
    """A suite directory of madp eval: ``costs[controller]`` holds one final cost per environment, the
    environments being ``groups``' in order (group → count; an environment's seed depends on its group
    and index alone, as the suites' do, or on group ``seeds_of``'s: the faults suite's are uniform's);
    ``rules``: a ``select`` column, each controller's selection rule (none without)."""
    envs = [(g, i) for g, n in groups.items() for i in range(n)]
    seed = lambda g, i: 1000 * (1 + zlib.crc32((seeds_of or g).encode()) % 1000) + i  # noqa: E731
    rows = [(suite, g, i, seed(g, i), c, float(costs[c][k]), 1.0) for c in costs for k, (g, i) in enumerate(envs)]
    names = ["suite", "group", "env", "scenario_seed", "controller", "final_cost", "mean_step_ms"]
    table = pa.table({n: [r[j] for r in rows] for j, n in enumerate(names)})
    if rules is not None:
        table = table.append_column("select", pa.array([rules.get(r[4], "") for r in rows]))
    (root / rel).mkdir(parents=True)
    pq.write_table(table, root / rel / "results.parquet")
    config = {"suite": suite, "steps": 600, "sampler": "dpm++", "sampling_steps": 3, "select": "explore",
              "candidates": 4, "frame": "d4", "env_keys": [f"{g}-{i:03d}" for g, i in envs],
              "checkpoints": {"madp": {"sha256": "ab" * 32}}}
    (root / rel / "config.json").write_text(json.dumps(config))


@pytest.fixture
def folder(tmp_path):
    rng = np.random.default_rng(0)
    madp, dcvt, option = rng.uniform(0.2, 0.4, 6), rng.uniform(0.5, 0.9, 6), rng.uniform(0.2, 0.4, 6)
    write_run(tmp_path, "mine-1/uniform", "uniform", {"uniform": 6}, {"madp": madp})
    write_run(tmp_path, "base-1/uniform", "uniform", {"uniform": 6}, {"dcvt": dcvt})
    write_run(tmp_path, "opt-1/uniform", "uniform", {"uniform": 6}, {"madp": option})
    spec = {"default": {"dirs": ["mine-1/uniform", "base-1/uniform"]},
            "options": [{"name": "o", "label": "an option", "dirs": ["opt-1/uniform"], "report": "r.md"}],
            "runs": {"mine-1": {"date": "2026-01-01", "commit": "abc1234"}, "base-1": {"date": "2026-01-02", "commit": "def5678"},
                     "opt-1": {"date": "2026-01-03", "commit": "0123456"}}}
    (tmp_path / "kept.json").write_text(json.dumps(spec))
    return tmp_path, madp, dcvt, option


def test_the_tables_hold_the_kept_figures(folder):
    root, madp, dcvt, option = folder
    blocks = render(load_kept(root))
    assert f"| `uniform` (6) | {dcvt.mean():.3f} | **{madp.mean():.3f}** | 0.72 / 0.48 / 0.46 |" in blocks["headline"]
    se = madp.std(ddof=1) / np.sqrt(6)
    assert f"| `uniform` | MADP | {madp.mean():.3f} ± {se:.3f} [" in blocks["default"]
    d = option - madp
    wins = int((d < 0).sum())
    assert (f"| an option | `uniform` | 6 | {option.mean():.3f} | {madp.mean():.3f} | {d.mean():+.3f} ± "
            f"{d.std(ddof=1) / np.sqrt(6):.3f} [") in blocks["options"]
    assert f"| {wins}/6 | [r.md](r.md) |" in blocks["options"]
    assert "| `base-1/uniform` | 6 | DCVT |  |" in blocks["provenance"] and "`def5678`" in blocks["provenance"]


def test_merged_runs_must_share_their_environments_and_not_a_controller(folder):
    root, madp, dcvt, _ = folder
    write_run(root, "base-2/uniform", "uniform", {"uniform": 5}, {"clairvoyant": dcvt[:5]})
    write_run(root, "base-3/uniform", "uniform", {"uniform": 6}, {"dcvt": dcvt})
    spec = json.loads((root / "kept.json").read_text())
    spec["runs"].update({n: {"date": "2026-12-01", "commit": "0000000"} for n in ("base-2", "base-3")})
    for extra, message in (("base-2/uniform", "hold other environments"), ("base-3/uniform", "is in both")):
        spec["default"]["dirs"] = ["mine-1/uniform", "base-1/uniform", extra]
        (root / "kept.json").write_text(json.dumps(spec))
        with pytest.raises(InputError, match=message):
            load_kept(root)


def test_blocks_are_rewritten_between_their_markers_only(folder, tmp_path_factory):
    blocks = render(load_kept(folder[0]))
    page = tmp_path_factory.mktemp("pages") / "page.md"
    page.write_text(f"# A page\n\nbefore\n<!-- generated by madp eval report: headline -->\nstale\n{END}\nafter\n")
    assert update_pages([page.parent], blocks, check=True) == [page]
    assert "stale" in page.read_text()
    assert update_pages([page.parent], blocks) == [page]
    assert page.read_text() == f"# A page\n\nbefore\n<!-- generated by madp eval report: headline -->\n{blocks['headline']}\n{END}\nafter\n"
    assert update_pages([page.parent], blocks, check=True) == []
    with pytest.raises(InputError, match="no generated block 'nope'"):
        replace_blocks("<!-- generated by madp eval report: nope -->\nx\n" + END, blocks, "p.md")
    with pytest.raises(InputError, match="no end marker"):
        replace_blocks("<!-- generated by madp eval report: headline -->\nx\n", blocks, "p.md")


def test_the_command_checks_and_writes(folder, tmp_path_factory):
    page = tmp_path_factory.mktemp("cli") / "p.md"
    page.write_text(f"<!-- generated by madp eval report: cities -->\n{END}\n")
    runner = CliRunner()
    r = runner.invoke(app, ["eval", "report", str(page), "--results", str(folder[0]), "--check"])
    assert r.exit_code == 1 and "differ" in r.output
    r = runner.invoke(app, ["eval", "report", str(page), "--results", str(folder[0])])
    assert r.exit_code == 0 and "No kept `cities` results." in page.read_text()


def test_every_generated_table_in_the_docs_is_what_the_kept_results_give():
    """README's and the site's results tables equal what ``madp eval report`` writes from docs/results."""
    blocks = render(load_kept(ROOT / "docs" / "results"))
    stale = update_pages(PAGES, blocks, check=True)
    assert not stale, f"run madp eval report: {[str(p.relative_to(ROOT)) for p in stale]}"
    canonical = (ROOT / "docs" / "reports" / "results.md").read_text(encoding="utf-8")
    assert all(f"madp eval report: {name} -->" in canonical for name in blocks)
    assert "madp eval report: headline -->" in (ROOT / "README.md").read_text(encoding="utf-8")


FIGURE = re.compile(r"(?<![\w.])0\.\d{3,}")  # a J(T)/J(0) as the tables print it, or longer
BLOCK = re.compile(r"<!-- generated by madp eval report: [\w-]+ -->\n.*?" + re.escape(END), re.S)


def undated_pages() -> list[Path]:
    """README and every page but the reports (dated, they keep their own figures; their index lists
    them by date) and the generated command-line reference; the canonical results page is among them."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    reports, cli = ROOT / "docs" / "reports", ROOT / "docs" / "reference" / "cli.md"
    return [p for p in pages if p != cli and (p.parent != reports or p.name == "results.md")]


def test_no_undated_page_states_a_result_of_its_own():
    """Outside the generated blocks, README and the undated pages state no J(T)/J(0): they link to the
    canonical page, so no page can say another figure for the same thing."""
    assert FIGURE.findall("J = 0.337 and 0.3277, not 10.337 nor v0.123") == ["0.337", "0.3277"]
    assert {p.name for p in undated_pages()} >= {"README.md", "results.md", "training.md"}
    hits = []
    for page in undated_pages():
        text = BLOCK.sub("", page.read_text(encoding="utf-8"))
        hits += [f"{page.relative_to(ROOT)}: {m.group()}" for m in FIGURE.finditer(text)]
    assert not hits, hits


def test_a_controllers_groups_may_come_from_separate_runs(tmp_path):
    rng = np.random.default_rng(1)
    a, b, d = rng.uniform(0.2, 0.4, 4), rng.uniform(0.2, 0.4, 3), rng.uniform(0.5, 0.9, 7)
    write_run(tmp_path, "m-1/faults", "faults", {"ideal": 4}, {"madp": a})
    write_run(tmp_path, "m-2/faults", "faults", {"loss_10": 3}, {"madp": b})
    write_run(tmp_path, "d-1/faults", "faults", {"ideal": 4, "loss_10": 3}, {"dcvt": d})
    runs = {k: {"date": "2026-01-01", "commit": "abc1234"} for k in ("m-1", "m-2/faults", "d-1")}  # a folder of its own
    (tmp_path / "kept.json").write_text(json.dumps({"default": {"dirs": ["m-1/faults", "m-2/faults", "d-1/faults"]},
                                                    "runs": runs}))
    cols = load_kept(tmp_path).default["faults"]
    madp = cols["controller"] == "madp"
    assert sorted(cols["final_cost"][madp].tolist()) == sorted(np.concatenate([a, b]).tolist())
    (tmp_path / "kept.json").write_text(json.dumps({"default": {"dirs": ["m-1/faults", "d-1/faults"]}, "runs": runs}))
    with pytest.raises(InputError, match="madp' on 4 of 7"):
        load_kept(tmp_path)
    write_run(tmp_path, "m-3/faults", "faults", {"ideal": 4}, {"madp": a})
    runs["m-3"] = runs["m-1"]
    (tmp_path / "kept.json").write_text(json.dumps({"default": {"dirs": ["m-1/faults", "m-2/faults", "m-3/faults",
                                                                         "d-1/faults"]}, "runs": runs}))
    with pytest.raises(InputError, match="group 'ideal'.* is in both m-1/faults and m-3/faults"):
        load_kept(tmp_path)


def test_the_network_block_pairs_every_group_with_the_ideal_network(tmp_path):
    rng = np.random.default_rng(2)
    costs = {c: rng.uniform(0.2, 0.9, 10) for c in ("dcvt", "madp")}  # ideal 0-4, loss_30 5-9 (same environments)
    write_run(tmp_path, "f-1/faults", "faults", {"ideal": 5, "loss_30": 5}, costs)
    (tmp_path / "kept.json").write_text(json.dumps({"default": {"dirs": ["f-1/faults"]},
                                                    "runs": {"f-1": {"date": "2026-01-01", "commit": "abc1234"}}}))
    blocks = render(load_kept(tmp_path))
    assert "faults" not in blocks["headline"]  # networks are not scenarios: their own blocks only
    d = {c: v[5:] - v[:5] for c, v in costs.items()}
    se = {c: v.std(ddof=1) / np.sqrt(5) for c, v in d.items()}
    assert f"| ideal: J(600)/J(0) (5) | {costs['dcvt'][:5].mean():.3f} | {costs['madp'][:5].mean():.3f} |" in blocks["network"]
    assert (f"| `loss_30` | {d['dcvt'].mean():+.3f} ± {se['dcvt']:.3f} | {d['madp'].mean():+.3f} ± {se['madp']:.3f} |"
            in blocks["network"])
    assert f"{costs['madp'][5:].mean():.3f}: {d['madp'].mean():+.3f} ± {se['madp']:.3f}" in blocks["network-detail"]


def test_the_network_default_note_names_the_environments_that_end_apart(folder):
    root, madp, dcvt, _ = folder
    ideal = {"madp": madp.copy(), "dcvt": dcvt + AGREE / 100}  # DCVT within rounding, MADP apart on one
    ideal["madp"][1] += 0.01
    write_run(root, "net-1/faults", "faults", {"ideal": 6}, ideal, seeds_of="uniform")
    spec = json.loads((root / "kept.json").read_text())
    spec["default"]["dirs"].append("net-1/faults")
    spec["runs"]["net-1"] = {"date": "2026-01-04", "commit": "fedcba9"}
    (root / "kept.json").write_text(json.dumps(spec))
    note = render(load_kept(root))["network-default"]
    assert note == ("The `ideal` network's environments are the 6 of `uniform` above, with the same seeds; they end "
                    f"where the default's run ends, to 0.001, for DCVT on all 6, MADP on 5 of 6 (`uniform-001` "
                    f"{ideal['madp'][1]:.3f} against {madp[1]:.3f}).")
    # a MADP whose network runs chose by another rule than the default's is named, not paired
    write_run(root, "net-2/faults", "faults", {"ideal": 6}, ideal, seeds_of="uniform", rules={"madp": "explore"})
    spec["default"]["dirs"][-1] = "net-2/faults"
    spec["runs"]["net-2"] = {"date": "2026-01-05", "commit": "fedcba8"}
    (root / "kept.json").write_text(json.dumps(spec))
    assert render(load_kept(root))["network-default"] == (
        "The `ideal` network's environments are the 6 of `uniform` above, with the same seeds; they end where the "
        "default's run ends, to 0.001, for DCVT on all 6; MADP is not paired: it chose among its samples by "
        "`explore` there and by `` in the default's run.")


def test_the_step_time_block_is_the_kept_benchmark_at_the_default(folder):
    root = folder[0]
    runs = render(load_kept(root))["step-time"]  # the kept runs' own times (1 ms a step in write_run)
    assert runs.endswith("| `uniform` | 1.0 | 1.0 | 2026-01-01 `abc1234`, 2026-01-02 `def5678` |") and "One control" not in runs
    step = {"candidates": 4, "select": DEFAULT_RULE, "sampler": "dpm++", "num_steps": 3, "num_robots": 32, "threads": 2,
            "latency_s": 0.01254}
    bench = {"paper_latency_s": 0.36, "selection": [{**step, "select": "cell", "latency_s": 0.02}, step],
             "robot_runtime": {"threads": 1, "mean_neighbourhood": 5.0, "onnxruntime_per_robot_s": 0.00529}}
    (root / "bench.json").write_text(json.dumps(bench))
    spec = json.loads((root / "kept.json").read_text())
    spec["bench"] = {"file": "bench.json", "date": "2026-01-05", "commit": "1234abc", "machine": "2 cores",
                     "command": "madp bench infer --no-sweep"}
    (root / "kept.json").write_text(json.dumps(spec))
    block = render(load_kept(root))["step-time"]
    assert "(N = 32, PyTorch, 2 threads) | 12.5 ms |" in block and "5.0 robots per neighbourhood) | 5.3 ms |" in block
    assert "Measured 2026-01-05 at commit `1234abc` on 2 cores: `madp bench infer --no-sweep`" in block
    assert f"`{DEFAULT_RULE}` among K = 4, DPM-Solver++(2M) S = 3" in block and "The paper's: 0.36 s" in block
    bench["selection"] = bench["selection"][:1]
    (root / "bench.json").write_text(json.dumps(bench))
    with pytest.raises(InputError, match="no decentralized control step at the default"):
        render(load_kept(root))
    del spec["bench"]["commit"]
    (root / "kept.json").write_text(json.dumps(spec))
    with pytest.raises(InputError, match="bench.commit: missing"):
        load_kept(root)
