"""Balance-v0: the humanoid task.

The tests in the second half need the engine's contact model
(``model.contacts.touching_static``); each calls ``needs_contacts``, which
reports xfail on an engine without contacts and does nothing once it has
them. The long ones are ``slow`` (run them with ``pytest -m slow``).
"""

import warnings

import gymnasium as gym
import numpy as np
import pytest

from ragdoll_env.baselines import StandingPD, ZeroTorque
from ragdoll_env.tasks.balance import lowest_points

from env_helpers import make


def balance(**kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gym.make("Ragdoll/Balance-v0", **kwargs)


def needs_contacts(env):
    if getattr(env.unwrapped.model, "contacts", None) is None:
        pytest.xfail("the engine has no contact model yet (engine/contacts.py); this test needs it")


# ---------------------------------------------------------------- no contacts needed
def test_observation_layout():
    env = make("Ragdoll/Balance-v0")
    u = env.unwrapped
    layout = u.obs_layout
    assert [k for k in layout] == ["pelvis_height", "pelvis_orientation", "pelvis_velocity",
                                   "pelvis_angular_velocity", "joint_angles", "joint_velocities",
                                   "com_from_feet", "com_velocity", "foot_contacts"]
    assert sum(s.stop - s.start for s in layout.values()) == env.observation_space.shape[0] == 81
    assert len(u.actuator_names) == env.action_space.shape[0] == 31
    assert u.actuator_names == tuple(a.name for a in u.model.actuators)
    assert np.array_equal(u.core.max_torque, [a.max_torque for a in u.model.actuators])


def test_reset_stands_on_the_ground_upright():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    u = env.unwrapped
    obs, _ = env.reset(seed=0)
    L = u.obs_layout
    assert obs[L["pelvis_height"]][0] == pytest.approx(u.task.standing_pelvis_height, abs=1e-6)
    assert np.allclose(obs[L["pelvis_orientation"]], [1, 0, 0, 0], atol=1e-6)
    assert np.allclose(obs[L["joint_angles"]], 0.0, atol=1e-6)
    assert abs(obs[L["com_from_feet"]][0]) < 0.1 and abs(obs[L["com_from_feet"]][1]) < 1e-6
    low = lowest_points(u.model, u.state.position[0], u.state.orientation[0], u.task.humanoid_bodies)
    assert low.min() == pytest.approx(0.0, abs=1e-9)


def test_reset_noise_keeps_the_soles_on_the_ground():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.05)
    u = env.unwrapped
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        low = lowest_points(u.model, u.state.position[0], u.state.orientation[0], u.task.humanoid_bodies)
        assert low.min() == pytest.approx(0.0, abs=1e-9)
        assert np.abs(obs[u.obs_layout["joint_angles"]]).max() <= 0.05 + 1e-6


def test_standing_reward_terms():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    env.reset(seed=0)
    _, r, term, _, info = env.step(np.zeros(31, dtype=np.float32))
    assert not term and info["healthy"]
    assert info["reward_survive"] == 1.0 and info["reward_ctrl"] == 0.0
    assert info["reward_upright"] == pytest.approx(0.5, abs=1e-3)
    assert info["reward_height"] == pytest.approx(0.5, abs=0.01)
    # the standing pose keeps its centre of mass 7 cm behind the foot centres, at rest
    assert info["capture_offset"] == pytest.approx(0.07, abs=0.01)
    assert info["reward_capture"] == pytest.approx(np.exp(-(info["capture_offset"] / 0.1) ** 2), rel=1e-9)
    assert r == pytest.approx(sum(v for k, v in info.items() if k.startswith("reward_")), rel=1e-12)
    assert r <= env.unwrapped.task.max_reward_per_step == 3.0


