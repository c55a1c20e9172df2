"""Frames (madp.render) and MP4 videos (madp.video): what is drawn, and files read back with OpenCV."""

from __future__ import annotations

import numpy as np
import pytest

from madp.io.atomic import is_temp
from madp.render import FrameRenderer, render_frame, robot_colors, status_line, text_mask
from madp.sim import CoverageEnv, DecentralizedCVT, Scenario, SimParams, rollout

cv2 = pytest.importorskip("cv2")

SMALL = SimParams(world_size=128, local_map_size=64, sensor_size=16, num_robots=4, num_features=3,
                  sigma_range_m=(10.0, 20.0), comm_radius_m=48.0)


def read_video(path) -> list[np.ndarray]:
    """Every frame of an MP4, RGB."""
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame[..., ::-1])
    cap.release()
    return frames


def assert_video(path, frames: int, size: int) -> list[np.ndarray]:
    """``path`` is an MP4 of ``frames`` frames of size × size that are not one colour."""
    got = read_video(path)
    assert len(got) == frames
    assert all(f.shape == (size, size, 3) for f in got)
    assert all(len(np.unique(f.reshape(-1, 3), axis=0)) > 10 for f in got)
    cap = cv2.VideoCapture(str(path))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == frames
    cap.release()
    return got


@pytest.fixture(scope="module")
def small_rollout():
    env = CoverageEnv(Scenario.random(3, SMALL))
    r = rollout(env, DecentralizedCVT(), 8)
    return env.world_map, r.positions_m, r.normalized_cost


def test_text_is_drawn_in_the_bitmap_font():
    m = text_mask("t=12", 2)
    assert m.shape == (14, 4 * 12) and m.any()
    assert not text_mask(" ", 1).any()
    assert status_line(12, 0.43219) == "t=12  J(t)/J(0)=0.432"
    world = np.zeros((128, 128))
    world[40:60, 40:60] = 1.0
    plain = render_frame(world, np.array([[100.0, 20.0]]), 256)
    labelled = render_frame(world, np.array([[100.0, 20.0]]), 256, step=7, cost=0.5)
    top = labelled[:20, :150]
    assert (top == 0).all(axis=2).sum() > 50  # black text at the top left
    np.testing.assert_array_equal(labelled[40:], plain[40:])  # and nowhere else


def test_trails_in_the_robots_colours(small_rollout):
    world, pos, cost = small_rollout
    r = FrameRenderer(world, 128)
    bare = r(pos[-1])
    trailed = r(pos[-1], pos)
    changed = (bare != trailed).any(axis=2)
    assert changed.sum() >= 4  # every robot moved at least a pixel or two
    colours = {tuple(c) for c in (robot_colors(4) * 255 * 0.8).astype(np.uint8)}
    assert {tuple(c) for c in trailed[changed]} <= colours


def test_rollout_video_reads_back(tmp_path, small_rollout):
    from madp.video import rollout_frames, write_rollout_video

    world, pos, cost = small_rollout
    out = tmp_path / "sub" / "r.mp4"
    info = write_rollout_video(out, world, pos, cost, size=128)
    assert info["frames"] == 9 and (info["width"], info["height"]) == (128, 128) and info["bytes"] > 0
    got = assert_video(out, 9, 128)
    want = list(rollout_frames(world, pos, cost, 128))
    assert np.abs(got[5].astype(int) - want[5]).mean() < 12  # the same picture, up to MPEG-4's loss
    assert not [p for p in out.parent.iterdir() if is_temp(p)]


def test_video_paths_are_checked(tmp_path):
    from madp.video import check_video_path

    with pytest.raises(ValueError, match=r"\.mp4"):
        check_video_path(tmp_path / "r.avi")
    (tmp_path / "file").write_text("x")
    with pytest.raises(OSError, match="file"):
        check_video_path(tmp_path / "file" / "r.mp4")  # under a file: no directory can be made
    (tmp_path / "d.mp4").mkdir()
    with pytest.raises(IsADirectoryError):
        check_video_path(tmp_path / "d.mp4")
    assert check_video_path(tmp_path / "new" / "r.MP4").parent.is_dir()
    assert not [p for p in (tmp_path / "new").iterdir()]  # the probe is gone


def test_write_video_refuses_mixed_sizes_and_leaves_nothing(tmp_path):
    from madp.video import write_video

    frames = [np.zeros((32, 32, 3), np.uint8), np.zeros((16, 16, 3), np.uint8)]
    with pytest.raises(ValueError, match="shape"):
        write_video(tmp_path / "x.mp4", frames)
    assert list(tmp_path.iterdir()) == []
