"""Malformed scenes: one test per kind of mistake. Each raises SceneError (a
ValueError) whose message names the item at fault and what is wrong with it."""

from __future__ import annotations

import math
import re

import pytest

from engine import Box, Capsule, SceneBuilder, SceneError, Settings, Sphere


def one_ball(**settings):
    b = SceneBuilder(**settings)
    b.add_body("ball", Sphere(0.1), mass=1.0)
    return b


def raises(*fragments):
    """pytest.raises(SceneError) whose message contains every fragment, in order."""
    return pytest.raises(SceneError, match=".*".join(re.escape(f) for f in fragments))


# ------------------------------------------------------------------------ bodies
@pytest.mark.parametrize("mass", [0.0, -1.0, math.nan, math.inf])
def test_bad_mass(mass):
    with raises("body 'bob'", "mass"):
        SceneBuilder().add_body("bob", Sphere(0.1), mass=mass)


def test_zero_mass():
    with raises("body 'bob'", "mass must be > 0"):
        SceneBuilder().add_body("bob", Sphere(0.1), mass=0.0)


def test_negative_mass():
    with raises("body 'bob'", "mass must be > 0", "-2"):
        SceneBuilder().add_body("bob", Sphere(0.1), mass=-2.0)


@pytest.mark.parametrize("radius", [-0.1, 0.0, math.nan])
def test_bad_sphere_radius(radius):
    with raises("body 'bob'", "radius"):
        SceneBuilder().add_body("bob", Sphere(radius), mass=1.0)


@pytest.mark.parametrize("shape, field", [
    (Capsule(-0.1, 0.2), "radius"),
    (Capsule(0.1, 0.0), "half_length"),
    (Box((0.1, 0.0, 0.1)), "half_extents[y]"),
    (Box((0.1, 0.1, math.nan)), "half_extents[z]"),
])
def test_bad_capsule_and_box_dimensions(shape, field):
    with raises("body 'bob'", field):
        SceneBuilder().add_body("bob", shape, mass=1.0)


def test_nan_position():
    with raises("body 'bob'", "position", "NaN"):
        SceneBuilder().add_body("bob", Sphere(0.1), mass=1.0, position=(0.0, math.nan, 0.0))


def test_zero_length_orientation():
    with raises("body 'bob'", "orientation", "zero length"):
        SceneBuilder().add_body("bob", Sphere(0.1), mass=1.0, orientation=(0.0, 0.0, 0.0, 0.0))


def test_duplicate_body_name():
    b = one_ball()
    with raises("body 'ball'", "already exists"):
        b.add_body("ball", Box((0.1, 0.1, 0.1)), mass=2.0)
    assert len(b.bodies) == 1


def test_unknown_material():
    with raises("body 'bob'", "unknown material 'unobtainium'"):
        SceneBuilder().add_body("bob", Sphere(0.1), mass=1.0, material="unobtainium")


@pytest.mark.parametrize("motion", [dict(velocity=(1.0, 0.0, 0.0)), dict(angular_velocity=(0.0, 0.0, 2.0))])
def test_static_body_with_velocity(motion):
    with raises("body 'post'", "static body cannot have a velocity"):
        SceneBuilder().add_body("post", Sphere(0.1), static=True, **motion)


def test_empty_scene():
    with raises("no dynamic body"):
        SceneBuilder().build()


def test_scene_with_only_static_bodies():
    b = SceneBuilder()
    b.add_ground()
    with raises("no dynamic body"):
        b.build()


# ----------------------------------------------------------------------- springs
def test_spring_naming_a_missing_body():
    with raises("spring 'sp'", "no body named 'ghost'"):
        one_ball().add_spring("sp", "ball", "ghost")


def test_spring_with_both_ends_on_one_body():
    with raises("spring 'sp'", "both ends", "'ball'"):
        one_ball().add_spring("sp", "ball", "ball", anchor_a=(0, 0, 0), anchor_b=(0, 0, 0.1))


@pytest.mark.parametrize("k", [-5.0, 0.0, math.nan])
def test_bad_spring_stiffness(k):
    with raises("spring 'sp'", "stiffness"):
        one_ball().add_spring("sp", None, "ball", anchor_a=(0, 0, 1), stiffness=k)


def test_negative_stiffness():
    with raises("spring 'sp'", "stiffness must be > 0", "-5"):
        one_ball().add_spring("sp", None, "ball", anchor_a=(0, 0, 1), stiffness=-5.0)


def test_duplicate_spring_name():
    b = one_ball()
    b.add_spring("sp", None, "ball", anchor_a=(0, 0, 1))
    with raises("spring 'sp'", "already exists"):
        b.add_spring("sp", None, "ball", anchor_a=(0, 0, 2))


# ----------------------------------------------------------------------- effects
def test_unknown_effect():
    with raises("unknown effect 'magnetism'"):
        one_ball().enable("magnetism")


def test_gravitation_with_bad_constant():
    with raises("gravitation", "G"):
        one_ball().enable("gravitation", G=-1.0)


# ------------------------------------------------------------------------ joints
def test_joint_naming_a_missing_body():
    with raises("joint 'knee'", "no body named 'shin'"):
        one_ball().add_hinge("knee", "ball", "shin")


def test_hinge_with_zero_axis():
    with raises("joint 'knee'", "axis", "zero length"):
        one_ball().add_hinge("knee", None, "ball", axis=(0.0, 0.0, 0.0))


def test_hinge_limits_min_above_max():
    with raises("joint 'knee'", "limits", "min 1", "max -1"):
        one_ball().add_hinge("knee", None, "ball", limits=(1.0, -1.0))


def test_twist_limits_min_above_max():
    with raises("joint 'hip'", "twist_limits", "min 0.5", "max 0.2"):
        one_ball().add_ball("hip", None, "ball", twist_limits=(0.5, 0.2))


@pytest.mark.parametrize("cone", [(0.5, math.pi), (0.0, 0.5), (-0.1, 0.5), (0.5, 4.0)])
def test_swing_cone_outside_open_interval(cone):
    with raises("joint 'hip'", "swing cone", "(0, π)"):
        one_ball().add_ball("hip", None, "ball", swing_limits=cone)


# ---------------------------------------------------------------------- settings
@pytest.mark.parametrize("dt", [0.0, -0.01, math.nan, math.inf])
def test_bad_dt(dt):
    with raises("settings", "dt"):
        one_ball(dt=dt).build()


def test_zero_substeps():
    with raises("settings", "substeps", "got 0"):
        one_ball(substeps=0).build()


def test_unknown_integrator():
    with raises("settings", "unknown integrator 'verlet'"):
        one_ball(integrator="verlet").build()


def test_bad_settings_object_and_with_settings():
    with raises("settings", "dt"):
        one_ball(settings=Settings(dt=0.0)).build()
    model = one_ball().build()
    with raises("settings", "substeps"):
        model.with_settings(substeps=0)