def test_capture_point_leads_the_centre_of_mass_by_its_velocity_over_omega():
    """ξ = c + ċ/ω with ω = √(g/h): a body moving at 0.3 m/s with its centre
    of mass 0.9 m above the feet has its capture point 0.3/√(9.81/0.9) m ahead."""
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    env.reset(seed=0)
    task, model = env.unwrapped.task, env.unwrapped.model
    com = np.array([[0.02, -0.01, 0.9]])
    xi = task.capture_offset(model, com, np.array([[0.3, 0.0, 0.0]]), np.zeros((1, 3)))
    g = np.linalg.norm(model.gravity)
    assert g == pytest.approx(9.81, abs=0.01)
    assert xi[0, 0] == pytest.approx(0.02 + 0.3 / np.sqrt(g / 0.9), rel=1e-9)
    assert xi[0, 1] == pytest.approx(-0.01, rel=1e-9)


def test_a_push_lowers_the_capture_reward():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    env.reset(seed=0)
    _, _, _, _, before = env.step(np.zeros(31, dtype=np.float32))
    env.unwrapped.push([-20.0, 0.0, 0.0], body="pelvis")  # 0.27 m/s backwards: ξ moves ~8 cm back
    _, _, _, _, after = env.step(np.zeros(31, dtype=np.float32))
    assert after["capture_offset"] > before["capture_offset"] + 0.05
    assert after["reward_capture"] < before["reward_capture"]


def test_low_pelvis_or_head_is_unhealthy():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    u = env.unwrapped
    env.reset(seed=0)
    u.state.position[0, :, 2] -= 0.5  # the whole body sinks half a metre
    _, r, term, _, info = env.step(np.zeros(31, dtype=np.float32))
    assert term and not info["healthy"] and info["reward_survive"] == 0.0 and info["reward_height"] == 0.0


class _FakeContacts:
    """Stands in for engine contacts: bodies listed in ``touching`` touch the ground."""

    effect_names = set()
    has_constraints = False
    rows = None
    projected = None

    def __init__(self, touching):
        self.touching = touching

    def project_static(self, model, state, worlds=None):
        return None  # moved nothing

    def touching_static(self, state):
        out = np.zeros((state.num_worlds, len(self.names)), dtype=bool)
        out[:, self.touching] = True
        return out


def test_touching_static_drives_foot_contacts_and_health():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    u = env.unwrapped
    m = u.model
    feet = [m.body_index("foot_l"), m.body_index("foot_r")]
    fake = _FakeContacts(feet)
    fake.names = m.body_names
    m.contacts = fake
    try:
        obs, _ = env.reset(seed=0)
        assert np.array_equal(obs[u.obs_layout["foot_contacts"]], [1.0, 1.0])
        _, _, term, _, info = env.step(np.zeros(31, dtype=np.float32))
        assert not term and info["healthy"] and not info["other_contact"]
        fake.touching = feet + [m.body_index("lower_arm_l")]
        _, _, term, _, info = env.step(np.zeros(31, dtype=np.float32))
        assert term and info["other_contact"] and not info["healthy"]
    finally:
        m.contacts = None


def test_push_is_an_impulse_on_the_chosen_body():
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    u = env.unwrapped
    env.reset(seed=0)
    chest = u.model.body_index("chest")
    v0 = u.state.velocity[0, chest].copy()
    env.unwrapped.push([10.0, 0.0, 0.0], body="chest")
    dv = u.state.velocity[0, chest] - v0
    assert dv == pytest.approx([10.0 / u.model.mass[chest], 0.0, 0.0])


def test_default_pushes_hit_chest_or_pelvis():
    env = make("Ragdoll/Balance-v0", push_interval=(0.02, 0.04), healthy_pelvis_height=0,
               healthy_head_height=0, terminate_on_contact=False)
    u = env.unwrapped
    env.reset(seed=1)
    bodies = set()
    for _ in range(20):
        info = env.step(np.zeros(31, dtype=np.float32))[4]
        if info["push_applied"]:
            bodies.add(u.model.body_names[info["push_body"]])
            assert 5.0 <= np.linalg.norm(info["push_impulse"]) <= 20.0
    assert bodies and bodies <= {"chest", "pelvis"}


