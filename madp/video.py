"""MP4 videos of rollouts (``madp rollout --video``, ``madp eval --video``), written with OpenCV.

Frame t (t = 0..T) is :class:`madp.render.FrameRenderer`'s frame of the robots at step t, with their
trails from step 0, the step and J(t)/J(0): exactly what the environments' ``render()`` returns at
step t. :data:`VIDEO_FPS` frames per second (the simulator runs 5 steps per simulated second, so a
video plays 6× faster than the swarm moves: 600 steps last 20 s). The codec is MPEG-4 part 2
(fourcc ``mp4v``), the one the headless OpenCV wheels can write; browsers may not play it inline,
desktop players (VLC, mpv, QuickTime) and OpenCV do. The file is written under a temporary name and
renamed into place (:func:`madp.io.atomic.atomic_path`). Needs ``opencv-python-headless``
(extra ``madp[video]``).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from madp.errors import MadpError, SettingError
from madp.io.atomic import atomic_path, temp_path
from madp.render import FrameRenderer
from madp.sim.rollout import Hook

VIDEO_FPS = 30
VIDEO_SIZE = 512
FOURCC = "mp4v"
SUFFIX = ".mp4"


def _cv2():
    try:
        import cv2
    except ImportError:
        raise MadpError("videos need OpenCV: pip install 'madp[video]' (opencv-python-headless)") from None
    return cv2


def check_video_path(path: str | os.PathLike) -> Path:
    """``path`` if a video can be written there: a ``.mp4`` name whose directory exists or can be made
    and takes a new file (probed with this process's temporary name). Raises a SettingError for another
    suffix, OSError (naming the path) when it cannot be written; checks that OpenCV is installed."""
    path = Path(path)
    if path.suffix.lower() != SUFFIX:
        raise SettingError("video", f"expected a {SUFFIX} file name, got {str(path)!r}")
    _cv2()
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    probe = temp_path(path, SUFFIX)
    probe.open("wb").close()
    probe.unlink()
    return path


def rollout_frames(world_map: np.ndarray, positions_m: np.ndarray, costs: np.ndarray, size: int = VIDEO_SIZE,
                   steps: Iterable[int] | None = None) -> Iterator[np.ndarray]:
    """The frames [size, size, 3] RGB of a rollout: positions ``[T+1, N, 2]``, J(t)/J(0) ``[T+1]``; one
    per step t = 0..T, or per step of ``steps`` (e.g. every 10th, for a short GIF)."""
    positions_m = np.asarray(positions_m, dtype=np.float64)
    if positions_m.ndim != 3 or positions_m.shape[2] != 2 or len(costs) != len(positions_m):
        raise ValueError(f"positions [T+1, N, 2] and costs [T+1] expected, got {positions_m.shape} and {len(costs)}")
    render = FrameRenderer(world_map, size)
    for t in range(len(positions_m)) if steps is None else steps:
        yield render(positions_m[t], positions_m[: t + 1], t, float(costs[t]))


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = VIDEO_FPS,
                total: int | None = None, progress: bool = False) -> dict:
    """Write RGB uint8 frames (all one size) as an MP4 (``mp4v``) at ``path``, atomically.

    ``progress`` shows a bar (``total`` frames, when known). Returns ``{"path", "frames", "bytes",
    "width", "height"}``."""
    cv2 = _cv2()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    count, shape = 0, None
    with atomic_path(path, SUFFIX) as tmp, Progress(
            TextColumn(f"video {path.name}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("ETA"),
            TimeRemainingColumn(), disable=not progress) as bar:
        task = bar.add_task("frames", total=total)
        writer = None
        try:
            for frame in frames:
                frame = np.asarray(frame)
                if writer is None:
                    shape = frame.shape
                    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
                        raise ValueError(f"frames must be [H, W, 3] uint8, got {frame.shape} {frame.dtype}")
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*FOURCC), float(fps),
                                             (frame.shape[1], frame.shape[0]))
                    if not writer.isOpened():
                        raise OSError(errno.EIO, f"OpenCV cannot open an MP4 ({FOURCC}) writer", str(path))
                elif frame.shape != shape:
                    raise ValueError(f"frame {count}: shape {frame.shape}, the first frame's was {shape}")
                writer.write(np.ascontiguousarray(frame[..., ::-1]))  # OpenCV wants BGR
                count += 1
                bar.advance(task)
        finally:
            if writer is not None:
                writer.release()
        if count == 0:
            raise ValueError(f"{path}: no frames to write")
        if not tmp.exists() or tmp.stat().st_size == 0:
            raise OSError(errno.EIO, "OpenCV wrote no video", str(path))
    return {"path": str(path), "frames": count, "bytes": path.stat().st_size, "width": shape[1], "height": shape[0]}


def write_rollout_video(path: str | os.PathLike, world_map: np.ndarray, positions_m: np.ndarray, costs: np.ndarray,
                        size: int = VIDEO_SIZE, fps: float = VIDEO_FPS, progress: bool = False) -> dict:
    """One rollout (positions ``[T+1, N, 2]``, J(t)/J(0) ``[T+1]``) as an MP4 of T+1 frames."""
    return write_video(path, rollout_frames(world_map, positions_m, costs, size), fps, total=len(costs),
                       progress=progress)


class Frames(Hook):
    """The rollout hook (:mod:`madp.sim.rollout`) that films environment ``index`` of a rollout of
    ``steps`` steps: it keeps the positions and J(t)/J(0) of every step, and :meth:`write` writes
    the T+1 frames to ``path``."""

    def __init__(self, path: str | os.PathLike, steps: int, index: int = 0):
        self.path, self.steps, self.index = path, steps, index

    def start(self, envs):
        env = envs[self.index]
        self.world_map = env.world_map
        self.positions_m = np.empty((self.steps + 1, env.num_robots, 2))
        self.cost = np.empty(self.steps + 1)
        self.positions_m[0], self.cost[0] = env.positions_m, 1.0

    def stepped(self, t, envs):
        env = envs[self.index]
        self.positions_m[t], self.cost[t] = env.positions_m, env.normalized_cost()

    def write(self, size: int = VIDEO_SIZE, fps: float = VIDEO_FPS, progress: bool = False) -> dict:
        return write_rollout_video(self.path, self.world_map, self.positions_m, self.cost, size, fps, progress)
