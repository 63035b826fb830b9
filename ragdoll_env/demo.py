"""The passive ragdoll: drop the humanoid (zero torque) down a flight of stairs or onto boxes.

    python -m ragdoll_env.demo --out DIR [--frames N] [--scene stairs|boxes] [--video]
        [--seconds S] [--width PX] [--height PX] [--fps N] [--seed N]

Writes ``DIR/<scene>_strip.png`` (N frames evenly spaced over ``--seconds``,
tiled by :func:`ragdoll_env.render.frame_strip`) and with ``--video`` also
``DIR/<scene>.mp4`` (every rendered frame, via imageio-ffmpeg or moviepy).
Runs headless: the renderer is numpy ray casting. The scene is static boxes
(Box shapes on static bodies) on a ground plane; the doll only lands on them
once the engine has contacts.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

import engine
from engine import Box
from engine.humanoid import add_humanoid, pose, random_pose

from .cli_args import non_negative_int, positive_int
from .render import Renderer, frame_strip

STEP_RISE, STEP_RUN, STEPS = 0.18, 0.35, 5


def build_scene(scene: str, seed: int = 0, dt: float = 1 / 60, substeps: int = 4):
    """(model, humanoid, initial State of one world) for ``scene``."""
    b = engine.SceneBuilder(dt=dt, substeps=substeps, check_finite=False)
    b.add_ground()
    rng = np.random.default_rng(seed)
    if scene == "stairs":
        for k in range(STEPS):
            top = (STEPS - k) * STEP_RISE
            b.add_body(f"step_{k}", Box((0.5 * STEP_RUN, 1.0, 0.5 * top)), static=True,
                       position=(k * STEP_RUN, 0.0, 0.5 * top), material="wood")
        start = np.array([-0.05, 0.0, STEPS * STEP_RISE])
    elif scene == "boxes":
        for k in range(6):
            half = rng.uniform(0.15, 0.35, size=3)
            xy = rng.uniform(-0.8, 0.8, size=2)
            q = engine.math3d.quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), rng.uniform(0, math.pi))
            b.add_body(f"box_{k}", Box(tuple(half)), static=True, position=(xy[0], xy[1], half[2]),
                       orientation=q, material="wood")
        start = np.array([0.0, 0.0, 1.2])
    else:
        raise ValueError(f"unknown scene {scene!r}; choose 'stairs' or 'boxes'")
    h = add_humanoid(b, position=start)
    model = b.build()
    state = model.initial_state(1)
    if scene == "stairs":
        # lean forward over the edge and step off with a push
        lean = engine.math3d.quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.25)
        pos, quat = pose(h, model, None, root_orientation=lean)
        velocity = np.array([1.0, 0.0, 0.0])
    else:
        tilt = engine.math3d.quat_from_axis_angle(np.array([1.0, 0.3, 0.0]) / math.hypot(1.0, 0.3), 1.2)
        pos, quat = pose(h, model, random_pose(rng, h, scale=0.4), root_orientation=tilt)
        velocity = np.zeros(3)
    body = np.array([model.body_index(h.name(p)) for p in h.bodies])
    state.position[0, body] = pos[body]
    state.orientation[0, body] = quat[body]
    state.velocity[0, body] = velocity
    return model, h, state


def run(out: str, scene: str = "stairs", frames: int = 8, seconds: float = 3.0, video: bool = False,
        width: int = 320, height: int = 240, fps: int = 30, seed: int = 0) -> dict:
    """Simulate and write the strip (and video); returns the written paths."""
    if not (seconds > 0 and math.isfinite(seconds)):
        raise ValueError(f"seconds must be a finite number > 0, got {seconds!r}")
    if not fps >= 1:
        raise ValueError(f"fps must be >= 1, got {fps!r}")
    os.makedirs(out, exist_ok=True)
    model, h, state = build_scene(scene, seed)
    renderer = Renderer.from_model(model, width=width, height=height)
    renderer.distance, renderer.elevation, renderer.azimuth = 5.0, 15.0, -65.0
    dt = model.settings.dt
    n_steps = max(1, int(round(seconds / dt)))
    every = max(1, int(round(1.0 / (fps * dt))))
    strip_at = set(np.linspace(0, n_steps, max(1, frames)).round().astype(int).tolist())
    zero = engine.Control.zeros(model, 1)
    pelvis = model.body_index(h.name("pelvis"))
    rendered, strip = [], []

    def shoot():
        target = state.position[0, pelvis].copy()
        if not np.all(np.isfinite(target)):
            target = None
        else:
            target[2] = float(np.clip(target[2], 0.5, 1.5))
        return renderer.render(state.position[0], state.orientation[0], target=target)

    worst_anchor = worst_penetration = 0.0
    for k in range(n_steps + 1):
        if k > 0:
            engine.step(model, state, zero)
            worst_anchor = max(worst_anchor, float(model.joints.anchor_error(state).max()))
            sep = state.contact_separation
            worst_penetration = max(worst_penetration, float(-sep[np.isfinite(sep)].min(initial=0.0)))
        if state.nonfinite_worlds().size:
            print(f"the simulation turned non-finite at step {k}; stopping", file=sys.stderr)
            break
        want_video = video and k % every == 0
        if k in strip_at or want_video:
            frame = shoot()
            if k in strip_at:
                strip.append(frame)
            if want_video:
                rendered.append(frame)
    from engine.diagnostics import kinetic_energy

    speeds = np.linalg.norm(state.velocity[0], axis=-1)
    print(f"passive ragdoll, {scene}: {n_steps} steps of {dt:g} s")
    print(f"  largest joint anchor error    {1000 * worst_anchor:8.2f} mm")
    print(f"  largest contact penetration   {1000 * worst_penetration:8.2f} mm")
    print(f"  pelvis height at the end      {state.position[0, pelvis, 2]:8.3f} m")
    print(f"  fastest bone at the end       {speeds.max():8.3f} m/s")
    print(f"  kinetic energy at the end     {kinetic_energy(model, state)[0]:8.3f} J")
    paths = {"strip": os.path.join(out, f"{scene}_strip.png")}
    frame_strip(strip, paths["strip"], columns=min(4, len(strip)))
    if video:
        paths["video"] = write_video(rendered, os.path.join(out, f"{scene}.mp4"), fps=round(1.0 / (every * dt)))
    return paths


def write_video(frames, path: str, fps: int) -> str:
    """Write uint8 frames as MP4 with imageio-ffmpeg, else moviepy."""
    frames = [np.asarray(f) for f in frames]
    try:
        import imageio.v2 as imageio

        with imageio.get_writer(path, fps=fps, codec="libx264", macro_block_size=1) as writer:
            for f in frames:
                writer.append_data(f)
        return path
    except ImportError:
        pass
    try:
        from moviepy import ImageSequenceClip
    except ImportError:
        try:
            from moviepy.editor import ImageSequenceClip
        except ImportError as exc:
            raise ImportError("--video needs imageio-ffmpeg or moviepy: pip install 'ragdoll[video]'") from exc
    ImageSequenceClip(frames, fps=fps).write_videofile(path, logger=None)
    return path


def _positive_seconds(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds > 0, got {text!r}")
    return value


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m ragdoll_env.demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--frames", type=positive_int, default=8, help="frames in the PNG strip (default 8)")
    p.add_argument("--scene", choices=("stairs", "boxes"), default="stairs")
    p.add_argument("--video", action="store_true", help="also write an MP4")
    p.add_argument("--seconds", type=_positive_seconds, default=3.0, help="simulated time (default 3 s)")
    p.add_argument("--width", type=positive_int, default=320, help="image width in pixels (default 320)")
    p.add_argument("--height", type=positive_int, default=240, help="image height in pixels (default 240)")
    p.add_argument("--fps", type=positive_int, default=30,
                   help="video frames per simulated second with --video (default 30; a whole number of 1/60 s "
                        "steps per frame, so at most 60)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the boxes scene (default 0)")
    args = p.parse_args(argv)
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        p.error(f"--out {args.out}: exists and is not a directory")
    paths = run(args.out, args.scene, args.frames, args.seconds, args.video, args.width, args.height,
                fps=args.fps, seed=args.seed)
    for kind, path in paths.items():
        print(f"{kind}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
