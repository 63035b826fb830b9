"""Threads and determinism of the compiled step: the thread count changes no
bit, W worlds together equal each alone, one model steps several states."""

import numba
import pytest

import engine
from engine.core.jit import get_threads, set_threads
from benchmarks import scenes


def _run(case, state, steps):
    for k in range(steps):
        engine.step(case.model, state, None if case.controller is None else case.controller(k, state))
    return state


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
def test_one_and_two_threads_give_the_same_bits(restore_threads):
    runs = []
    for threads in (1, 2, 1):
        set_threads(threads)
        case = scenes.ragdoll_max_torque(num_worlds=4)  # a fresh controller: the same torques
        runs.append(_run(case, case.state.copy(), 40))
    assert runs[0].equal(runs[1]) and runs[0].equal(runs[2])
    assert not runs[0].equal(case.state)  # it moved


def test_worlds_together_equal_each_alone():
    case = scenes.ragdoll_max_torque(num_worlds=3)
    motors = [case.controller(k, None).motor.copy() for k in range(30)]
    together = case.state.copy()
    for m in motors:
        engine.step(case.model, together, engine.Control(motor=m))
    for w in range(3):
        alone = case.state.select([w])
        for m in motors:
            engine.step(case.model, alone, engine.Control(motor=m[w:w + 1]))
        assert alone.equal(together.select([w])), f"world {w}"


def test_one_model_steps_two_states_interleaved():
    case = scenes.ragdoll_drops()
    a, b = case.state.select([0]), case.state.select([1])
    a_alone, b_alone = a.copy(), b.copy()
    for _ in range(40):
        engine.step(case.model, a)
        engine.step(case.model, b)
    for _ in range(40):
        engine.step(case.model, a_alone)
    for _ in range(40):
        engine.step(case.model, b_alone)
    assert a.equal(a_alone) and b.equal(b_alone)
    assert not a.equal(b)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2", numba.config.NUMBA_NUM_THREADS + 1])
def test_set_threads_names_a_bad_count(bad, restore_threads):
    with pytest.raises(ValueError, match="threads"):
        set_threads(bad)


def test_set_threads_default_is_every_core(restore_threads):
    assert set_threads() == numba.config.NUMBA_NUM_THREADS == get_threads()
    assert set_threads(1) == 1 == get_threads()
