"""madp bench infer --roofline: the analytic FLOPs and bytes of the control step's model parts are what
torch counts on the same calls, the parts make up the whole decentralized call, and the table holds
every part with fractions of peak in (0, 1] or flagged (structure, not speed)."""

import json

import pytest
import torch

from madp.inference_bench.roofline import MODEL_PARTS, PARTS, format_roofline, model_costs, model_parts
from madp.models import MADP
from madp.models.bench import count_bytes, count_flops, random_swarm
from madp.policies import SamplingSettings
from tests.models.models_testutils import tiny_madp_config
from tests.test_reliability_errors import cli


@pytest.mark.parametrize("overrides,layout,sampling", [
    ({}, "uniform", SamplingSettings()),
    ({"cnn_norm": "none", "mlp_ratio": 2, "time_embed_dim": 16, "n_dec_layers": 3}, "square",
     SamplingSettings(sampler="ddim", sampling_steps=2, select="oracle_cell", candidates=3)),
])
def test_analytic_costs_are_what_torch_counts(overrides, layout, sampling):
    torch.manual_seed(0)
    model = MADP(tiny_madp_config(**overrides)).eval()
    obs, pos, _ = random_swarm(1, 12, world=1024.0 if layout == "uniform" else 150.0,
                               generator=torch.Generator().manual_seed(1))
    parts, lay = model_parts(model, obs, pos, sampling)
    assert lay.tokens <= lay.rows * lay.row_len and lay.units <= lay.robots <= lay.tokens
    if layout == "square":
        assert lay.units == 1 and lay.tokens == 12  # everyone within r_c: one neighbourhood
    costs = model_costs(model.config, lay)
    assert set(costs) == set(MODEL_PARTS) == set(parts)
    with torch.inference_mode():
        for part, fn in parts.items():
            assert costs[part][0] == pytest.approx(count_flops(fn), rel=0.02), part
            assert costs[part][1] == pytest.approx(count_bytes(fn), rel=0.02), part
        whole = count_flops(lambda: model.sample_decentralized(obs, pos, sampling.sampling_steps, sampling.eta,
                                                                sampler=sampling.sampler, copies=sampling.candidates))
    assert sum(c[0] for c in costs.values()) == pytest.approx(whole, rel=0.02)  # the parts are the whole call


def _check_table(r: dict) -> None:
    assert len(r["states"]) == 2 and r["sampling"]["candidates"] == SamplingSettings().candidates
    for st in r["states"]:
        rows = {x["part"]: x for x in st["parts"]}
        assert list(rows) == [*PARTS, "other", "control step"]
        assert rows["control step"]["flops"] == sum(rows[p]["flops"] for p in PARTS) > 0
        for part in PARTS:
            x = rows[part]
            assert x["flops"] > 0 and x["bytes"] > 0 and x["bound"] in ("memory", "compute")
            for dtype in ("float32", "bfloat16") if part in MODEL_PARTS else ("float32",):
                v = x[dtype]
                assert v["time_s"] > 0
                assert 0 < v["fraction"] <= 1 or v["flag"], (part, dtype, v)
            assert (x["bfloat16"] is None) == (part not in MODEL_PARTS)
    for p in r["peaks"]["cpu"]["matmul"]:
        assert p["flops_per_s"] > 0 and p["dtype"] in ("float32", "bfloat16")
    assert r["machine"]["torch_capability"] and r["peaks"]["cpu"]["copy_bytes_per_s"] > 0
    lines = "\n".join(format_roofline(r))
    assert all(f"\n{p}" in lines for p in [*PARTS, "other", "control step"]) and "peaks on cpu" in lines


def test_bench_infer_roofline_cli_prints_and_writes_every_part(tmp_path):
    out = tmp_path / "r.json"
    code, err = cli("bench", "infer", "--roofline", "--no-sweep", "--presets", "cpu", "--grid", "dpm++:1",
                    "--repeats", "1", "--no-robot", "--roofline-after", "2", "--out", out)
    assert code == 0, err
    r = json.loads(out.read_text())["roofline"]
    _check_table(r)
    assert r["load_average"]["before"] is not None and r["repeats"] == 1
