"""Static contact post-stabilisation (engine.contact_projection, on by
default at 2 cm): a body that ends a step deeper than ``static_contact_projection_depth``
in a static shape is moved back out to that depth, positions only; its joints
are closed after."""

from __future__ import annotations

import math

import numpy as np
import pytest

import engine as e
from engine import contact_projection as cp
from engine import math3d
from engine.collision import collide_rows
from engine.humanoid import add_humanoid
from engine.math3d import quat_from_axis_angle, quat_rotate
from tests.engine.saved_states import saved_soak_world

DEPTH = 0.02  # m, static_contact_projection_depth in these tests
HALF = np.array([0.2, 0.15, 0.1])  # m, the box's half extents


def box_in_ground(depth_of_corner, **settings):
    """A box on the ground tilted 0.3 rad about x, its lowest corner
    ``depth_of_corner`` (m) below the ground, at rest."""
    b = e.SceneBuilder(**{"static_contact_projection_depth": DEPTH, **settings})
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


@pytest.mark.parametrize("chunk", [None, 1])
def test_a_world_projects_the_same_alone_or_in_a_batch(chunk):
    model, state = box_in_ground(0.15, world_chunk=chunk)
    batch = state.select([0, 0, 0])
    batch.position[1, 1, 2] += 0.13  # 2 cm deep: not projected
    batch.position[2, 1, 2] += 0.5   # in the air
    alone = [batch.select([w]) for w in range(3)]
    e.step(model, batch)
    for s in alone:
        e.step(model, s)
    for w, s in enumerate(alone):
        assert s.equal(batch.select([w]))
    assert -lowest_corner(batch.select([0])) == pytest.approx(DEPTH, abs=1e-12)  # projected
    assert -lowest_corner(batch.select([1])) < DEPTH  # the solve alone lifted it


def test_a_box_deep_across_two_static_tiles_moves_out_once():
    # Two static boxes side by side, tops flush at z = 0, and a dynamic box
    # straddling their seam 12 cm deep: both pairs are deep along the same
    # normal, and the box rises to DEPTH below the tops, not by both excesses.
    b = e.SceneBuilder(static_contact_projection_depth=DEPTH)
    b.enable("contacts")
    for name, x in (("tile_a", -0.5), ("tile_b", 0.5)):
        b.add_body(name, e.Box((0.5, 0.5, 0.1)), position=(x, 0, -0.1), static=True)
    b.add_body("box", e.Box(tuple(HALF)), mass=2.0, position=(0, 0, HALF[2] - 0.12))
    model = b.build()
    state = model.initial_state(1)
    e.step(model, state)
    box = model.body_index("box")
    assert -lowest_corner(state, box) == pytest.approx(DEPTH, abs=1e-9)


def test_a_sphere_deep_in_a_static_box_is_moved_out_against_the_normal():
    # The sphere is the pair's first shape here (sphere-box), so it moves
    # against the normal, which points from it to the box.
    b = e.SceneBuilder(static_contact_projection_depth=DEPTH)
    b.enable("contacts")
    b.add_body("block", e.Box((1.0, 1.0, 0.5)), position=(0, 0, -0.5), static=True)
    b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0, 0, 0.1 - 0.15))
    model = b.build()
    state = model.initial_state(1)
    e.step(model, state)
    ball = model.body_index("ball")
    assert state.position[0, ball, 2] - 0.1 == pytest.approx(-DEPTH, abs=1e-9)
    assert np.array_equal(state.position[0, ball, :2], [0.0, 0.0])


@pytest.mark.parametrize("tilt", [0.0, 0.5])
def test_a_foot_pushed_into_the_ground_is_moved_out_and_its_ankle_closed(tilt):
    # The standing humanoid with its left foot 8 cm down (its ankle opened by
    # 8 cm), flat or tipped 0.5 rad onto its heel: after one step the foot is
    # within the projection depth (6.7 cm deep without it, flat) and the
    # joint projection has closed the ankle by moving the leg, not by
    # turning the foot back in. (Here the foot's rows alone hold it in the
    # joint projection's metric; the moved manifold's own points were needed
    # under random maximum torques, where a foot turned about its one deep
    # corner went 10.8 cm in: the hard cases' 5 cm bound covers that.)
    b = e.SceneBuilder(static_contact_projection_depth=DEPTH)
    b.add_ground()
    add_humanoid(b, position=(0, 0, 0))
    model = b.build()
    state = model.initial_state(1)
    foot = model.body_index("foot_l")
    half = model.shape_params[foot]
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), -tilt)  # toe up
    state.orientation[0, foot] = math3d.quat_mul(q, state.orientation[0, foot])
    state.position[0, foot, 2] -= lowest_corner(state, foot, half) + 0.08
    e.step(model, state)
    assert -lowest_corner(state, foot, half) <= DEPTH + 1e-3
    assert model.joints.anchor_error(state).max() < 1e-3


def test_the_thesis_solver_keeps_its_own_penetration_resolution():
    model, state = box_in_ground(0.15, solver="thesis")
    e.step(model, state)
    assert model.contacts.projected is None


def test_the_projection_is_on_by_default_at_2_cm_and_off_at_the_old_defaults():
    assert e.Settings().static_contact_projection_depth == 0.02
    assert math.isinf(e.Settings(**e.SOFT_JOINTS).static_contact_projection_depth)


def test_a_negative_projection_depth_is_refused():
    with pytest.raises(ValueError, match="static_contact_projection_depth"):
        e.Settings(static_contact_projection_depth=-0.01).validate()


