"""Float16 checkpoints split into checksummed parts (madp.policies.parts): written, joined by the
policy loader everywhere (eval, rollout, --init, datagen --policy), refused by name when damaged."""

import json

import pytest
import torch
from safetensors import safe_open

from madp.models import MADP, madp_config
from madp.policies.fp16 import main
from madp.policies.parts import INDEX_SUFFIX, MAX_PART_BYTES, write_fp16
from madp.training.checkpoint import load_policy, save_policy
from tests.test_reliability_errors import assert_one_line, cli

META = {"action_stats": {"count": 1, "mean": [0.1, -0.2], "std": [1.5, 2.5]}, "step": 7}


def policy(tmp_path, preset: str):
    """A well-formed policy file of ``preset`` with random weights: (path, model)."""
    torch.manual_seed(0)
    model = MADP(madp_config(preset))
    model.set_action_stats(torch.tensor([0.1, -0.2]), torch.tensor([1.5, 2.5]))
    path = tmp_path / f"{preset}.safetensors"
    save_policy(path, model, "madp", META)
    return path, model


def metadata(path) -> dict:
    with safe_open(str(path), framework="pt") as f:
        return dict(f.metadata())


def assert_fp16_copy(model, loaded) -> None:
    """``loaded`` is ``model`` with its parameters rounded to float16 (and back to float32) and its
    buffers exact."""
    params = dict(model.named_parameters())
    want, got = model.state_dict(), loaded.state_dict()
    assert want.keys() == got.keys()
    for k, v in got.items():
        assert v.dtype == want[k].dtype  # float32 again
        if k in params:
            assert torch.equal(v, want[k].half().float()), k
        else:
            assert torch.equal(v, want[k]), k


def test_the_paper_model_splits_into_16_mib_parts_that_load_as_float32(tmp_path):
    src, model = policy(tmp_path, "paper")
    files = write_fp16(model, metadata(src), tmp_path / "out" / "policy-fp16.safetensors")
    index = tmp_path / "out" / ("policy-fp16.safetensors" + INDEX_SUFFIX)
    assert files[0] == index and [p.name for p in files[1:]] == [f"policy-fp16.safetensors.{i:03d}" for i in range(len(files) - 1)]
    sizes = [p.stat().st_size for p in files[1:]]
    assert len(sizes) >= 2 and max(sizes) <= MAX_PART_BYTES
    assert sum(sizes) < src.stat().st_size * 0.55  # float16: about half the float32 file
    for name in (index, files[1], files[-1]):  # the index, the first part or any part
        loaded, meta = load_policy(name)
        assert_fp16_copy(model, loaded)
        assert meta["weights_dtype"] == "float16" and meta["step"] == 7 and meta["kind"] == "madp"
    doc = json.loads(index.read_text())
    assert doc["bytes"] == sum(sizes) and [p["bytes"] for p in doc["parts"]] == sizes


def test_a_small_model_is_written_whole_and_loads_everywhere(tmp_path):
    src, model = policy(tmp_path, "cpu")
    out = tmp_path / "small.safetensors"
    assert main([str(src), str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cpu.safetensors", "small.safetensors"]
    loaded, meta = load_policy(out)
    assert_fp16_copy(model, loaded)
    assert main([str(src), str(out)]) == 2  # never replaces what is there
    # split, and used by the commands: a rollout and an evaluation take the index or a part
    assert main([str(src), str(tmp_path / "p.safetensors"), "--part-mib", "0.2"]) == 0
    index = tmp_path / ("p.safetensors" + INDEX_SUFFIX)
    code, err = cli("rollout", "--scenario", scenario(tmp_path), "--controller", "madp", "--checkpoint", index,
                    "--steps", "2", "--out", tmp_path / "r.json")
    assert code == 0, err
    code, err = cli("eval", "--suite", "uniform", "--num-envs", "2", "--steps", "2", "--controllers", "madp",
                    "--madp", tmp_path / "p.safetensors.001", "--workers", "1", "--out", tmp_path / "eval")
    assert code == 0, err
    assert json.loads((tmp_path / "eval" / "uniform" / "config.json").read_text())["device"] == "cpu"


def scenario(tmp_path):
    from madp.sim import Scenario

    path = tmp_path / "s.json"
    Scenario.random(0).save(path)
    return path


def test_damaged_missing_or_unindexed_parts_are_one_line_errors(tmp_path):
    src, _ = policy(tmp_path, "cpu")
    assert main([str(src), str(tmp_path / "p.safetensors"), "--part-mib", "0.2"]) == 0
    index = tmp_path / ("p.safetensors" + INDEX_SUFFIX)
    part = tmp_path / "p.safetensors.001"
    good = part.read_bytes()

    def refused(*needles):
        assert_one_line(*cli("eval", "--suite", "uniform", "--controllers", "madp", "--madp", index,
                             "--out", tmp_path / "e"), *needles)

    part.write_bytes(good[:-10])
    refused("p.safetensors.001", "part 2 of", "truncated")
    part.write_bytes(good[:100] + bytes([good[100] ^ 1]) + good[101:])
    refused("p.safetensors.001", "damaged")
    part.unlink()
    refused("p.safetensors.001", "missing")
    part.write_bytes(good)
    load_policy(index)  # whole again
    doc = json.loads(index.read_text())
    index.write_text(json.dumps({**doc, "parts": [{**doc["parts"][0], "name": "../p.safetensors.000"}]}))
    refused("p.safetensors.parts.json", "malformed")
    index.write_text("{")
    refused("p.safetensors.parts.json", "not a readable index")
    index.unlink()
    assert_one_line(*cli("eval", "--suite", "uniform", "--controllers", "madp", "--madp", tmp_path / "p.safetensors.000",
                         "--out", tmp_path / "e"), "p.safetensors.parts.json", "missing")


def test_a_weight_beyond_float16_is_refused_by_name(tmp_path):
    src, model = policy(tmp_path, "cpu")
    with torch.no_grad():
        model.head.weight[0, 0] = 1e6
    with pytest.raises(ValueError, match="head.weight"):
        write_fp16(model, metadata(src), tmp_path / "x.safetensors")
    assert not (tmp_path / "x.safetensors").exists()
