"""Baseline controllers on the pendulums and the shape contract of act()."""

import gymnasium as gym
import numpy as np
import pytest

from engine import STANDARD_GRAVITY
from ragdoll_env import baselines
from ragdoll_env.baselines import LQR, PendulumPD, ZeroTorque, linearize, make_baseline, solve_dare

from env_helpers import PENDULUMS, make


def vec(env_id, n=2, **kwargs):
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


def run(envs, controller, steps):
    """Returns of the first episode of each world and whether none terminated."""
    obs, _ = envs.reset(seed=0)
    ret = np.zeros(envs.num_envs)
    alive = np.ones(envs.num_envs, dtype=bool)
    running = np.ones(envs.num_envs, dtype=bool)
    for _ in range(steps):
        obs, r, term, trunc, _ = envs.step(controller.act(obs))
        ret += r * running
        alive &= ~(term & running)
        running &= ~(term | trunc)
    return ret, alive


@pytest.mark.parametrize("env_id", PENDULUMS)
@pytest.mark.parametrize("name", ["lqr", "pd"])
def test_controllers_hold_the_pendulums_upright(env_id, name):
    envs = vec(env_id)
    ret, alive = run(envs, make_baseline(name, envs), 80)
    assert alive.all()
    per_step = envs.unwrapped.task.max_reward_per_step
    assert ret.min() > 0.99 * 80 * per_step


@pytest.mark.parametrize("env_id", PENDULUMS)
def test_zero_torque_falls(env_id):
    envs = vec(env_id)
    _, alive = run(envs, ZeroTorque(envs), 60)
    assert not alive.any()


def test_lqr_holds_tilts_near_the_torque_limit():
    envs = vec("Ragdoll/InvertedPendulum-v0", n=2, reset_noise_scale=0.15)
    _, alive = run(envs, LQR(envs), 60)
    assert alive.all()


def test_linearisation_matches_the_rigid_pendulum():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    core = env.unwrapped.core
    A, B = linearize(core)
    t = core.task
    m, L = t.pole_mass, t.pole_length
    r = 0.03
    # capsule inertia about its end (engine's shape formula via the model)
    inertia_cm = core.model.inertia[core.model.body_index("pole"), 0]
    pivot = inertia_cm + m * (0.5 * L) ** 2
    w2 = m * STANDARD_GRAVITY * 0.5 * L / pivot
    h = core.dt
    assert A[1, 0] == pytest.approx(np.sqrt(w2) * np.sinh(np.sqrt(w2) * h), rel=0.03)
    assert A[0, 1] == pytest.approx(np.sinh(np.sqrt(w2) * h) / np.sqrt(w2), rel=0.03)
    assert B[1, 0] == pytest.approx(t.max_torques[0] / pivot * h, rel=0.03)
    assert r > 0


def test_riccati_without_scipy_matches_scipy(monkeypatch):
    pytest.importorskip("scipy")
    A = np.array([[1.02, 0.04], [1.0, 1.02]])
    B = np.array([[0.007], [0.3]])
    Q, R = np.diag([10.0, 1.0]), np.eye(1)
    P1 = solve_dare(A, B, Q, R)
    import builtins

    real_import = builtins.__import__

    def no_scipy(name, *args, **kwargs):
        if name.startswith("scipy"):
            raise ImportError("no scipy")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_scipy)
    P2 = solve_dare(A, B, Q, R)
    assert np.allclose(P1, P2, rtol=1e-6)


def test_act_shapes_for_single_vector_and_sb3():
    from ragdoll_env.sb3 import make_sb3_vec_env

    single = gym.make("Ragdoll/InvertedDoublePendulum-v0")
    obs, _ = single.reset(seed=0)
    c = make_baseline("lqr", single)
    a = c.act(obs)
    assert a.shape == (2,) and a.dtype == np.float32 and np.all(np.abs(a) <= 1)
    assert c.act(np.stack([obs, obs])).shape == (2, 2)
    assert c.act(obs * 100).max() == 1.0 or c.act(obs * 100).min() == -1.0
    venv = make_sb3_vec_env("Ragdoll/InvertedDoublePendulum-v0", num_envs=3, seed=0, monitor=True)
    assert make_baseline("pd", venv).act(venv.reset()).shape == (3, 2)
    assert isinstance(make_baseline("pd", single), PendulumPD)


def test_make_baseline_rejects_unknown_and_mismatched():
    env = gym.make("Ragdoll/InvertedPendulum-v0")
    with pytest.raises(ValueError, match="unknown baseline"):
        make_baseline("mpc", env)
    with pytest.raises(TypeError):
        baselines.StandingPD(env)
    balance = make("Ragdoll/Balance-v0")
    with pytest.raises(TypeError):
        LQR(balance)


def test_lqr_on_balance_says_what_fits():
    balance = make("Ragdoll/Balance-v0")
    with pytest.raises(TypeError) as exc:
        make_baseline("lqr", balance)
    msg = str(exc.value)
    assert "LQR baseline is for the pendulum tasks" in msg and "Ragdoll/Balance-v0" in msg
    assert "'standing_pd'" in msg and "'zero'" in msg
    assert "linearize" not in msg
    for name in ("standing_pd", "pd", "zero"):  # the ones it names do fit
        make_baseline(name, balance)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", PENDULUMS)
def test_lqr_reaches_the_maximum_return(env_id):
    envs = vec(env_id, n=2)
    ret, alive = run(envs, LQR(envs), 1000)
    assert alive.all()
    assert ret.min() > 0.999 * envs.unwrapped.max_return
