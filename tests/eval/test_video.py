"""madp eval --video K: which environments are filmed, the MP4s read back, and filming changes no result."""

import numpy as np
import pyarrow.parquet as pq
import pytest

from madp.eval.runner import EvalConfig, owned_files, run_suite, video_envs
from madp.eval.suites import suite_envs
from tests.test_reliability_errors import cli

pytest.importorskip("cv2")


def test_video_envs_spread_over_the_groups():
    sigma = suite_envs("sigma", 3)  # 4 groups x 3
    assert [(e.group, e.index) for e in video_envs(sigma, 5)] == [
        ("sigma_30-40", 0), ("sigma_20-30", 0), ("sigma_10-20", 0), ("sigma_5-10", 0), ("sigma_30-40", 1)]
    uniform = suite_envs("uniform", 5)
    assert video_envs(uniform, 2) == uniform[:2]
    cities = suite_envs("cities", 40)  # one group per city
    assert video_envs(cities, 3) == cities[:3]
    assert video_envs(uniform, 0) == [] and len(video_envs(uniform, 99)) == 5


def test_eval_writes_videos_and_they_change_no_result(tmp_path, checkpoints):
    """``madp eval --video 2``: the classical controller films its lone rollouts, LPAC-K3 its batch;
    the tables equal those of a run without videos."""
    from tests.test_video import assert_video

    lpac = str(checkpoints / "lpac.safetensors")
    code, err = cli("eval", "--suite", "uniform", "--num-envs", "3", "--steps", "4", "--controllers", "clairvoyant,lpac",
                    "--lpac", lpac, "--workers", "1", "--video", "2", "--out", tmp_path / "with")  # in this process: no start-up
    assert code == 0, err
    d = tmp_path / "with" / "uniform"
    names = sorted(p.name for p in (d / "videos").iterdir())
    assert names == sorted(f"uniform-00{i}-{c}.mp4" for i in (0, 1) for c in ("clairvoyant", "lpac"))
    for name in names:
        assert_video(d / "videos" / name, 5, 512)
    assert set(f"videos/{n}" for n in names) <= set(owned_files(d))  # --overwrite may remove them
    run_suite(EvalConfig(suite="uniform", out=str(tmp_path / "without"), num_envs=3, steps=4, workers=1,
                         controllers=("clairvoyant", "lpac"), lpac=lpac), "uniform", progress=False)
    with_video = pq.read_table(d / "curves.parquet").to_pandas()
    without = pq.read_table(tmp_path / "without" / "uniform" / "curves.parquet").to_pandas()
    np.testing.assert_array_equal(with_video.cost, without.cost)
    with pytest.raises(ValueError, match="video"):  # another --video is another setting
        run_suite(EvalConfig(suite="uniform", out=str(tmp_path / "with"), num_envs=3, steps=4, workers=1,
                             controllers=("clairvoyant", "lpac"), lpac=lpac), "uniform", progress=False)
