"""Named controllers: several checkpoints of one kind in one evaluation (``--controllers
madp,madp:a=PATH,madp:b=PATH``): their names in every output, resume, the checksum guard, compare,
and one-line errors for bad specs."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from madp.controllers import display_name, file_stem, make_controller, parse_controllers
from madp.io.checksum import sha256_file
from madp.errors import SettingError
from madp.models import MADP, madp_config
from madp.training.checkpoint import save_policy
from tests.eval.conftest import META
from tests.test_reliability_errors import assert_one_line, cli


def test_parse_controllers():
    names, paths = parse_controllers("dcvt, madp,madp:r4=runs/r4/policy.safetensors,lpac:old=x.safetensors")
    assert names == ("dcvt", "madp", "madp:r4", "lpac:old")
    assert paths == {"madp:r4": "runs/r4/policy.safetensors", "lpac:old": "x.safetensors"}
    assert (display_name("madp:r4"), display_name("madp_central:r4"), display_name("lpac:old")) == \
        ("MADP:r4", "MADP (central):r4", "LPAC-K3:old")
    assert file_stem("madp:r4") == "madp@r4" and file_stem("madp") == "madp"
    for spec, words in (("madp:=x", "checkpoint name"), ("foo:x=y", "KIND:NAME"), ("madp:r4", "expected madp:r4=PATH"),
                        ("madp:a=x,madp:a=y", "given twice"), ("madp,madp", "given twice"),
                        ("madp:r/4=x", "letters, digits"), ("madp:a.b=x", "letters, digits"),
                        ("madp:-a=x", "first a letter"), ("dcvt:x=y", "dcvt takes none"), ("dcvt=x", "takes no checkpoint"),
                        ("madp_central=x", "--madp PATH"), ("dcvt,,madp", "comma-separated")):
        with pytest.raises(SettingError, match="^controllers: ") as e:
            parse_controllers(spec)
        assert words in str(e.value), (spec, str(e.value))
    with pytest.raises(SettingError, match="named checkpoint"):
        make_controller("madp:r4")  # never the shipped checkpoint under another name


@pytest.fixture(scope="module")
def two(tmp_path_factory, checkpoints):
    """Two MADP checkpoints: ``a`` is the file given as ``--madp`` too, ``b`` other weights."""
    d = tmp_path_factory.mktemp("named")
    shutil.copy(checkpoints / "madp.safetensors", d / "a.safetensors")
    torch.manual_seed(1)
    model = MADP(madp_config("cpu"))
    model.set_action_stats(torch.zeros(2), torch.full((2,), 2.0))
    save_policy(d / "b.safetensors", model, "madp", META)
    return d


def _eval(out, checkpoints, two, *more, controllers=None):
    controllers = controllers or f"dcvt,madp,madp:a={two / 'a.safetensors'},madp:b={two / 'b.safetensors'}"
    return cli("eval", "--suite", "uniform", "--num-envs", 2, "--steps", 10, "--workers", 1, "--sampling-steps", 2,
               "--record", 1, "--out", out, "--madp", checkpoints / "madp.safetensors", "--controllers", controllers, *more)


def _stamps(d):
    return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in (d / "jobs").glob("*.npz")}


def test_two_named_madp_checkpoints_in_one_run(tmp_path, checkpoints, two):
    code, err = _eval(tmp_path, checkpoints, two)
    assert code == 0, err
    d = tmp_path / "uniform"
    res = pq.read_table(d / "results.parquet").to_pandas()
    assert sorted(set(res.controller)) == ["dcvt", "madp", "madp:a", "madp:b"] and len(res) == 8
    cost = {c: g.sort_values("env").final_cost.to_numpy() for c, g in res.groupby("controller")}
    np.testing.assert_array_equal(cost["madp:a"], cost["madp"])  # the same file as --madp: the same rollouts
    assert np.abs(cost["madp:b"] - cost["madp"]).max() > 1e-6  # its own checkpoint, not --madp's
    assert (res[res.controller.str.startswith("madp")].sampling_steps == 2).all()
    curves = pq.read_table(d / "curves.parquet").to_pandas()
    assert {"madp:a", "madp:b"} <= set(curves.controller)
    md = (d / "summary.md").read_text()
    assert "| MADP | MADP:a | MADP:b |" in md
    assert set(json.loads((d / "summary.json").read_text())["overall"]) == {"dcvt", "madp", "madp:a", "madp:b"}
    saved = json.loads((d / "config.json").read_text())["checkpoints"]
    assert set(saved) == {"madp", "madp:a", "madp:b"}
    for name in ("a", "b"):
        assert saved[f"madp:{name}"] == {"path": str(two / f"{name}.safetensors"),
                                         "sha256": sha256_file(two / f"{name}.safetensors")}
    from mcap.reader import make_reader

    with open(d / "rollouts" / "uniform-000-madp@b.mcap", "rb") as f:
        assert {m.name: m.metadata for m in make_reader(f).iter_metadata()}["madp.rollout"]["controller"] == "madp:b"

    # Interrupted: two jobs of the named controllers missing. The same command runs only those.
    stamps = _stamps(d)
    for f in ("uniform-001-madp@a.npz", "uniform-001-madp@b.npz"):
        (d / "jobs" / f).unlink()
    code, err = _eval(tmp_path, checkpoints, two)
    assert code == 0, err
    again = _stamps(d)
    assert sorted(n for n in again if again[n] != stamps.get(n)) == ["uniform-001-madp@a.npz", "uniform-001-madp@b.npz"]
    after = pq.read_table(d / "results.parquet").to_pandas()
    assert sorted(set(after.controller)) == ["dcvt", "madp", "madp:a", "madp:b"]
    np.testing.assert_array_equal(after.final_cost, res.final_cost)

    # madp:b's file now holds other weights: refused in one line; --overwrite re-runs only madp:b.
    shutil.copy(two / "b.safetensors", tmp_path / "b-old.safetensors")
    shutil.copy(two / "a.safetensors", two / "b.safetensors")
    try:
        assert_one_line(*_eval(tmp_path, checkpoints, two), "madp:b checkpoint", "--overwrite")
        stamps = _stamps(d)
        code, err = _eval(tmp_path, checkpoints, two, "--overwrite")
        assert code == 0, err
    finally:
        shutil.copy(tmp_path / "b-old.safetensors", two / "b.safetensors")
    again = _stamps(d)
    assert sorted(n for n in again if again[n] != stamps[n]) == ["uniform-000-madp@b.npz", "uniform-001-madp@b.npz"]
    res = pq.read_table(d / "results.parquet").to_pandas()
    np.testing.assert_array_equal(res[res.controller == "madp:b"].final_cost, res[res.controller == "madp"].final_cost)


def test_compare_pairs_named_controllers_by_name(tmp_path, checkpoints, two):
    """Run y swaps the two named checkpoints: compare pairs madp:a of y with madp:a of x, so its
    difference is x's madp:b − madp:a on each environment."""
    a, b = two / "a.safetensors", two / "b.safetensors"
    assert _eval(tmp_path / "x", checkpoints, two, controllers=f"madp:a={a},madp:b={b}")[0] == 0
    assert _eval(tmp_path / "y", checkpoints, two, controllers=f"madp:a={b},madp:b={a}")[0] == 0
    code, err = cli("eval", "compare", tmp_path / "x" / "uniform", tmp_path / "y" / "uniform", "--out", tmp_path / "cmp")
    assert code == 0, err
    doc = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert doc["controllers"] == ["madp:a", "madp:b"]
    assert {"madp:a checkpoint", "madp:b checkpoint"} <= set(doc["differing_settings"])
    x = pq.read_table(tmp_path / "x" / "uniform" / "results.parquet").to_pandas()
    per = {c: g.sort_values("env").final_cost.to_numpy() for c, g in x.groupby("controller")}
    want = (per["madp:b"] - per["madp:a"]).mean()
    got = doc["by_controller"]["madp:a"]["groups"]["uniform"]["paired"]["y"]["diff"]
    assert got == pytest.approx(want, abs=1e-12) and abs(want) > 1e-6