def test_standing_pd_at_the_standing_pose_gives_only_its_feed_forward():
    """The PD terms vanish at the standing pose; what is left is the static load
    (knees pressed onto their limit, small gravity and balance torques)."""
    env = make("Ragdoll/Balance-v0", reset_noise_scale=0.0)
    obs, _ = env.reset(seed=0)
    names = env.unwrapped.actuator_names
    pd_only = StandingPD(env, gravity=False, balance=False, knee_lock=0.0).act(obs)
    assert pd_only.shape == (31,) and pd_only.dtype == np.float32
    assert np.abs(pd_only).max() < 1e-3
    a = StandingPD(env).act(obs)
    knees = np.array([n.startswith("knee") for n in names])
    assert np.all(a[knees] < -0.05)
    assert np.abs(a[~knees]).max() < 0.1
    batch = StandingPD(env).act(np.stack([obs, obs]))
    assert batch.shape == (2, 31) and np.array_equal(batch[1], a)


# ---------------------------------------------------------------- contacts needed
def test_feet_touch_the_ground_after_reset():
    """contacts: both foot_contacts read 1 within 1/30 s of the reset (its
    joint noise can leave one sole a few mm above the ground: at 60 Hz the
    first step of seed 0 reads (0, 1)), nothing else touches."""
    env = balance()
    needs_contacts(env)
    obs, _ = env.reset(seed=0)
    for _ in range(int(round((1 / 30) / env.unwrapped.dt))):
        obs, _, term, _, info = env.step(np.zeros(31, dtype=np.float32))
    assert np.array_equal(obs[env.unwrapped.obs_layout["foot_contacts"]], [1.0, 1.0])
    assert not info["other_contact"] and not term


def test_humanoid_rests_on_the_ground_instead_of_sinking():
    """contacts: with the PD for half a second, the soles stay within 3 cm of the ground
    (soft contacts let a standing 75 kg body sink about 2 cm at the default settings)."""
    env = balance(push_strength=0)
    needs_contacts(env)
    u = env.unwrapped
    obs, _ = env.reset(seed=0)
    pd = StandingPD(env)
    for _ in range(15):
        obs, *_ = env.step(pd.act(obs))
    low = lowest_points(u.model, u.state.position[0], u.state.orientation[0], u.task.humanoid_bodies)
    assert low.min() > -0.03


@pytest.mark.slow
def test_zero_torque_falls_onto_the_ground():
    """contacts: a passive doll collapses within 5 s (terminated), and lies on the ground, not under it."""
    env = balance(push_strength=0)
    needs_contacts(env)
    u = env.unwrapped
    obs, _ = env.reset(seed=0)
    zero = ZeroTorque(env)
    for step in range(int(5.0 / u.dt)):
        obs, _, term, _, info = env.step(zero.act(obs))
        if term:
            break
    assert term
    for _ in range(int(1.0 / u.dt)):
        obs, *_ = env.step(zero.act(obs))
    assert u.state.position[0, u.task.pelvis, 2] > 0.05


