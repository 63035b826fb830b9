"""Static contact post-stabilisation (engine.contact_projection): a body that
ends a step deeper than ``static_contact_projection_depth`` in a static shape
is moved back out to that depth, positions only; its joints are closed after."""

from __future__ import annotations

import math

import numpy as np
import pytest

import engine as e
from engine.humanoid import add_humanoid
from engine.math3d import quat_from_axis_angle, quat_rotate

DEPTH = e.Settings().static_contact_projection_depth
HALF = np.array([0.2, 0.15, 0.1])  # m, the box's half extents


def box_in_ground(depth_of_corner, **settings):
    """A box on the ground tilted 0.3 rad about x, its lowest corner
    ``depth_of_corner`` (m) below the ground, at rest."""
    b = e.SceneBuilder(**settings)
    b.add_ground()
    q = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.3)
    b.add_body("box", e.Box(tuple(HALF)), mass=2.0, position=(0, 0, 1.0), orientation=tuple(q))
    model = b.build()
    state = model.initial_state(1)
    state.position[0, 1, 2] -= lowest_corner(state) + depth_of_corner
    return model, state


def lowest_corner(state, body=1, half=HALF):
    """Height (m) of a box body's lowest corner in world 0."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    q = np.broadcast_to(state.orientation[0, body], (8, 4))
    return float((state.position[0, body] + quat_rotate(q, signs * half))[:, 2].min())


def test_a_box_ending_its_step_deep_in_the_ground_is_moved_out_to_the_projection_depth():
    # Created 15 cm deep at rest: the solve's push-out (at most max_push_out
    # 3 m/s, 5 cm a step) leaves it about 10 cm deep after one step; the
    # projection then lifts it along the normal to exactly DEPTH.
    model, state = box_in_ground(0.15)
    off_model, off_state = box_in_ground(0.15, static_contact_projection_depth=math.inf)
    e.step(model, state)
    e.step(off_model, off_state)
    assert -lowest_corner(off_state) > DEPTH + 0.05  # without it: still deep
    assert -lowest_corner(state) == pytest.approx(DEPTH, abs=1e-12)
    # Positions only: the velocities are the solve's, and the move is along the normal.
    assert np.array_equal(state.velocity, off_state.velocity)
    assert np.array_equal(state.angular_velocity, off_state.angular_velocity)
    assert np.array_equal(state.orientation, off_state.orientation)
    assert np.array_equal(state.position[0, 1, :2], off_state.position[0, 1, :2])


def test_contacts_shallower_than_the_depth_are_left_alone():
    # 1.5 cm deep: the step is the same bit for bit with the projection off.
    model, state = box_in_ground(0.015)
    off_model, off_state = box_in_ground(0.015, static_contact_projection_depth=math.inf)
    for _ in range(30):
        e.step(model, state)
        e.step(off_model, off_state)
    assert state.equal(off_state)


def test_a_world_projects_the_same_alone_or_in_a_batch():
    model, state = box_in_ground(0.15)
    batch = state.select([0, 0, 0])
    batch.position[1, 1, 2] += 0.13  # 2 cm deep: not projected
    batch.position[2, 1, 2] += 0.5   # in the air
    alone = [batch.select([w]) for w in range(3)]
    for _ in range(10):
        e.step(model, batch)
        for s in alone:
            e.step(model, s)
    for w, s in enumerate(alone):
        assert s.equal(batch.select([w]))


def test_a_foot_pushed_into_the_ground_is_moved_out_and_its_ankle_closed():
    # The standing humanoid with its left foot 8 cm down (its ankle opened by
    # 8 cm): after one step the foot is within the projection depth and the
    # joint projection has closed the ankle again by moving the leg, not by
    # turning the foot back in (its whole manifold is stiff in the metric).
    b = e.SceneBuilder()
    b.add_ground()
    add_humanoid(b, position=(0, 0, 0))
    model = b.build()
    state = model.initial_state(1)
    foot = model.body_index("foot_l")
    state.position[0, foot, 2] -= 0.08
    e.step(model, state)
    half = model.shape_params[foot]
    assert -lowest_corner(state, foot, half) <= DEPTH + 1e-3
    assert model.joints.anchor_error(state).max() < 1e-3


def test_a_negative_projection_depth_is_refused():
    with pytest.raises(ValueError, match="static_contact_projection_depth"):
        e.Settings(static_contact_projection_depth=-0.01).validate()
