"""Residual control: a zero residual is the baseline, bit for bit; a residual
adds to it and is clipped; bad settings and bad actions are named."""

import gymnasium as gym
import numpy as np
import pytest

import ragdoll_env  # noqa: F401
from ragdoll_env.baselines import make_baseline
from ragdoll_env.residual import ResidualAction, check_residual, residual_action

pytest.importorskip("stable_baselines3")

from ragdoll_env.residual import residual_vec_env  # noqa: E402
from ragdoll_env.sb3 import make_sb3_vec_env  # noqa: E402

ENV = "Ragdoll/InvertedDoublePendulum-v0"
SPEC = {"baseline": "lqr", "scale": 0.5}


def _trajectory(venv, act, steps):
    obs = venv.reset()
    out = [obs]
    for _ in range(steps):
        obs, reward, done, _ = venv.step(act(obs))
        out.append(obs)
    return np.array(out)


def test_zero_residual_is_the_baseline_bit_for_bit():
    plain = make_sb3_vec_env(ENV, num_envs=3, seed=5)
    lqr = make_baseline("lqr", plain)
    expected = _trajectory(plain, lqr.act, 60)
    wrapped = residual_vec_env(make_sb3_vec_env(ENV, num_envs=3, seed=5), SPEC)
    got = _trajectory(wrapped, lambda obs: np.zeros((3, 2), dtype=np.float32), 60)
    assert np.array_equal(got, expected)


def test_residual_adds_scaled_and_clips():
    venv = make_sb3_vec_env(ENV, num_envs=2, seed=1)
    lqr = make_baseline("lqr", venv)
    obs = venv.reset()
    r = np.array([[0.4, -0.2], [5.0, -5.0]])
    a = residual_action(lqr, obs, r, 0.5)
    expected = np.clip(lqr.act(obs).astype(np.float64) + 0.5 * r, -1.0, 1.0)
    assert a.dtype == np.float32 and np.allclose(a, expected, atol=1e-7)
    assert a[1, 0] == 1.0 and a[1, 1] == -1.0


def test_single_env_wrapper_matches_the_vector_wrapper():
    env = ResidualAction(gym.make(ENV), SPEC)
    venv = residual_vec_env(make_sb3_vec_env(ENV, num_envs=1, seed=9), SPEC)
    obs, _ = env.reset(seed=9)
    vobs = venv.reset()
    assert np.array_equal(obs, vobs[0])
    r = np.array([0.3, -0.1], dtype=np.float32)
    for _ in range(20):
        obs, *_ = env.step(r)
        vobs, *_ = venv.step(r[None])
        assert np.array_equal(obs, vobs[0])


def test_actuator_subset_shrinks_the_action_space_and_leaves_the_rest_to_the_baseline():
    spec = {**SPEC, "actuators": ["hip"]}
    venv = residual_vec_env(make_sb3_vec_env(ENV, num_envs=2, seed=4), spec)
    env = ResidualAction(gym.make(ENV), spec)
    assert venv.action_space.shape == (1,) and env.action_space.shape == (1,)
    obs = venv.reset()
    lqr = venv.controller
    a = residual_action(lqr, obs, np.array([[0.3], [-0.3]]), 0.5, venv.subset)
    base = lqr.act(obs)
    assert np.array_equal(a[:, 0], base[:, 0])  # the ankle: the LQR alone
    assert np.allclose(a[:, 1], np.clip(base[:, 1] + np.array([0.15, -0.15]), -1, 1), atol=1e-7)
    venv.step(np.zeros((2, 1)))
    with pytest.raises(ValueError, match="matches none"):
        residual_vec_env(make_sb3_vec_env(ENV, num_envs=1), {**SPEC, "actuators": ["knee"]})


@pytest.mark.parametrize("spec, match", [
    ({"baseline": "lqr", "actuators": "hip"}, "actuators must be a non-empty list"),
    ({"baseline": "lqr", "actuators": []}, "actuators must be a non-empty list"),
    ({"baseline": "nope"}, "baseline must be one of"),
    ({"baseline": "zero"}, "baseline must be one of"),
    ({"baseline": "lqr", "scale": 0}, "scale must be a finite number > 0"),
    ({"baseline": "lqr", "scale": float("nan")}, "scale must be a finite number > 0"),
    ({"baseline": "lqr", "gain": 2}, "unknown keys"),
    ("lqr", "must be a mapping"),
])
def test_bad_residual_settings_are_named(spec, match):
    with pytest.raises(ValueError, match=match):
        check_residual(spec)


def test_bad_residual_actions_raise_before_stepping():
    venv = residual_vec_env(make_sb3_vec_env(ENV, num_envs=2, seed=0), SPEC)
    venv.reset()
    before = venv.venv.core.state.position.copy()
    with pytest.raises(ValueError, match=r"NaN or infinite entry at index \(0, 0\)"):
        venv.step(np.array([[np.nan, 0.0], [0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"must have shape \(2, 2\), got \(2, 3\)"):
        venv.step(np.zeros((2, 3)))
    assert np.array_equal(venv.venv.core.state.position, before)
    env = ResidualAction(gym.make(ENV), SPEC)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"NaN or infinite entry at index \(0,\)"):
        env.step(np.array([np.inf, 0.0]))
