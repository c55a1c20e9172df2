"""The README's video: the shipped MADP (decentralized, default sampler) drives the PettingZoo env on the
first ``cities`` environment for 600 steps (the rollout ``madp eval --suite cities --num-envs 1
--controllers madp --video 1`` makes, bit for bit), written as

- ``docs/cities-madp.mp4``: every 6th step at 320 px, 10 frames/s (10 s), a small copy of what
  ``--video`` writes at 512 px for every step (OpenCV's ``mp4v`` writer has no quality setting, so
  fewer frames and pixels are what make the file small);
- ``docs/cities-madp.gif``: every 5th step at 256 px, 20 frames/s (6 s), for the README page.

    .venv/bin/python scripts/readme_video.py        # ~1 min on one core
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from madp.envs import coverage_v0, make_controller
from madp.eval.suites import suite_envs
from madp.video import rollout_frames, write_video

DOCS = Path(__file__).resolve().parents[1] / "docs"
STEPS = 600


def main() -> None:
    spec = suite_envs("cities", 1)[0]
    env = coverage_v0.parallel_env(scenario=spec, max_steps=STEPS)
    policy = make_controller("madp", seed=spec.seed)  # madp eval seeds MADP's noise with the scenario's seed
    env.reset(seed=0)
    costs = [1.0]
    while env.agents:
        _, _, _, _, infos = env.step(env.actions_from(policy))
        costs.append(infos["robot_0"]["normalized_cost"])
    trail, costs = env.trail, np.array(costs)
    print(f"{spec.group}: J({STEPS})/J(0) = {costs[-1]:.4f}")

    mp4 = write_video(DOCS / "cities-madp.mp4", rollout_frames(env.sim.world_map, trail, costs, 320,
                                                                range(0, STEPS + 1, 6)), fps=10)
    print(f"{mp4['path']}: {mp4['frames']} frames, {mp4['bytes'] / 1e6:.2f} MB")

    frames = [Image.fromarray(f).quantize(colors=64, method=Image.Quantize.MEDIANCUT)
              for f in rollout_frames(env.sim.world_map, trail, costs, 256, range(0, STEPS + 1, 5))]
    gif = DOCS / "cities-madp.gif"
    durations = [50] * (len(frames) - 1) + [2000]  # hold the last frame for 2 s
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=durations, loop=0, optimize=True)
    print(f"{gif}: {len(frames)} frames, {gif.stat().st_size / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
