"""The native VectorEnv and the SB3 VecEnv: same numbers as W single envs, autoreset, contracts."""

import re
import warnings

import gymnasium as gym
import numba
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from ragdoll_env.vector import RagdollVectorEnv

from env_helpers import ALL_IDS, fast_kwargs, make, random_actions

W = 3


def make_vec(env_id, num_envs=W, **kwargs):
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                        **{**fast_kwargs(env_id), **kwargs})


def test_make_vec_uses_the_vector_entry_point():
    envs = gym.make_vec("Ragdoll/InvertedPendulum-v0", num_envs=4, vectorization_mode="vector_entry_point")
    assert isinstance(envs.unwrapped, RagdollVectorEnv)
    assert envs.num_envs == 4 and envs.unwrapped.core.num_worlds == 4
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert envs.unwrapped.core.max_episode_steps == 1000
    obs, info = envs.reset(seed=0)
    assert obs.shape == (4, 2) and obs.dtype == np.float32
    assert envs.observation_space.shape == (4, 2) and envs.action_space.shape == (4, 1)
    obs, r, term, trunc, info = envs.step(envs.action_space.sample())
    assert r.shape == term.shape == trunc.shape == (4,) and term.dtype == bool
    assert info["reward_survive"].shape == (4,) and info["_reward_survive"].all()


def test_default_make_vec_picks_the_vector_entry_point():
    envs = gym.make_vec("Ragdoll/InvertedPendulum-v0", num_envs=2)
    assert isinstance(envs.unwrapped, RagdollVectorEnv)


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_vector_env_equals_single_envs_with_autoreset(env_id):
    """W single envs reset with seeds s + i and fed the same actions give bit-identical
    observations, rewards and flags, including next-step autoresets."""
    steps = 50 if "Pendulum" in env_id else 12
    limit = 9 if "Pendulum" in env_id else 5
    extra = {"push_strength": (5.0, 15.0), "push_interval": (0.03, 0.1)}
    envs = make_vec(env_id, max_episode_steps=limit, **extra)
    singles = [make(env_id, max_episode_steps=limit, **extra) for _ in range(W)]
    obs_v, _ = envs.reset(seed=10)
    obs_s = [env.reset(seed=10 + i)[0] for i, env in enumerate(singles)]
    assert np.array_equal(obs_v, np.stack(obs_s))
    actions = random_actions(2, steps, envs.action_space.shape)
    pending = [False] * W
    resets = 0
    for a in actions:
        obs_v, r_v, term_v, trunc_v, info_v = envs.step(a)
        for i, env in enumerate(singles):
            if pending[i]:
                o, _ = env.reset()
                r, term, trunc = 0.0, False, False
                resets += 1
                assert not info_v["_reward_survive"][i]
            else:
                o, r, term, trunc, info = env.step(a[i])
                assert info_v["pushes"][i] == info["pushes"]
            assert np.array_equal(obs_v[i], o), i
            assert r_v[i] == r and term_v[i] == term and trunc_v[i] == trunc
            pending[i] = term or trunc
    assert resets >= W  # autoreset happened


def test_same_step_autoreset_reports_final_observation():
    envs = make_vec("Ragdoll/InvertedPendulum-v0", max_episode_steps=4, autoreset_mode="SameStep")
    single = make("Ragdoll/InvertedPendulum-v0", max_episode_steps=4)
    envs.reset(seed=0)
    single.reset(seed=0)
    a = np.zeros((W, 1), dtype=np.float32)
    for _ in range(4):
        obs, r, term, trunc, info = envs.step(a)
        o1 = single.step(a[0])[0]
    assert trunc.all()
    assert np.array_equal(info["final_obs"][0], o1)
    assert info["_final_obs"].all() and info["final_info"]["_time"].all()
    # As Gymnasium's SyncVectorEnv: the reset worlds' top-level info is their (empty) reset info.
    assert not info["_time"].any()
    assert np.array_equal(obs[0], single.reset()[0])
    obs, r, term, trunc, info = envs.step(a)
    assert not trunc.any() and "final_obs" not in info


def test_reset_mask_resets_only_selected_worlds():
    envs = make_vec("Ragdoll/InvertedPendulum-v0")
    obs0, _ = envs.reset(seed=0)
    obs1, *_ = envs.step(np.ones((W, 1), dtype=np.float32))
    mask = np.array([True, False, True])
    obs2, _ = envs.reset(seed=0, options={"reset_mask": mask})
    assert np.array_equal(obs2[0], obs0[0]) and np.array_equal(obs2[2], obs0[2])
    assert np.array_equal(obs2[1], obs1[1])