def test_bad_named_specs_are_one_line(tmp_path, checkpoints):
    def run(spec):
        return cli("eval", "--out", tmp_path, "--num-envs", 1, "--steps", 2, "--controllers", spec)

    assert_one_line(*run("madp:=x"), "--controllers", "checkpoint name")
    assert_one_line(*run(f"madp:r4={tmp_path / 'missing.safetensors'}"), "missing.safetensors", "madp:r4")
    assert_one_line(*run(f"madp:r4={checkpoints / 'lpac.safetensors'}"), "lpac.safetensors", "expected madp")
    ck = checkpoints / "madp.safetensors"
    assert_one_line(*run(f"madp:r4={ck},madp:r4={ck}"), "--controllers", "given twice")
    assert_one_line(*run("foo:x=y"), "--controllers", "foo:x")
    assert_one_line(*run(f"madp:r 4={ck}"), "--controllers", "letters, digits")
    assert not (tmp_path / "uniform").exists()  # refused before anything was written


def test_rollout_takes_a_named_controller(tmp_path, two):
    from madp.eval.suites import suite_envs

    suite_envs("uniform", 1)[0].scenario().save(tmp_path / "s.json")
    code, err = cli("rollout", "--scenario", tmp_path / "s.json", "--controller", "madp:b", "--checkpoint",
                    two / "b.safetensors", "--steps", 3, "--out", tmp_path / "r.json")
    assert code == 0, err
    assert json.loads((tmp_path / "r.json").read_text())["controller"] == "madp:b"
    assert_one_line(*cli("rollout", "--scenario", tmp_path / "s.json", "--controller", "madp:b", "--steps", 3,
                         "--out", tmp_path / "r2.json"), "--checkpoint", "madp:b")
