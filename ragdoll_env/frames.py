"""Render one frame of each registered environment to PNG files.

    python -m ragdoll_env.frames [--out docs] [--steps N]

Each environment is reset with seed 0, stepped ``--steps`` times with zero
action (so the picture shows the task's starting situation), and rendered
headless with ``render_mode="rgb_array"``.
"""

from __future__ import annotations

import argparse
import os
import sys

import gymnasium as gym
import numpy as np

from . import ENV_IDS
from .render import save_png


def write_frames(out: str, steps: int = 5) -> list[str]:
    os.makedirs(out, exist_ok=True)
    paths = []
    for env_id in ENV_IDS:
        env = gym.make(env_id, render_mode="rgb_array")
        env.reset(seed=0)
        for _ in range(steps):
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        name = env_id.split("/")[-1].split("-")[0]
        path = os.path.join(out, f"frame_{name}.png")
        save_png(env.render(), path)
        env.close()
        paths.append(path)
    return paths


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m ragdoll_env.frames", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="docs", help="output directory (default docs)")
    p.add_argument("--steps", type=int, default=5, help="zero-action steps before the frame (default 5)")
    args = p.parse_args(argv)
    for path in write_frames(args.out, args.steps):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