def balance_worlds(num, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gym.make_vec("Ragdoll/Balance-v0", num_envs=num, vectorization_mode="vector_entry_point", **kwargs)


def first_termination(envs, controller, seed, steps):
    """Step a vector env of Balance worlds (seeded seed + i) under a controller;
    returns each world's first terminating step (steps + 1 if none), whether it
    was truncated at the end, its return until then and its last info."""
    obs, _ = envs.reset(seed=seed)
    W = envs.num_envs
    fell = np.full(W, steps + 1)
    total = np.zeros(W)
    for step in range(1, steps + 1):
        obs, r, term, trunc, info = envs.step(controller.act(obs))
        alive = fell > steps
        total += np.where(alive, r, 0.0)
        fell[alive & term] = step
    return fell, trunc, total, info


def test_standing_pd_stands_and_zero_torque_falls():
    """contacts: without pushes the PD baseline keeps three seeds standing for
    5 s; without torques the same seeds fall within 1.5 s (knees buckling)."""
    envs = balance_worlds(3, push_strength=(0.0, 0.0))
    needs_contacts(envs)
    steps = int(round(5.0 / envs.unwrapped.dt))
    fell, _, _, info = first_termination(envs, StandingPD(envs), 0, steps)
    assert np.all(fell > steps), f"fell at steps {fell}"
    assert np.all(info["head_height"] > 1.4)
    fell, *_ = first_termination(envs, ZeroTorque(envs), 0, int(round(1.5 / envs.unwrapped.dt)))
    assert np.all(fell <= int(round(1.5 / envs.unwrapped.dt))), f"zero torque fell at steps {fell}"


def test_standing_pd_keeps_its_feet_still_with_closed_joints():
    """contacts: at ``engine.CLOSED_JOINTS`` (rigid joints, contacts solved in
    contact space before the joints) the standing PD settles 20 reset worlds
    without pushes and no foot turns faster than 20 rad/s in the first second
    (measured 4.1 rad/s, one articulated-contact sweep 4.7; SOFT_JOINTS, the defaults before 2026-12-04, 8.2). With the contact columns read
    before the joint solve had taken back what the ankle motors turned the
    feet within a substep, a foot spun at 125 rad/s in one world."""
    import engine
    from ragdoll_env.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("Ragdoll/Balance-v0", num_envs=20, seed=0, push_strength=0.0, **engine.CLOSED_JOINTS)
    core = venv.core
    feet = [core.model.body_index(core.task.humanoid.name(n)) for n in ("foot_l", "foot_r")]
    pd = StandingPD(venv)
    obs = venv.reset()
    spin, fell = 0.0, np.zeros(20, dtype=bool)
    for _ in range(int(round(1.0 / core.dt))):
        obs, _, done, _ = venv.step(pd.act(obs))
        fell |= done
        spin = max(spin, float(np.linalg.norm(core.state.angular_velocity[:, feet], axis=-1).max()))
    assert spin < 20.0, f"a foot turned at {spin:.1f} rad/s"
    assert not fell.any()


@pytest.mark.slow
def test_standing_pd_stands_20_seconds_without_pushes():
    """contacts: the PD baseline keeps the humanoid standing for whole 20 s episodes, seeds 0-9."""
    envs = balance_worlds(10, push_strength=(0.0, 0.0))
    needs_contacts(envs)
    steps = envs.unwrapped.core.max_episode_steps
    assert steps == 1200
    fell, trunc, total, info = first_termination(envs, StandingPD(envs), 0, steps)
    assert np.all(fell > steps), f"fell at steps {fell}"
    assert np.all(trunc)
    assert np.all(info["head_height"] > 1.4)
    assert np.all(total > 0.9 * envs.unwrapped.max_return)


@pytest.mark.slow
def test_pushes_are_counted_as_survived_with_the_pd():
    """contacts: with gentle pushes the PD survives some of them, and info counts them."""
    env = balance(push_strength=(3.0, 6.0), push_interval=(1.0, 1.5))
    needs_contacts(env)
    obs, _ = env.reset(seed=0)
    pd = StandingPD(env)
    for _ in range(int(6.0 / env.unwrapped.dt)):
        obs, _, term, _, info = env.step(pd.act(obs))
        if term:
            break
    assert info["pushes"] >= 2 and info["pushes_survived"] >= 1


@pytest.mark.parametrize("load_sharing", [True, False])
def test_standing_pd_shares_the_load_to_survive_sideways_pushes(load_sharing):
    """contacts: 20 N·s sideways at the pelvis (both ways) and diagonally
    forward at the chest (both sides); with the legs' support rows scaled by
    the load each foot must carry, the PD stands 3.3 s later (measured: all
    four); without it the unloaded leg's hip swings its foot in under the
    body and each of them falls (measured 1.6-1.8 s after the push)."""
    from ragdoll_env.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("Ragdoll/Balance-v0", num_envs=4, seed=3, push_strength=0.0)
    core = venv.core
    pd = StandingPD(venv, load_sharing=load_sharing)
    h = core.task.humanoid
    c = 20.0 / np.sqrt(2.0)
    pushes = [("pelvis", (0.0, 20.0, 0.0)), ("pelvis", (0.0, -20.0, 0.0)), ("chest", (c, c, 0.0)),
              ("chest", (c, -c, 0.0))]
    obs = venv.reset()
    alive = np.ones(4, dtype=bool)
    push_step = int(round(0.67 / core.dt))
    for k in range(int(round(4.0 / core.dt))):
        if k == push_step:
            for w, (body, impulse) in enumerate(pushes):
                core.push(w, core.model.body_index(h.name(body)), np.array(impulse))
        obs, _, done, _ = venv.step(pd.act(obs))
        alive &= ~done
    assert alive.all() if load_sharing else not alive.any(), f"standing: {alive}"


def test_standing_pd_steadies_a_lifted_foot():
    """contacts: the sideways pelvis pushes of the load-sharing test lift one
    foot for 0.5-0.8 s. At full gains its ankle PD, on the 1 kg foot alone
    (kd Δt / I about 2.6 about the roll axis at 60 Hz, past the explicit
    damper's limit of 2), flips its roll torque's sign at every control step
    (measured with these two worlds and two diagonal chest pushes: 43 of 43
    and 48 of 48 lifted steps in these two); at the default quarter gains in
    7 of 33 and 11 of 45. The ankle rows of a lifted foot alone change, by
    three quarters of their PD part."""
    from ragdoll_env.sb3 import make_sb3_vec_env

    flip_share = {}
    for scale in (1.0, 0.25):
        venv = make_sb3_vec_env("Ragdoll/Balance-v0", num_envs=2, seed=3, push_strength=0.0)
        core = venv.core
        layout, names = core.task.obs_layout, list(core.actuator_names)
        pd = StandingPD(venv, lifted_ankle=scale)
        rows = [names.index(f"ankle_{s}:swing_z") for s in "lr"]
        obs = venv.reset()
        flips = lifted = 0
        before = None
        for k in range(round(2.5 / core.dt)):
            if k == round(0.67 / core.dt):
                for w, side in enumerate((1.0, -1.0)):
                    core.push(w, core.model.body_index(core.task.humanoid.name("pelvis")), np.array([0.0, 20.0 * side, 0.0]))
            a = pd.act(obs)
            now = (a[:, rows], obs[:, layout["foot_contacts"]] == 0)
            if before is not None:
                up = now[1] & before[1]
                flips += int((up & (now[0] * before[0] < 0)).sum())
                lifted += int(up.sum())
            before = now
            obs, _, done, _ = venv.step(a)
            assert not done.any()
        assert lifted >= 60, f"the pushes lifted a foot for only {lifted} steps"
        flip_share[scale] = flips / lifted
    assert flip_share[1.0] > 0.9 and flip_share[0.25] < 0.35, flip_share
    obs = venv.reset()[:1].copy()
    full, lifted_pd = StandingPD(venv, lifted_ankle=1.0), StandingPD(venv)
    obs[:, layout["foot_contacts"]] = [0.0, 1.0]
    obs[:, layout["joint_angles"]] += 0.05
    change = full.act(obs)[0].astype(float) - lifted_pd.act(obs)[0]
    diff = np.flatnonzero(change)
    assert [names[k] for k in diff] == [f"ankle_l:{axis}" for axis in ("twist", "swing_y", "swing_z")]
    pd_part = StandingPD(venv, lifted_ankle=1.0, gravity=False, balance=False).act(obs)[0]
    np.testing.assert_allclose(change[diff], 0.75 * pd_part[diff], rtol=1e-5, atol=1e-7)
    assert np.abs(pd_part[diff]).min() > 1e-3


def test_each_push_counts_once_its_world_stood_a_second_after_it():
    """contacts: pushes every 0.5 s, closer than the 1 s recovery time: each push
    counts once the world has stood 1 s after it, whatever pushes came since,
    so all but the last (0.5 s before the end) count."""
    env = balance(push_strength=3.0, push_interval=(0.5, 0.5), max_episode_steps=300)
    needs_contacts(env)
    obs, _ = env.reset(seed=0)
    pd = StandingPD(env)
    while True:
        obs, _, term, trunc, info = env.step(pd.act(obs))
        if term or trunc:
            break
    assert trunc and not term
    length = 300 * env.unwrapped.dt  # 5 s
    push_times = 0.5 * np.arange(1, info["pushes"] + 1)
    assert info["pushes"] == 9
    assert info["pushes_survived"] == int(np.sum(push_times + 1.0 <= length + 1e-9))  # all but the last
