"""Malformed inputs across the engine and the environments.

Each case asserts an error whose message names what is wrong, and, where a
state exists, that the state is unchanged afterwards (every array equal to a
``state.copy()`` taken before). Scene-builder mistakes have their own file
(test_errors.py); a few are repeated here as part of the input surface.
Training CLI cases (missing run dir, corrupted checkpoint) are tested under
tests/training.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import engine as e
from engine import Box, Capsule, Control, SceneBuilder, SceneError, Sphere


# ------------------------------------------------------------------ fixtures
@pytest.fixture
def scene():
    """Two balls on a motorised hinge above the ground, 3 worlds, stepped once."""
    b = SceneBuilder()
    b.add_ground()
    b.add_body("a", Sphere(0.1), mass=1.0, position=(0, 0, 1))
    b.add_body("c", Sphere(0.1), mass=1.0, position=(0.5, 0, 1))
    b.add_hinge("h", "a", "c", anchor=(0.25, 0, 1), max_torque=5.0)
    model = b.build()
    state = model.initial_state(3)
    e.step(model, state)
    return model, state


def unchanged(before, after):
    assert before.arrays.keys() == after.arrays.keys()
    for k, v in before.arrays.items():
        assert np.array_equal(v, after.arrays[k], equal_nan=True), f"state.{k} changed"


def raises(exc, *fragments):
    return pytest.raises(exc, match="(?s)" + ".*".join(re.escape(f) for f in fragments))


# ------------------------------------------------------------------ controls
@pytest.mark.parametrize("field, value, fragments", [
    ("motor", np.zeros((3, 2)), ("control.motor", "shape (3, 1)", "(3, 2)")),
    ("motor", np.zeros(3), ("control.motor", "shape (3, 1)", "(3,)")),
    ("force", np.zeros((3, 3)), ("control.force", "shape (3, 3, 3)", "(3, 3)")),
    ("torque", np.zeros((2, 3, 3)), ("control.torque", "shape (3, 3, 3)", "(2, 3, 3)")),
], ids=["motor-extra-axis", "motor-flat", "force-missing-axis", "torque-wrong-worlds"])
def test_control_of_wrong_shape(scene, field, value, fragments):
    model, state = scene
    before = state.copy()
    with raises(ValueError, *fragments):
        e.step(model, state, Control(**{field: value}))
    unchanged(before, state)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_control_motor_nan_or_inf(scene, bad):
    model, state = scene
    before = state.copy()
    u = np.zeros((3, 1))
    u[2, 0] = bad
    with raises(ValueError, "control.motor", "NaN or infinite", "(2, 0)"):
        e.step(model, state, Control(motor=u))
    unchanged(before, state)


def test_control_force_nan(scene):
    model, state = scene
    before = state.copy()
    f = np.zeros((3, model.num_bodies, 3))
    f[1, 2, 0] = math.nan
    with raises(ValueError, "control.force", "NaN or infinite", "(1, 2, 0)"):
        e.step(model, state, Control(force=f))
    unchanged(before, state)


def test_control_of_string_dtype(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "control.motor", "numeric", "<U"):
        e.step(model, state, Control(motor=np.full((3, 1), "a")))
    unchanged(before, state)


def test_control_of_complex_dtype(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "control.motor", "complex"):
        e.step(model, state, Control(motor=np.ones((3, 1), dtype=complex)))
    unchanged(before, state)


def test_control_not_a_control(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "control must be an engine.Control", "dict"):
        e.step(model, state, {"motor": np.zeros((3, 1))})
    unchanged(before, state)


def test_state_of_another_model(scene):
    model, state = scene
    b = SceneBuilder()
    b.add_body("solo", Sphere(0.1), mass=1.0)
    other = b.build()
    before = state.copy()
    with raises(ValueError, "state", "bodies"):
        e.step(other, state)
    unchanged(before, state)


# ------------------------------------------------------------------ impulses
def test_apply_impulse_nan(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "impulse", "NaN or infinite"):
        e.apply_impulse(model, state, "c", (math.nan, 0.0, 0.0))
    unchanged(before, state)


def test_apply_impulse_inf_point(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "impulse point", "NaN or infinite"):
        e.apply_impulse(model, state, "c", (1.0, 0.0, 0.0), point=(0.0, math.inf, 1.0))
    unchanged(before, state)


def test_apply_impulse_unknown_body(scene):
    model, state = scene
    before = state.copy()
    with raises(KeyError, "no body named 'ghost'"):
        e.apply_impulse(model, state, "ghost", (1.0, 0.0, 0.0))
    unchanged(before, state)


def test_apply_impulse_wrong_shape(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "impulse", "shape"):
        e.apply_impulse(model, state, "c", (1.0, 0.0, 0.0, 0.0))
    unchanged(before, state)


def test_apply_impulse_world_out_of_range(scene):
    model, state = scene
    before = state.copy()
    with raises(IndexError, "world"):
        e.apply_impulse(model, state, "c", (1.0, 0.0, 0.0), worlds=[5])
    unchanged(before, state)


# ------------------------------------------------------------------ worlds and states
@pytest.mark.parametrize("W", [0, -4, 2.5])
def test_bad_num_worlds(scene, W):
    model, _ = scene
    with raises(ValueError, "num_worlds", "integer >= 1", str(W)):
        model.initial_state(W)


def test_num_worlds_not_a_number(scene):
    model, _ = scene
    with raises(ValueError, "num_worlds"):
        model.initial_state("ten")


@pytest.mark.parametrize("worlds", [[3], [-4], [0, 7]])
def test_reset_worlds_out_of_range(scene, worlds):
    model, state = scene
    before = state.copy()
    with raises(IndexError, "world index out of range for 3 worlds"):
        model.reset_worlds(state, worlds)
    unchanged(before, state)


def test_reset_worlds_bad_mask(scene):
    model, state = scene
    before = state.copy()
    with raises(ValueError, "world mask must have shape (3,)", "(2,)"):
        model.reset_worlds(state, np.array([True, False]))
    unchanged(before, state)


def test_state_field_assigned_wrong_shape(scene):
    _, state = scene
    before = state.copy()
    with raises(ValueError, "state.position has shape (3, 3, 3)", "(3, 3)"):
        state.position = np.zeros((3, 3))
    unchanged(before, state)


def test_state_unknown_field(scene):
    _, state = scene
    with raises(AttributeError, "no field 'positions'"):
        state.positions = np.zeros((3, 3, 3))


# ------------------------------------------------------------------ scenes and settings
def test_negative_mass():
    with raises(SceneError, "body 'bob'", "mass must be > 0", "-3"):
        SceneBuilder().add_body("bob", Box((0.1, 0.1, 0.1)), mass=-3.0)


@pytest.mark.parametrize("shape, fragment", [
    (Sphere(-0.2), "radius"), (Box((0.1, -0.1, 0.1)), "half_extents[y]"), (Capsule(0.1, -0.5), "half_length")])
def test_negative_sizes(shape, fragment):
    with raises(SceneError, "body 'bob'", fragment):
        SceneBuilder().add_body("bob", shape, mass=1.0)


def test_inverted_hinge_limits():
    b = SceneBuilder()
    b.add_body("bob", Sphere(0.1), mass=1.0)
    with raises(SceneError, "joint 'knee'", "limits has min 1 > max -1"):
        b.add_hinge("knee", None, "bob", limits=(1.0, -1.0))


def test_inverted_twist_limits():
    b = SceneBuilder()
    b.add_body("bob", Sphere(0.1), mass=1.0)
    with raises(SceneError, "joint 'hip'", "twist_limits has min 0.5 > max -0.5"):
        b.add_ball("hip", None, "bob", twist_limits=(0.5, -0.5))


def test_negative_swing_cone():
    b = SceneBuilder()
    b.add_body("bob", Sphere(0.1), mass=1.0)
    with raises(SceneError, "joint 'hip'", "swing cone angles must lie in (0, π)"):
        b.add_ball("hip", None, "bob", swing_limits=(-0.5, 0.5))


def test_empty_scene():
    with raises(SceneError, "no dynamic body"):
        SceneBuilder().build()


@pytest.mark.parametrize("changes, fragment", [
    (dict(dt=-0.01), "dt must be a positive finite number"),
    (dict(dt=math.nan), "dt must be a number"),
    (dict(substeps=0), "substeps must be an integer >= 1"),
    (dict(articulated_contact_sweeps=0), "articulated_contact_sweeps must be an integer >= 1"),
    (dict(free_contact_relax_passes=-1), "free_contact_relax_passes must be an integer >= 0"),
    (dict(relax_iterations=1.5), "relax_iterations must be an integer >= 0"),
    (dict(joint_projection_passes=-2), "joint_projection_passes must be an integer >= 0"),
    (dict(joint_projection_slop=-0.001), "joint_projection_slop must be a finite number >= 0"),
    (dict(joint_projection_contact_weight=math.inf), "joint_projection_contact_weight must be a finite number >= 0"),
    (dict(integrator="leapfrog"), "unknown integrator 'leapfrog'"),
    (dict(contact_coloring="random"), "unknown contact_coloring 'random'"),
    (dict(joint_limits_in_tree=True, limit_hertz=120.0), "joint_limits_in_tree solves rigid limits"),
    (dict(loop_joint_hertz=0.0), "loop_joint_hertz must be > 0"),
    (dict(contact_load_stiffening=0.5), "contact_load_stiffening must be a finite number >= 1"),
    (dict(limit_soft_margin=-0.01), "limit_soft_margin must be a finite number >= 0"),
    (dict(loop_joint_damping_ratio=-1.0), "loop_joint_damping_ratio must be a finite number >= 0"),
    (dict(joint_limits_in_tree=True, joint_solver="gauss_seidel"), "joint_limits_in_tree needs joint_solver 'tree'"),
    (dict(articulated_contacts=True, solver="thesis"), "articulated_contacts needs joint_solver 'tree' and solver 'soft_step'"),
])
def test_bad_settings(scene, changes, fragment):
    model, _ = scene
    with raises(SceneError, fragment):
        model.with_settings(**changes)


@pytest.mark.parametrize("make, exc, fragments", [
    (lambda: SceneBuilder(settings={"substep": 4}), SceneError, ("unknown settings ['substep']",)),
    (lambda: SceneBuilder(settings=4), SceneError, ("settings must be a Settings or a mapping", "int")),
], ids=["unknown-key", "not-a-mapping"])
def test_builder_settings_argument(make, exc, fragments):
    with raises(exc, *fragments):
        make()


def test_builder_settings_mapping_is_used():
    assert SceneBuilder(settings={"dt": 0.01}, substeps=2).settings.dt == 0.01
    assert SceneBuilder(settings={"dt": 0.01}, substeps=2).settings.substeps == 2


def test_string_for_a_number_setting_is_named():
    b = SceneBuilder(dt="0.1")
    b.add_body("x", Sphere(0.1), mass=1.0)
    with raises(SceneError, "dt must be a number", "'0.1'"):
        b.build()


@pytest.mark.parametrize("add, fragments", [
    (lambda b: b.add_body("q", Sphere("big"), mass=1.0), ("body 'q'", "radius", "'big'")),
    (lambda b: b.add_body("q", Sphere(0.1), mass=1.0, collision_group="a"), ("body 'q'", "collision_group", "'a'")),
    (lambda b: b.add_body("q", Sphere(0.1), mass=1.0, collision_mask=-1), ("body 'q'", "collision_mask", "-1")),
    (lambda b: b.add_hinge("h", None, "a", max_torque="x"), ("joint 'h'", "max_torque", "'x'")),
    (lambda b: b.add_ball("h", None, "a", max_torque=(1.0, -1.0, 1.0)), ("joint 'h'", "max_torque", ">= 0")),
    (lambda b: b.add_body("q", Box((0.1, 0.1, 0.1)), mass=3.0, static=True), ("body 'q'", "static body has no mass")),
    (lambda b: b.materials.add(e.Material("grippy", 0.2, 0.5)), ("material 'grippy'", "kinetic_friction 0.5",
                                                                   "static_friction 0.2")),
], ids=["shape-size-string", "group-string", "mask-negative", "max-torque-string", "max-torque-negative-axis",
        "static-with-mass", "kinetic-above-static"])
def test_malformed_items_are_named(add, fragments):
    b = SceneBuilder()
    b.add_body("a", Sphere(0.1), mass=1.0)
    with raises((SceneError, ValueError), *fragments):
        add(b)
    assert [x.name for x in b.bodies] == ["a"]


def test_a_rejected_joint_to_the_world_leaves_no_world_body():
    b = SceneBuilder()
    b.add_body("a", Sphere(0.1), mass=1.0)
    with raises(SceneError, "joint 'h'", "axis has zero length"):
        b.add_hinge("h", None, "a", axis=(0, 0, 0))
    assert [x.name for x in b.bodies] == ["a"]
    b.add_body("world", Sphere(0.1), mass=1.0)  # the name is free: no stray body took it
    assert b.build().num_bodies == 2


def test_unknown_setting(scene):
    model, _ = scene
    with raises(TypeError, "'substep'"):
        model.with_settings(substep=4)


# ------------------------------------------------------------------ environments
gym = pytest.importorskip("gymnasium")
pytest.importorskip("ragdoll_env")

PENDULUM = "Ragdoll/InvertedPendulum-v0"


@pytest.fixture
def env():
    env = gym.make(PENDULUM)
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    yield env
    env.close()


@pytest.fixture
def venv():
    env = gym.make_vec(PENDULUM, num_envs=3, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    yield env
    env.close()


def test_unknown_gym_id():
    with raises(gym.error.Error, "Nope", "doesn't exist"):
        gym.make("Ragdoll/Nope-v0")


def test_unknown_gym_make_kwarg():
    with raises(TypeError, "unknown keyword argument 'bogus'", "valid keyword arguments"):
        gym.make(PENDULUM, bogus=1)


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(frame_skip=0), "frame_skip must be >= 1"),
    (dict(dt=-0.1), "dt must be a positive finite number"),
    (dict(push_strength=(5.0, 1.0)), "push_strength must have lo <= hi"),
    (dict(reset_noise_scale=-1.0), "reset_noise_scale must be >= 0"),
])
def test_bad_gym_make_values(kwargs, fragment):
    with raises(ValueError, fragment):
        gym.make(PENDULUM, **kwargs)


def test_bad_num_envs():
    with raises(ValueError, "num_envs must be >= 1", "0"):
        gym.make_vec(PENDULUM, num_envs=0, vectorization_mode="vector_entry_point")


@pytest.mark.parametrize("action, fragments", [
    (np.zeros(2), ("action must have shape (1,)", "(2,)")),
    (np.array([math.nan]), ("action has a NaN or infinite entry", "(0,)")),
    (np.array([math.inf]), ("action has a NaN or infinite entry",)),
    (np.array(["x"]), ("action must be a numeric array", "<U1")),
    (np.array([0.5 + 0.5j]), ("action must be a numeric array", "complex")),
], ids=["shape", "nan", "inf", "string", "complex"])
def test_env_step_bad_action(env, action, fragments):
    state = env.unwrapped.state
    before = state.copy()
    with raises(ValueError, *fragments):
        env.step(action)
    unchanged(before, state)


def test_env_push_nan(env):
    state = env.unwrapped.state
    before = state.copy()
    with raises(ValueError, "impulse", "NaN or infinite"):
        env.unwrapped.push((math.nan, 0.0, 0.0))
    unchanged(before, state)


def test_env_push_unknown_body(env):
    state = env.unwrapped.state
    before = state.copy()
    with raises(KeyError, "no body named 'nobody'"):
        env.unwrapped.push((1.0, 0.0, 0.0), body="nobody")
    unchanged(before, state)


def test_vector_step_wrong_shape(venv):
    state = venv.unwrapped.state
    before = state.copy()
    with raises(ValueError, "action must have shape (3, 1)", "(2, 1)"):
        venv.step(np.zeros((2, 1), dtype=np.float32))
    unchanged(before, state)


def test_vector_step_nan(venv):
    state = venv.unwrapped.state
    before = state.copy()
    a = np.zeros((3, 1), dtype=np.float32)
    a[1, 0] = np.nan
    with raises(ValueError, "action has a NaN or infinite entry", "(1, 0)"):
        venv.step(a)
    unchanged(before, state)


def test_vector_reset_mask_wrong_shape(venv):
    state = venv.unwrapped.state
    before = state.copy()
    with raises(ValueError, "reset_mask", "shape (3,)", "(2,)"):
        venv.reset(options={"reset_mask": np.ones(2, dtype=bool)})
    unchanged(before, state)


def test_vector_reset_wrong_number_of_seeds(venv):
    state = venv.unwrapped.state
    before = state.copy()
    with raises(ValueError, "list of 3 seeds", "got 2 seeds"):
        venv.reset(seed=[1, 2])
    unchanged(before, state)


def test_env_reset_unknown_option(env):
    state = env.unwrapped.state
    before = state.copy()
    with raises(ValueError, "unknown reset options ['reset_msk']", "takes none"):
        env.reset(options={"reset_msk": True})
    unchanged(before, state)


def test_vector_reset_unknown_option(venv):
    state = venv.unwrapped.state
    before = state.copy()
    rng = venv.unwrapped.core.rngs[0].bit_generator.state
    with raises(ValueError, "unknown reset options ['seed']", "'reset_mask' alone"):
        venv.reset(options={"seed": 3, "reset_mask": np.ones(3, dtype=bool)})
    unchanged(before, state)
    assert venv.unwrapped.core.rngs[0].bit_generator.state == rng