def _deepest_and_anchor_after_one_step(name, **settings):
    """(deepest penetration m, largest joint anchor error m) at the end of one
    step of a saved state (the next step's narrow phase measures the depth)."""
    model, state, motor = saved_soak_world(name, **settings)
    e.step(model, state, e.Control(motor=motor))
    anchor = model.joints.anchor_error(state).max()
    e.step(model, state, e.Control(motor=motor))
    sep = state.contact_separation
    return -sep[np.isfinite(sep)].min(), anchor


def test_a_shin_turned_into_the_ground_by_its_ankle_closing_is_moved_out_in_the_next_round(monkeypatch):
    """World 11 of 16 under random maximum torques (seed 0) before its step
    466: the projection moves the left foot out of the ground, and closing
    the ankle turns the shin 5.4 cm in (measured with one round). The next
    rounds move the shin out and close the joints again: measured 2.8 cm
    deep, the joints at their 0.2 mm slop."""
    assert cp.ROUNDS == 3
    rounds = _deepest_and_anchor_after_one_step("maxtorque16_world11_step466")
    monkeypatch.setattr(cp, "ROUNDS", 1)
    one_round = _deepest_and_anchor_after_one_step("maxtorque16_world11_step466")
    assert one_round[0] > 0.05
    assert rounds[0] < 0.03
    assert rounds[1] < 0.0003


def test_the_rounds_step_a_world_the_same_alone_or_in_a_batch():
    """The two saved states above side by side with a ragdoll in the air
    whose forearm was thrown 3 m off its elbow (more than the joint
    projection's passes close in one step), in one batch: each world ends
    the step bit for bit as alone, though the rounds after the first run in
    some worlds and not in others."""
    saved = [saved_soak_world(name) for name in ("maxtorque16_world11_step466", "soak_world403_step560")]
    model = saved[0][0]
    thrown = model.initial_state(1)
    thrown.position[..., 2] += 1.0
    thrown.position[0, model.body_index("lower_arm_l")] += (3.0, 0.0, 0.0)
    worlds = [saved[0][1], thrown, saved[1][1]]
    motors = [saved[0][2], np.zeros_like(saved[0][2]), saved[1][2]]
    alone = []
    for state, motor in zip(worlds, motors):
        one = state.copy()
        e.step(model, one, e.Control(motor=motor))
        alone.append(one)
    assert model.joints.anchor_error(alone[1]).max() > 0.01  # still open after this step's passes
    batch = model.initial_state(3)
    for k in batch.arrays:
        batch.arrays[k][...] = np.concatenate([s.arrays[k] for s in worlds])
    e.step(model, batch, e.Control(motor=np.concatenate(motors)))
    for w in range(3):
        assert batch.worlds(w, w + 1).equal(alone[w])


def test_the_moved_points_are_the_manifolds_points_in_the_bodys_frame():
    # Two worlds, the box deep in world 1 only: its four corners under the
    # ground (the exact narrow phase, every point), as lever arms in the
    # box's frame at its position before the move, the normal out of the
    # ground; world 0 is left alone bit for bit.
    model, state = box_in_ground(0.15)
    batch = state.select([0, 0])
    batch.position[0, 1, 2] += 1.0
    before = batch.copy()
    moved = cp.project_static_contacts(model.contacts, model, batch, DEPTH)
    assert moved.worlds.tolist() == [1]
    assert np.array_equal(moved.position_before, before.position[[1]])
    assert np.array_equal(moved.orientation_before, before.orientation[[1]])
    assert np.array_equal(batch.position[0], before.position[0])
    m = collide_rows(model.contacts.static_pair_kind, before.position[1, 0], before.orientation[1, 0],
                     model.shape_params[0], before.position[1, 1], before.orientation[1, 1], model.shape_params[1],
                     np.inf)
    pts = m.point[0][m.valid[0]]
    assert moved.world.tolist() == [1] * len(pts) and moved.body.tolist() == [1] * len(pts)
    q = np.broadcast_to(before.orientation[1, 1], (len(pts), 4))
    np.testing.assert_allclose(before.position[1, 1] + quat_rotate(q, moved.lever), pts, atol=1e-14)
    assert np.array_equal(moved.normal, np.tile(m.normal[0], (len(pts), 1)))
    # Out along the normal by the excess over the depth.
    excess = -m.separation[0].min() - DEPTH
    np.testing.assert_allclose(batch.position[1, 1] - before.position[1, 1], excess * m.normal[0], atol=1e-14)


def test_merged_keeps_only_the_later_rounds_points_of_a_body_moved_again_world_by_world():
    def points(world, body, tag):
        world, body = np.array(world), np.array(body)
        lever = np.stack([np.full(world.size, tag), world * 1.0, body * 1.0], axis=1)
        return cp.ProjectedPoints(world, body, lever, -lever, np.unique(world), np.zeros((2, 4, 3)),
                                  np.zeros((2, 4, 4)))

    first = points([0, 0, 0, 3, 3], [1, 2, 2, 1, 2], 1.0)
    then = points([0, 3, 3], [2, 3, 3], 2.0)
    out = cp.merged(first, then)
    # World 0: body 1 from the first round, body 2 only from the second;
    # world 3: the first round's two, then the second's.
    assert out.world.tolist() == [0, 0, 3, 3, 3, 3]
    assert out.body.tolist() == [1, 2, 1, 2, 3, 3]
    assert out.lever[:, 0].tolist() == [1.0, 2.0, 1.0, 1.0, 2.0, 2.0]
    assert np.array_equal(out.normal, -out.lever)
    assert out.worlds is first.worlds and out.position_before is first.position_before
    assert cp.merged(None, then) is then
