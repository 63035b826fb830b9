"""engine.ParallelStepper: the worlds of one state stepped in worker processes."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

import engine as e
from engine.humanoid import add_humanoid


def ragdoll_on_ground():
    b = e.SceneBuilder()
    b.add_ground()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b)
    return b.build()


def random_controls(model, worlds, steps, seed=0):
    rng = np.random.default_rng(seed)
    max_torque = np.array([a.max_torque for a in model.actuators])
    return [e.Control(motor=rng.uniform(-1, 1, (worlds, model.num_actuators)) * max_torque) for _ in range(steps)]


def test_parallel_steps_are_bit_identical_to_one_process():
    # 5 worlds over 2 workers (3 + 2): the ragdoll on the ground under random
    # torques, with contacts, limits and the joint post-stabilisation at work.
    model = ragdoll_on_ground()
    controls = random_controls(model, 5, 40)
    serial, shared = model.initial_state(5), model.initial_state(5)
    for c in controls:
        e.step(model, serial, c)
    with e.ParallelStepper(model, shared, processes=2) as stepper:
        assert stepper.processes == 2
        for c in controls:
            assert stepper.step(c) is shared
        assert shared.equal(serial)
    assert shared.equal(serial)  # close keeps the values
    assert np.abs(serial.position - model.initial_state(5).position).max() > 0.05  # it moved


def test_workers_run_parallel_kernels_after_the_parent_did():
    """The parent steps a batch large enough for the kernels' parallel loop,
    then forks workers with as many worlds each: they step it too (a forked
    child of a process that used GNU OpenMP is terminated when it enters a
    parallel region; the kernels' threading layer is one that survives fork),
    bit for bit as one process."""
    from engine.core.jit import SERIAL_BELOW

    model = ragdoll_on_ground()
    W = 2 * SERIAL_BELOW
    controls = random_controls(model, W, 4, seed=2)
    serial = model.initial_state(W)
    e.step(model, serial, controls[0])  # the parallel loop, in the parent
    shared = serial.copy()
    for c in controls[1:]:
        e.step(model, serial, c)
    with e.ParallelStepper(model, shared, processes=2) as stepper:
        for c in controls[1:]:
            stepper.step(c)
        assert shared.equal(serial)


def test_the_parent_writes_between_steps_reach_the_workers():
    model = ragdoll_on_ground()
    controls = random_controls(model, 4, 10, seed=1)
    serial, shared = model.initial_state(4), model.initial_state(4)
    push = np.array([0.0, 30.0, 0.0])
    with e.ParallelStepper(model, shared, processes=2) as stepper:
        for k, c in enumerate(controls):
            for s in (serial, shared):
                if k == 3:
                    e.apply_impulse(model, s, 0, push, worlds=[1, 3])
                if k == 6:
                    s.assign([2], model.initial_state(1))  # a reset
            e.step(model, serial, c)
            stepper.step(c)
        assert shared.equal(serial)


def breakable_pair():
    """Two free spheres joined by a ball joint that breaks beyond 50 N, no gravity."""
    b = e.SceneBuilder(gravity=None)
    b.add_body("a", e.Sphere(0.1), mass=1.0, position=(0, 0, 0))
    b.add_body("b", e.Sphere(0.1), mass=3.0, position=(0.3, 0, 0))
    b.add_ball("j", "a", "b", anchor=(0.15, 0, 0), break_force=50.0)
    return b.build()


def test_events_carry_the_states_world_indices():
    model = breakable_pair()
    state = model.initial_state(4)
    state.velocity[3, 0] = (-2.0, 0.0, 0.0)  # only world 3 pulls its joint apart
    state.velocity[3, 1] = (1.0, 0.5, 0.0)
    events = []
    with e.ParallelStepper(model, state, processes=2) as stepper:
        for _ in range(30):
            events += stepper.step().events
    assert [(ev.kind, ev.name, ev.world) for ev in events] == [("joint_broken", "j", 3)]
    assert state.joint_broken[:, 0].tolist() == [False, False, False, True]


def test_a_bad_control_raises_before_any_world_moves():
    model = ragdoll_on_ground()
    state = model.initial_state(4)
    with e.ParallelStepper(model, state, processes=2) as stepper:
        before = state.copy()
        motor = np.zeros((4, model.num_actuators))
        motor[2, 5] = np.nan
        with pytest.raises(ValueError, match=re.escape("control.motor has a NaN or infinite entry at index (2, 5)")):
            stepper.step(e.Control(motor=motor))
        with pytest.raises(ValueError, match="control.motor must have shape"):
            stepper.step(e.Control(motor=np.zeros((3, model.num_actuators))))
        assert state.equal(before)
        stepper.step()  # the workers are still there
        assert not state.equal(before)


def test_a_non_finite_world_is_named_by_its_index_in_the_state():
    model = ragdoll_on_ground()
    state = model.initial_state(4)
    with e.ParallelStepper(model, state, processes=2) as stepper:
        state.velocity[3, 2, 0] = np.inf  # world 3 lives in the second worker
        with pytest.raises(e.SimulationError, match=r"world 3 turned non-finite at step 1") as info:
            stepper.step()
        assert info.value.worlds == (3,)


def test_bad_arguments_and_a_closed_stepper():
    model = ragdoll_on_ground()
    state = model.initial_state(2)
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="processes must be an integer >= 1"):
            e.ParallelStepper(model, state, processes=bad)
    other = e.SceneBuilder()
    other.add_body("x", e.Sphere(0.1), mass=1.0)
    with pytest.raises(ValueError, match="state has .* bodies per world but the model has 1"):
        e.ParallelStepper(other.build(), state)
    stepper = e.ParallelStepper(model, state, processes=8)  # no more workers than worlds
    assert stepper.processes == 2
    stepper.close()
    with pytest.raises(RuntimeError, match="closed"):
        stepper.step()
    e.step(model, state)  # the state is an ordinary state again


def test_arrays_taken_before_close_stay_readable():
    model = ragdoll_on_ground()
    state = model.initial_state(2)
    stepper = e.ParallelStepper(model, state, processes=2)
    position = state.position  # a reference into the shared memory
    stepper.step()
    stepper.close()
    assert np.array_equal(position, state.position) and np.isfinite(position).all()
    position[0, 0, 0] = 1.0  # still writable, still the state's array
    assert state.position[0, 0, 0] == 1.0


def test_a_dead_worker_closes_the_stepper_with_a_clear_error():
    model = ragdoll_on_ground()
    state = model.initial_state(4)
    stepper = e.ParallelStepper(model, state, processes=2)
    stepper.step()
    stepper._procs[1].kill()
    stepper._procs[1].join()
    before = state.copy()
    with pytest.raises(RuntimeError, match=r"worker 1 \(worlds 2-3\) died"):
        stepper.step()
    assert state.equal(before)  # no worker stepped
    with pytest.raises(RuntimeError, match="closed"):
        stepper.step()


def test_workers_leave_ctrl_c_to_the_parent():
    # Ctrl-C signals the whole process group: a worker that died of it would
    # print its own traceback and fail the step the parent is saving after.
    import os
    import signal
    import time

    model = ragdoll_on_ground()
    serial, shared = model.initial_state(4), model.initial_state(4)
    # As in a terminal (a background job may start with SIGINT ignored, which forks inherit).
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        stepper = e.ParallelStepper(model, shared, processes=2)
    finally:
        signal.signal(signal.SIGINT, before)
    with stepper:
        stepper.step()
        for p in stepper._procs:
            os.kill(p.pid, signal.SIGINT)
        time.sleep(0.2)
        assert all(p.is_alive() for p in stepper._procs)
        stepper.step()
    e.step(model, serial)
    e.step(model, serial)
    assert shared.equal(serial)


def test_events_of_a_worker_with_a_non_finite_world_are_kept():
    model = breakable_pair()
    state = model.initial_state(4)
    state.velocity[0, 0] = (-20.0, 0.0, 0.0)  # world 0 breaks its joint in the first step
    state.velocity[1, 1, 0] = np.nan  # and world 1, in the same worker, turns non-finite
    with e.ParallelStepper(model, state, processes=2) as stepper:
        with pytest.raises(e.SimulationError, match="world 1"):
            stepper.step()
        assert [(ev.kind, ev.world) for ev in state.events] == [("joint_broken", 0)]
