"""Settings.world_chunk: a large batch stepped as slices of worlds."""

from __future__ import annotations

import numpy as np
import pytest

import engine as e
from tests.engine.test_parallel import breakable_pair, ragdoll_on_ground, random_controls


def test_slices_step_bit_identically_to_one_pass():
    # 7 worlds in slices of 3, 3 and 1: the ragdoll on the ground under random
    # torques, its fall bringing articulated contacts of different counts per slice.
    one_pass = ragdoll_on_ground().with_settings(world_chunk=None)
    sliced = one_pass.with_settings(world_chunk=3)
    controls = random_controls(one_pass, 7, 60, seed=2)
    a, b = one_pass.initial_state(7), sliced.initial_state(7)
    for c in controls:
        e.step(one_pass, a, c)
        e.step(sliced, b, c)
    assert a.equal(b)
    assert np.abs(a.position - one_pass.initial_state(7).position).max() > 0.05  # it moved


def test_events_and_errors_name_the_batchs_worlds():
    model = breakable_pair().with_settings(world_chunk=3)
    state = model.initial_state(5)
    state.velocity[3, 0] = (-2.0, 0.0, 0.0)  # only world 3 (the second slice's first) pulls its joint apart
    state.velocity[3, 1] = (1.0, 0.5, 0.0)
    events = []
    for _ in range(30):
        events += e.step(model, state).events
    assert [(ev.kind, ev.name, ev.world) for ev in events] == [("joint_broken", "j", 3)]
    state.velocity[4, 1, 0] = np.inf
    with np.errstate(invalid="ignore"), pytest.raises(e.SimulationError, match="world 4 turned non-finite") as err:
        e.step(model, state)
    assert tuple(err.value.worlds) == (4,)


@pytest.mark.parametrize("value", [-1, 2.5, 256.0, True])
def test_a_bad_world_chunk_is_refused(value):
    with pytest.raises(ValueError, match="world_chunk must be an integer >= 0"):
        e.Settings(world_chunk=value).validate()


def _box_on_box_and_a_ball():
    """A box turned 45° and tilted 0.08 rad on a box on the ground, and a ball beside them."""
    b = e.SceneBuilder()
    b.add_ground()
    b.add_body("base", e.Box((0.2, 0.2, 0.1)), mass=2.0, position=(0.0, 0.0, 0.1))
    half, tilt = np.pi / 8, 0.04
    q = np.array([np.cos(half) * np.cos(tilt), np.sin(tilt) * np.cos(half), np.sin(tilt) * np.sin(half),
                  np.sin(half) * np.cos(tilt)])
    b.add_body("top", e.Box((0.15, 0.15, 0.05)), mass=1.0, position=(0.0, 0.0, 0.26), orientation=q / np.linalg.norm(q))
    b.add_body("ball", e.Sphere(0.05), mass=1.0, position=(2.0, 0.0, 0.5))
    return b.build()


def test_a_worlds_contacts_do_not_depend_on_the_other_worlds():
    """Each pair's speculative margin is its own: with one margin for all pairs
    (the largest), the box pair's choice of its four points in world 0
    changed when another world's ball fell fast, and world 0 in a batch left
    world 0 alone (3e-5 m after 4 steps)."""
    model = _box_on_box_and_a_ball()
    batch = model.initial_state(2)
    batch.velocity[1, 3] = (0.0, 0.0, -30.0)
    alone = model.initial_state(1)
    for _ in range(20):
        e.step(model, batch)
        e.step(model, alone)
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        assert np.array_equal(batch.arrays[key][0], alone.arrays[key][0]), key