def test_vector_bad_actions_raise_and_leave_state_untouched():
    envs = make_vec("Ragdoll/InvertedDoublePendulum-v0")
    envs.reset(seed=0)
    before = envs.unwrapped.state.copy()
    for bad in (np.zeros((W, 3)), np.zeros(2), np.full((W, 2), np.nan)):
        with pytest.raises(ValueError):
            envs.step(bad)
    assert envs.unwrapped.state.equal(before)


def test_vector_nonfinite_world_is_reported_and_reset():
    envs = make_vec("Ragdoll/InvertedPendulum-v0")
    obs0, _ = envs.reset(seed=0)
    envs.unwrapped.state.position[1, 0, 2] = np.nan
    obs, r, term, trunc, info = envs.step(np.zeros((W, 1), dtype=np.float32))
    assert info["nonfinite"].tolist() == [False, True, False]
    assert term[1] and r[1] == 0.0 and np.all(np.isfinite(obs))
    assert envs.unwrapped.state.nonfinite_worlds().size == 0
    obs, r, term, trunc, info = envs.step(np.zeros((W, 1), dtype=np.float32))
    assert np.all(np.isfinite(obs)) and not term[1]


def test_vector_render_returns_one_frame_per_world():
    envs = make_vec("Ragdoll/InvertedPendulum-v0", num_envs=2, render_mode="rgb_array", width=64, height=48)
    envs.reset(seed=0)
    frames = envs.render()
    assert len(frames) == 2 and frames[0].shape == (48, 64, 3) and frames[0].dtype == np.uint8


# ------------------------------------------------------------------ SB3
def test_sb3_vec_env_contract_and_equality_with_single_envs():
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import VecEnv

    from ragdoll_env.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=W, max_episode_steps=6)
    assert isinstance(venv, VecEnv)
    venv.seed(20)
    obs = venv.reset()
    assert isinstance(obs, np.ndarray) and obs.shape == (W, 2) and obs.dtype == np.float32
    singles = [make("Ragdoll/InvertedPendulum-v0", max_episode_steps=6) for _ in range(W)]
    assert np.array_equal(obs, np.stack([e.reset(seed=20 + i)[0] for i, e in enumerate(singles)]))
    saw_done = False
    for a in random_actions(3, 20, (W, 1)):
        obs, rewards, dones, infos = venv.step(a)
        assert rewards.dtype == np.float32 and dones.dtype == bool and len(infos) == W
        for i, env in enumerate(singles):
            o, r, term, trunc, _ = env.step(a[i])
            assert np.float32(r) == rewards[i] and dones[i] == (term or trunc)
            if term or trunc:
                saw_done = True
                assert np.array_equal(infos[i]["terminal_observation"], o)
                assert infos[i]["TimeLimit.truncated"] == (trunc and not term)
                o, _ = env.reset()
            assert np.array_equal(obs[i], o)
    assert saw_done
    assert venv.get_attr("render_mode") == [None] * W
    assert venv.get_attr("frame_skip", indices=[0]) == [2]
    assert len(venv.get_attr("np_random")) == W
    assert venv.env_is_wrapped(Monitor) == [False] * W
    venv.set_attr("alive_bonus", 2.0)
    assert venv.get_attr("alive_bonus") == [2.0] * W
    with pytest.raises(ValueError):
        venv.set_attr("alive_bonus", 3.0, indices=[0])
    venv.set_attr("custom_tag", "x", indices=[1])
    assert venv.get_attr("custom_tag", indices=[1]) == ["x"]
    o, info = venv.env_method("reset", seed=20, indices=[0])[0]
    assert np.array_equal(o, singles[0].reset(seed=20)[0])
    with pytest.raises(AttributeError):
        venv.get_attr("no_such_attribute")
    venv.close()


def test_sb3_adapter_rejects_bad_actions():
    from ragdoll_env.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=2, seed=0)
    venv.reset()
    with pytest.raises(ValueError):
        venv.step(np.array([[np.nan], [0.0]]))


def test_ppo_learns_on_the_sb3_adapter():
    import stable_baselines3
    import stable_baselines3.common.logger

    from ragdoll_env.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=2, seed=0, monitor=True)
    model = stable_baselines3.PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=2, seed=0, device="cpu")
    model.set_logger(stable_baselines3.common.logger.Logger(folder=None, output_formats=[]))  # no /tmp/SB3-<date>
    model.learn(128)
    action, _ = model.predict(venv.reset(), deterministic=True)
    assert action.shape == (2, 1)


def test_sb3_adapter_renders_rgb_frames():
    from ragdoll_env.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=2, seed=0, render_mode="rgb_array",
                            width=40, height=30)
    venv.reset()
    images = venv.get_images()
    assert len(images) == 2 and images[0].shape == (30, 40, 3)
    assert venv.render().dtype == np.uint8


