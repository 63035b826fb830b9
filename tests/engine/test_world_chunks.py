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


@pytest.mark.parametrize("value", [-1, 2.5])
def test_a_bad_world_chunk_is_refused(value):
    with pytest.raises(ValueError, match="world_chunk must be an integer >= 0"):
        e.Settings(world_chunk=value).validate()
