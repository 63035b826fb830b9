"""Rendering of the environments: rgb_array frames, human mode without a display, video, the demo."""

import importlib.util
import os

import gymnasium as gym
import numpy as np
import pytest

from env_helpers import ALL_IDS, fast_kwargs


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_rgb_array_frames(env_id):
    env = gym.make(env_id, render_mode="rgb_array", width=96, height=72, **fast_kwargs(env_id))
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (72, 96, 3) and frame.dtype == np.uint8
    assert frame.std() > 5  # not a blank image
    env.step(env.action_space.sample())
    assert env.render().shape == (72, 96, 3)


def test_render_without_mode_returns_none():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning):
        assert env.unwrapped.render() is None


def test_human_mode_without_display_warns_clearly_and_steps(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.warns(RuntimeWarning, match="without a display"):
        env = gym.make("Ragdoll/InvertedPendulum-v0", render_mode="human")
    obs, _ = env.reset(seed=0)
    obs2, *_ = env.step(env.action_space.sample())
    assert env.render() is None and not np.array_equal(obs, obs2)
    env.close()


def test_camera_follows_the_body():
    env = gym.make("Ragdoll/Balance-v0", render_mode="rgb_array", width=64, height=64, substeps=1)
    env.reset(seed=0)
    u = env.unwrapped
    first = env.render()
    u.state.position[0, :, 0] += 50.0  # move every body far along x: still in view
    assert np.abs(env.render().astype(int) - first.astype(int)).mean() < 20


@pytest.mark.skipif(importlib.util.find_spec("moviepy") is None, reason="moviepy is not installed")
def test_record_video_writes_an_mp4(tmp_path):
    from gymnasium.wrappers import RecordVideo

    env = gym.make("Ragdoll/InvertedPendulum-v0", render_mode="rgb_array", width=64, height=48,
                   max_episode_steps=12)
    env = RecordVideo(env, str(tmp_path), episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, _ = env.step(np.zeros(1, dtype=np.float32))
        done = term or trunc
    env.close()
    videos = [f for f in os.listdir(tmp_path) if f.endswith(".mp4")]
    assert videos and os.path.getsize(tmp_path / videos[0]) > 0


@pytest.mark.parametrize("scene", ["stairs", "boxes"])
def test_demo_writes_a_strip_headless(tmp_path, scene, monkeypatch):
    from ragdoll_env import demo

    monkeypatch.delenv("DISPLAY", raising=False)
    rc = demo.main(["--out", str(tmp_path), "--frames", "3", "--scene", scene, "--seconds", "0.1",
                    "--width", "48", "--height", "36"])
    assert rc == 0
    from PIL import Image

    strip = np.asarray(Image.open(tmp_path / f"{scene}_strip.png"))
    assert strip.shape == (36, 3 * 48 + 2 * 4, 3)


def test_demo_video(tmp_path):
    pytest.importorskip("imageio")
    from ragdoll_env import demo

    paths = demo.run(str(tmp_path), "stairs", frames=2, seconds=0.2, video=True, width=48, height=36)
    assert os.path.getsize(paths["video"]) > 0
