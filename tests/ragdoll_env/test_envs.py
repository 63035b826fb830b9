"""The three environments: registration, API contracts, checkers, kwargs, actions, seeding."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import ragdoll_env
from ragdoll_env.batched import BatchedSim
from ragdoll_env.tasks import BalanceTask, InvertedPendulumTask

from env_helpers import ALL_IDS, PENDULUMS, fast_kwargs, make, random_actions


def test_import_registers_every_id_with_both_entry_points():
    for env_id in ALL_IDS:
        spec = gym.spec(env_id)
        assert spec.entry_point.startswith("ragdoll_env.single:")
        assert spec.vector_entry_point.startswith("ragdoll_env.vector:")
    assert gym.spec("Ragdoll/InvertedPendulum-v0").max_episode_steps == 1000
    assert gym.spec("Ragdoll/InvertedDoublePendulum-v0").max_episode_steps == 1000
    balance = gym.spec("Ragdoll/Balance-v0")
    assert balance.max_episode_steps * BalanceTask.dt * BalanceTask.frame_skip == pytest.approx(20.0)


def test_make_with_module_prefix_in_a_fresh_interpreter():
    import subprocess
    import sys

    code = ("import gymnasium as gym, warnings; warnings.simplefilter('ignore');"
            "env = gym.make('ragdoll_env:Ragdoll/Balance-v0', substeps=1);"
            "obs, _ = env.reset(seed=0); print(obs.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "(81,)"


def test_sb3_subproc_vec_env_with_module_prefix():
    """The README's advice: SB3's forkserver workers find the id with the prefix."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    venv = make_vec_env("ragdoll_env:Ragdoll/InvertedPendulum-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    try:
        obs = venv.reset()
        obs, reward, done, info = venv.step(np.zeros((2, 1), dtype=np.float32))
        assert obs.shape == (2, 2) and np.isfinite(obs).all() and reward.shape == (2,)
    finally:
        venv.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_env_checker(env_id):
    env = make(env_id)
    gym_check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_env_checker_with_its_defaults_headless(env_id, monkeypatch):
    """check_env as a user calls it, render check included: every declared
    mode is made, "human" too, which without a display warns and shows nothing."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = gym.make(env_id)
    with pytest.warns(RuntimeWarning, match="without a display"):
        gym_check_env(env.unwrapped)
    env.close()
    human = gym.make(env_id, render_mode="human")
    human.reset(seed=0)
    assert human.render() is None
    human.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_sb3_env_checker(env_id):
    from stable_baselines3.common.env_checker import check_env

    env = make(env_id)
    check_env(env, warn=True)
    env.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_spaces_step_types_and_render_fps(env_id):
    env = make(env_id)
    u = env.unwrapped
    obs, info = env.reset(seed=1)
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape
    assert env.observation_space.contains(obs)
    assert env.action_space.low.min() == -1.0 and env.action_space.high.max() == 1.0
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert type(reward) is float and type(terminated) is bool and type(truncated) is bool
    assert obs.dtype == np.float32
    terms = [v for k, v in info.items() if k.startswith("reward_")]
    assert math.isclose(sum(terms), reward, rel_tol=1e-9, abs_tol=1e-12)
    assert env.metadata["render_fps"] == int(round(1.0 / (u.model.settings.dt * u.core.frame_skip)))
    assert u.max_return == pytest.approx(u.task.max_reward_per_step * env.spec.max_episode_steps)
    env.close()


def test_max_returns_are_documented_values():
    assert gym.make("Ragdoll/InvertedPendulum-v0").unwrapped.max_return == 1000.0
    assert gym.make("Ragdoll/InvertedDoublePendulum-v0").unwrapped.max_return == 10000.0
    assert gym.make("Ragdoll/Balance-v0", substeps=1).unwrapped.max_return == 3600.0


def test_render_fps_follows_dt_and_frame_skip():
    env = gym.make("Ragdoll/InvertedPendulum-v0", dt=0.01, frame_skip=3)
    assert env.metadata["render_fps"] == 33
    assert env.unwrapped.dt == pytest.approx(0.03)


# --------------------------------------------------------------- kwargs
@pytest.mark.parametrize("env_id", ALL_IDS)
def test_unknown_kwarg_raises_naming_it(env_id):
    with pytest.raises(TypeError, match="not_a_setting"):
        gym.make(env_id, not_a_setting=1)
    with pytest.raises(TypeError, match="not_a_setting"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", not_a_setting=1)


@pytest.mark.parametrize("kwargs, name", [
    ({"frame_skip": 0}, "frame_skip"),
    ({"frame_skip": 1.5}, "frame_skip"),
    ({"reset_noise_scale": -1}, "reset_noise_scale"),
    ({"dt": -0.01}, "dt"),
    ({"substeps": 0}, "substeps"),
    ({"integrator": "leapfrog"}, "integrator"),
    ({"push_strength": (3, 1)}, "push_strength"),
    ({"push_strength": -1}, "push_strength"),
    ({"push_interval": (0, 1)}, "push_interval"),
    ({"push_strength": 1.0, "push_bodies": ("nose",)}, "push_bodies"),
    ({"push_strength": 1.0, "push_bodies": ("world",)}, "push_bodies: 'world' is static"),
    ({"render_mode": "ascii"}, "render_mode"),
    ({"width": 0, "render_mode": "rgb_array"}, "width"),
    ({"pole_mass": 0}, "pole_mass"),
    ({"healthy_angle": float("nan")}, "healthy_angle"),
])
def test_bad_values_raise_value_error_naming_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        gym.make("Ragdoll/InvertedPendulum-v0", **kwargs)


def test_check_finite_is_not_a_user_setting():
    with pytest.raises(TypeError, match="check_finite"):
        gym.make("Ragdoll/InvertedPendulum-v0", check_finite=True)


def test_engine_settings_reach_the_model():
    env = gym.make("Ragdoll/InvertedDoublePendulum-v0", dt=0.01, substeps=2, iterations=3, joint_hertz=30.0)
    s = env.unwrapped.model.settings
    assert (s.dt, s.substeps, s.iterations, s.joint_hertz, s.check_finite) == (0.01, 2, 3, 30.0, False)


# --------------------------------------------------------------- actions
@pytest.mark.parametrize("env_id", ALL_IDS)
@pytest.mark.parametrize("bad", ["shape", "nan", "inf", "text", "batch"])
def test_bad_action_raises_and_leaves_the_state_untouched(env_id, bad):
    env = make(env_id)
    u = env.unwrapped
    env.reset(seed=3)
    env.step(env.action_space.sample())
    before = u.state.copy()
    rng_state = u.np_random.bit_generator.state
    counters = (u.core.episode_steps.copy(), u.core.next_push_time.copy())
    a = np.zeros(env.action_space.shape, dtype=np.float32)
    if bad == "shape":
        a = np.zeros(a.size + 1, dtype=np.float32)
    elif bad == "nan":
        a[0] = np.nan
    elif bad == "inf":
        a[-1] = -np.inf
    elif bad == "text":
        a = ["x"] * a.size
    elif bad == "batch":
        a = a[None]
    with pytest.raises(ValueError):
        u.step(a)
    assert u.state.equal(before)
    assert u.np_random.bit_generator.state == rng_state
    assert np.array_equal(counters[0], u.core.episode_steps)
    assert np.array_equal(counters[1], u.core.next_push_time)


def test_actions_outside_the_box_are_clipped():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    out = []
    for a in (1.0, 7.5):
        env.reset(seed=5)
        out.append(env.step(np.array([a], dtype=np.float32))[0])
    assert np.array_equal(out[0], out[1])


# --------------------------------------------------------------- seeding
@pytest.mark.parametrize("env_id", ALL_IDS)
def test_same_seed_and_actions_replay_bit_identically(env_id):
    kwargs = {"push_strength": (5.0, 10.0), "push_interval": (0.05, 0.1)} if env_id.endswith("Balance-v0") else {}
    actions = random_actions(0, 25, gym.spec(env_id).make(**fast_kwargs(env_id)).action_space.shape)
    runs = []
    for _ in range(2):
        env = make(env_id, **kwargs)
        obs, _ = env.reset(seed=123)
        trace = [obs]
        for a in actions:
            obs, r, term, trunc, info = env.step(a)
            trace.append(np.append(obs, [r, term, info["pushes"]]))
            if term or trunc:
                obs, _ = env.reset()
                trace.append(obs)
        runs.append(np.concatenate(trace))
    assert np.array_equal(runs[0], runs[1])


def test_different_seeds_give_different_starts():
    env = gym.make("Ragdoll/InvertedDoublePendulum-v0")
    a, _ = env.reset(seed=1)
    b, _ = env.reset(seed=2)
    assert not np.array_equal(a, b)


def test_reset_noise_scale_zero_starts_exactly_upright():
    env = gym.make("Ragdoll/InvertedPendulum-v0", reset_noise_scale=0.0)
    obs, _ = env.reset(seed=0)
    assert np.all(obs == 0.0)


# --------------------------------------------------------------- episodes
def test_pendulum_terminates_past_the_healthy_angle_without_alive_bonus():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    env.reset(seed=0)
    for _ in range(200):
        obs, r, term, trunc, info = env.step(np.array([1.0], dtype=np.float32))
        if term:
            break
    assert term and abs(obs[0]) > 0.2
    assert info["reward_survive"] == 0.0 and not info["healthy"]


def test_pendulum_torque_cannot_hold_a_large_tilt():
    """Past asin(0.3) ≈ 17.5° the full torque loses to gravity."""
    core = gym.make("Ragdoll/InvertedPendulum-v0", healthy_angle=1.5).unwrapped.core
    core.rngs[0] = np.random.default_rng(0)
    core.reset([0])
    core.task.set_coordinates(core.model, core.state, [0], [[0.35]], [[0.0]])
    for _ in range(20):
        obs, *_ = core.step(np.array([[-1.0]]))
    assert obs[0, 0] > 0.45


def test_time_limit_truncates_at_max_episode_steps():
    env = gym.make("Ragdoll/InvertedPendulum-v0", max_episode_steps=5, reset_noise_scale=0.0)
    env.reset(seed=0)
    flags = [env.step(np.zeros(1, dtype=np.float32))[3] for _ in range(5)]
    assert flags == [False] * 4 + [True]


def test_info_reports_reward_terms_for_each_task():
    keys = {
        "Ragdoll/InvertedPendulum-v0": {"reward_survive", "reward_ctrl"},
        "Ragdoll/InvertedDoublePendulum-v0": {"reward_survive", "reward_distance", "reward_velocity", "reward_ctrl"},
        "Ragdoll/Balance-v0": {"reward_survive", "reward_upright", "reward_height", "reward_capture",
                               "reward_ctrl"},
    }
    for env_id, expected in keys.items():
        env = make(env_id)
        env.reset(seed=0)
        info = env.step(env.action_space.sample())[4]
        assert {k for k in info if k.startswith("reward_")} == expected
        assert {"healthy", "nonfinite", "pushes", "pushes_survived", "push_applied"} <= set(info)


def test_double_pendulum_upright_and_still_earns_the_full_bonus():
    env = gym.make("Ragdoll/InvertedDoublePendulum-v0", reset_noise_scale=0.0, ctrl_cost_weight=0.0)
    env.reset(seed=0)
    _, r, term, _, info = env.step(np.zeros(2, dtype=np.float32))
    assert not term
    assert r == pytest.approx(10.0, abs=1e-3)


# --------------------------------------------------------------- non-finite
def test_nonfinite_world_terminates_with_a_finite_observation():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    u = env.unwrapped
    obs0, _ = env.reset(seed=0)
    u.state.velocity[0, 0, 0] = np.nan
    obs, r, term, trunc, info = env.step(np.zeros(1, dtype=np.float32))
    assert term and info["nonfinite"] and r == 0.0
    assert np.array_equal(obs, obs0)
    assert u.state.nonfinite_worlds().size == 0
    obs, _ = env.reset()
    assert np.all(np.isfinite(obs))


def test_nonfinite_reward_is_caught_too():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    env.reset(seed=0)
    env.unwrapped.state.angular_velocity[0, 0, 1] = 1e200  # squares to inf in the obs/reward
    _, r, term, _, info = env.step(np.zeros(1, dtype=np.float32))
    assert term and info["nonfinite"] and math.isfinite(r)


# --------------------------------------------------------------- pushes
def test_pushes_follow_the_settings_and_are_reported():
    env = gym.make("Ragdoll/InvertedPendulum-v0", push_strength=(0.5, 1.0), push_interval=(0.1, 0.2),
                   healthy_angle=3.0, push_recovery_time=0.0)
    env.reset(seed=0)
    applied = []
    for _ in range(20):
        info = env.step(np.zeros(1, dtype=np.float32))[4]
        if info["push_applied"]:
            J = info["push_impulse"]
            assert 0.5 <= np.linalg.norm(J) <= 1.0 and J[2] == 0.0
            assert info["push_body"] == env.unwrapped.model.body_index("pole")
            applied.append(info["time"])
    assert 3 <= len(applied) <= 9
    assert np.all(np.diff(applied) >= 0.1 - 1e-9)
    assert info["pushes"] == len(applied) and info["pushes_survived"] == len(applied)


def test_push_strength_zero_disables_pushes():
    env = make("Ragdoll/Balance-v0", push_strength=0, push_interval=(0.01, 0.02))
    env.reset(seed=0)
    for _ in range(5):
        info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))[4]
        assert not info["push_applied"]
    assert info["pushes"] == 0


def test_push_changes_the_motion():
    def run(strength):
        env = gym.make("Ragdoll/InvertedPendulum-v0", push_strength=strength, push_interval=(0.04, 0.04),
                       reset_noise_scale=0.0)
        env.reset(seed=0)
        for _ in range(3):
            obs = env.step(np.zeros(1, dtype=np.float32))[0]
        return obs

    assert np.all(run(0.0) == 0.0)
    assert abs(run(2.0)[1]) > 0.1


def test_core_worlds_do_not_depend_on_batch_size():
    task = InvertedPendulumTask()
    one = BatchedSim(InvertedPendulumTask(), 1)
    many = BatchedSim(task, 3)
    one.rngs[0] = np.random.default_rng(7)
    many.rngs = [np.random.default_rng(s) for s in (1, 7, 9)]
    o1, _ = one.reset([0])
    o3, _ = many.reset([0, 1, 2])
    assert np.array_equal(o1[0], o3[1])
    acts = random_actions(1, 10, (3, 1))
    for a in acts:
        r1 = one.step(a[1:2])
        r3 = many.step(a)
        assert np.array_equal(r1[0][0], r3[0][1]) and r1[1][0] == r3[1][1]


def test_env_ids_constant():
    assert set(ragdoll_env.ENV_IDS) == set(ALL_IDS)
    assert all(i in PENDULUMS or i.endswith("Balance-v0") for i in ALL_IDS)
