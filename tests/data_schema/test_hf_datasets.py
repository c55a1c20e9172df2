"""Hugging Face datasets reads a Parquet dataset of madp datagen; the guide's recipe decodes the same O as madp."""

import re
import textwrap
from pathlib import Path

import datasets
import numpy as np

from madp.data_schema.dataset import iter_split, open_dataset
from tests.test_reliability_errors import cli

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "datasets.md"


def readme_recipe() -> str:
    """The guide's Python block that loads a dataset with ``datasets`` (exactly one)."""
    blocks = [textwrap.dedent(b) for b in re.findall(r"```python\n(.*?)```", GUIDE.read_text(), re.S)
              if "load_dataset" in b]
    assert len(blocks) == 1, f"expected one Hugging Face recipe in the guide, found {len(blocks)}"
    return blocks[0]


def test_readme_recipe_decodes_what_madp_decodes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(datasets.config, "HF_DATASETS_CACHE", tmp_path / "hf-cache")  # not the user's cache
    code, err = cli("datagen", "--n", 48, "--format", "parquet", "--out", "data", "--workers", 1, "--num-robots", 4,
                    "--num-features", 4, "--world-size", 256, "--samples-per-shard", 16)
    assert code == 0, err
    manifest = open_dataset("data")
    assert len(manifest.splits["train"].shards) > 1  # the rows of several shards, in their order
    ns: dict = {}
    exec(compile(readme_recipe(), "docs/guides/datasets.md (datasets)", "exec"), ns)
    ds, first = ns["ds"], ns["observations"]
    assert first.shape == (4, 4, 32, 32) and first.dtype == np.float16
    ours = {k: np.concatenate([getattr(b, k) for b in iter_split("data", manifest, "train")])
            for k in ("episode_id", "step", "scenario_seed", "actions", "positions", "observations")}
    n = len(ours["step"])
    assert ds.num_rows == n == manifest.splits["train"].num_samples
    np.testing.assert_array_equal(first, ours["observations"][0])
    # every sample, every column, bit for bit
    decoded = np.frombuffer(b"".join(ds["observations"]), "<f2").reshape(n, -1, 4, 32, 32)
    assert decoded.tobytes() == ours["observations"].tobytes() and ours["observations"].any()
    for k in ("episode_id", "step", "scenario_seed"):
        np.testing.assert_array_equal(np.asarray(ds[k]), ours[k])
    for k in ("actions", "positions"):
        got = np.asarray(ds[k], dtype=np.float32).reshape(n, -1, 2)
        assert got.tobytes() == ours[k].astype(np.float32).tobytes()