@pytest.fixture
def restore_threads():
    """The engine's thread count (of this thread) as it was before the test."""
    import engine

    before = engine.get_threads()
    yield
    engine.set_threads(before)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
def test_vector_env_on_one_and_two_threads_equals_the_default(restore_threads):
    # Balance with pushes every 0.05-0.1 s and episodes of 20 steps (autoreset),
    # 16 worlds (enough for the kernels' prange loops, SERIAL_BELOW) on 1 and
    # on 2 threads: the same observations, rewards and infos bit for bit as
    # the default (the engine's count).
    from engine.core.jit import SERIAL_BELOW

    n = 2 * SERIAL_BELOW
    kwargs = dict(num_envs=n, max_episode_steps=20, push_strength=(5.0, 20.0), push_interval=(0.05, 0.1))
    default = make_vec("Ragdoll/Balance-v0", **kwargs)
    one, two = (make_vec("Ragdoll/Balance-v0", threads=t, **kwargs) for t in (1, 2))
    assert default.unwrapped.core.threads is None
    assert one.unwrapped.core.threads == 1 and two.unwrapped.core.threads == 2
    envs = (default, one, two)
    outs = [v.reset(seed=5) for v in envs]
    for o in outs[1:]:
        np.testing.assert_array_equal(outs[0][0], o[0])
    pushes = 0
    for a in random_actions(2, 30, default.action_space.shape):
        steps = []
        for v in envs:
            steps.append(v.step(a))
            # the count is set for this thread at each step and left set
            assert numba.get_num_threads() == (v.unwrapped.core.threads or numba.get_num_threads())
        (o0, r0, t0, u0, i0) = steps[0]
        for (o, r, t, u, i) in steps[1:]:
            for x, y in ((o0, o), (r0, r), (t0, t), (u0, u), (i0["push_impulse"], i["push_impulse"])):
                np.testing.assert_array_equal(x, y)
        pushes += int(i0["push_applied"].sum())
    assert pushes > 0
    assert default.unwrapped.state.equal(one.unwrapped.state) and one.unwrapped.state.equal(two.unwrapped.state)
    for v in envs:
        v.close()  # nothing to stop; the state keeps its values
    assert one.unwrapped.state.equal(two.unwrapped.state)


@pytest.mark.parametrize("bad, message", [
    (0, "threads must be >= 1, got 0"),
    (1.5, "threads must be an integer, got 1.5"),
    (True, "threads must be an integer, got True"),
    ("2", "threads must be an integer"),
    (numba.config.NUMBA_NUM_THREADS + 1, f"threads must be <= {numba.config.NUMBA_NUM_THREADS} (NUMBA_NUM_THREADS"),
])
def test_bad_threads_are_value_errors_naming_threads(bad, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        make_vec("Ragdoll/Balance-v0", threads=bad)
    with pytest.raises(ValueError, match=re.escape(message)):
        make("Ragdoll/InvertedPendulum-v0", threads=bad)


def test_processes_is_a_deprecated_alias_of_threads(restore_threads):
    """processes=P (the former worker processes) warns and steps on
    min(P, NUMBA_NUM_THREADS) threads; processes=0 and processes with
    threads are errors naming them."""
    cores = numba.config.NUMBA_NUM_THREADS
    for p in (1, 2, 64):
        with pytest.warns(DeprecationWarning, match=re.escape("processes= is deprecated: the worlds step on threads; "
                                                              "use threads=")):
            envs = make_vec("Ragdoll/Balance-v0", processes=p)
        assert envs.unwrapped.core.threads == min(p, cores)
        envs.close()
    from ragdoll_env.sb3 import make_sb3_vec_env

    with pytest.warns(DeprecationWarning, match="processes= is deprecated"):
        venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=2, seed=0, processes=2)
    assert venv.core.threads == min(2, cores)
    venv.close()
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="processes must be >= 1"):
        make_vec("Ragdoll/Balance-v0", processes=0)
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="give threads= only, not also"):
        make_vec("Ragdoll/Balance-v0", processes=2, threads=1)


def test_the_deprecation_warning_names_the_callers_line():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make_vec("Ragdoll/InvertedPendulum-v0", processes=1).close()
    [w] = [w for w in caught if issubclass(w.category, DeprecationWarning) and "processes=" in str(w.message)]
    assert w.filename == __file__


@pytest.mark.parametrize("steps, expected", [(None, np.inf), (50, 50)])
def test_max_return_follows_the_vector_envs_episode_length(steps, expected):
    env = make_vec("Ragdoll/InvertedPendulum-v0", num_envs=2, max_episode_steps=steps)
    try:
        assert env.max_return == expected * env.max_reward_per_step
    finally:
        env.close()
