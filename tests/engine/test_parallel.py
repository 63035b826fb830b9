"""Batched steps on threads (what replaced engine.ParallelStepper's worker
processes): numba's threading layer, the thread count per calling thread,
and the bits of a batched step on one and on two threads."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import numba
import numpy as np
import pytest

import engine as e
from engine.core.jit import SERIAL_BELOW, get_threads, set_threads
from engine.humanoid import add_humanoid

REPO = Path(__file__).resolve().parents[2]
TWO_THREADS = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
#: W: enough worlds for the kernels' prange loops (SERIAL_BELOW and more steps on the calling thread)
W = 2 * SERIAL_BELOW


def ragdoll_on_ground():
    b = e.SceneBuilder()
    b.add_ground()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b)
    return b.build()


def breakable_pair():
    """Two free spheres joined by a ball joint that breaks beyond 50 N, no gravity."""
    b = e.SceneBuilder(gravity=None)
    b.add_body("a", e.Sphere(0.1), mass=1.0, position=(0, 0, 0))
    b.add_body("b", e.Sphere(0.1), mass=3.0, position=(0.3, 0, 0))
    b.add_ball("j", "a", "b", anchor=(0.15, 0, 0), break_force=50.0)
    return b.build()


def random_controls(model, worlds, steps, seed=0):
    rng = np.random.default_rng(seed)
    max_torque = np.array([a.max_torque for a in model.actuators])
    return [e.Control(motor=rng.uniform(-1, 1, (worlds, model.num_actuators)) * max_torque) for _ in range(steps)]


@pytest.fixture(scope="module")
def lying():
    """(model, W ragdolls fallen onto the ground under 1.5 s of random torques)."""
    model = ragdoll_on_ground()
    state = model.initial_state(W)
    for c in random_controls(model, W, 90, seed=1):
        e.step(model, state, c)
    standing = model.initial_state(1).position[0, 1:, 2].max()
    assert standing > 1.4 and (state.position[:, 1:, 2].max(axis=1) < 0.8).all()  # fallen: no body above 0.8 m
    return model, state


def _run(model, state, controls, threads):
    s = state.copy()
    events = []
    for c, n in zip(controls, threads):
        set_threads(n)
        e.step(model, s, c)
        events += [(ev.kind, ev.name, ev.world) for ev in s.events]
    return s, events


@TWO_THREADS
def test_lying_ragdolls_on_one_and_two_threads_are_bit_identical(lying, restore_threads):
    """W = 16 lying ragdolls (many contacts, limits, the joint tree) under
    random torques: 1 thread, 2 threads and a count changed between steps
    give the same state bit for bit."""
    model, start = lying
    controls = random_controls(model, W, 12, seed=2)
    one, ev1 = _run(model, start, controls, [1] * 12)
    two, ev2 = _run(model, start, controls, [2] * 12)
    mixed, ev3 = _run(model, start, controls, [1, 2] * 6)
    assert one.equal(two) and one.equal(mixed)
    assert ev1 == ev2 == ev3
    assert not one.equal(start)  # it moved


@TWO_THREADS
@pytest.mark.parametrize("threads", [1, 2])
def test_events_of_a_batched_step_carry_the_states_world_indices(threads, restore_threads):
    set_threads(threads)
    model = breakable_pair()
    state = model.initial_state(W)
    for w in (3, W - 4):  # only these worlds pull their joint apart
        state.velocity[w, 0] = (-2.0, 0.0, 0.0)
        state.velocity[w, 1] = (1.0, 0.5, 0.0)
    events = []
    for _ in range(30):
        e.step(model, state)
        events += [(ev.kind, ev.name, ev.world) for ev in state.events]
    assert events == [("joint_broken", "j", 3), ("joint_broken", "j", W - 4)]
    assert np.flatnonzero(state.joint_broken[:, 0]).tolist() == [3, W - 4]


@TWO_THREADS
@pytest.mark.parametrize("threads", [1, 2])
def test_a_non_finite_world_of_a_batched_step_is_named_by_its_index(threads, restore_threads):
    set_threads(threads)
    model = ragdoll_on_ground()
    state = model.initial_state(W)
    state.velocity[W - 5, 2, 0] = np.inf
    with pytest.raises(e.SimulationError, match=rf"world {W - 5} turned non-finite at step 1") as info:
        e.step(model, state)
    assert info.value.worlds == (W - 5,)


def test_a_batched_step_in_another_python_thread_gives_the_same_bits(lying):
    """The envs and the training step from whichever Python thread calls them:
    a batched step from a second thread (numba's thread count there is its
    own, all cores) equals the main thread's."""
    model, start = lying
    controls = random_controls(model, W, 4, seed=3)
    here, _ = _run(model, start, controls, [get_threads()] * 4)
    out = {}

    def work():
        out["threads"] = get_threads()
        s = start.copy()
        for c in controls:
            e.step(model, s, c)
        out["state"] = s

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert out["threads"] == numba.config.NUMBA_NUM_THREADS
    assert out["state"].equal(here)


def test_the_thread_count_is_per_calling_thread(restore_threads):
    set_threads(1)
    seen = []
    t = threading.Thread(target=lambda: seen.append(get_threads()))
    t.start()
    t.join()
    assert get_threads() == 1 and seen == [numba.config.NUMBA_NUM_THREADS]


@pytest.mark.parametrize("bad", [0, -1, 1.5, 2.0, True, "2", numba.config.NUMBA_NUM_THREADS + 1])
def test_set_threads_rejects_a_bad_count_naming_threads_and_the_range(bad, restore_threads):
    before = get_threads()
    with pytest.raises(ValueError, match=rf"threads must be an integer in 1\.\.{numba.config.NUMBA_NUM_THREADS} "
                                         rf"\(NUMBA_NUM_THREADS\), got "):
        set_threads(bad)
    assert get_threads() == before  # unchanged


def test_set_threads_takes_numpy_integers(restore_threads):
    assert set_threads(np.int64(1)) == 1 == get_threads()
    assert isinstance(set_threads(np.int32(1)), int)


PROBE = """
import json, sys, warnings
import numpy as np
if sys.argv[1] == "no-omp":
    sys.modules["numba.np.ufunc.omppool"] = None  # as on a machine without libgomp: the import fails
import numba
import engine
from engine.humanoid import add_humanoid
b = engine.SceneBuilder()
b.add_ground()
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    add_humanoid(b)
model = b.build()
state = model.initial_state(int(sys.argv[2]))
engine.step(model, state)
print(json.dumps({"layer": numba.threading_layer(), "position": state.position.tolist()}))
"""


def _probe(mode, env=None):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")} | (env or {})
    out = subprocess.run([sys.executable, "-c", PROBE, mode, str(W)], cwd=REPO, env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _omp_loads() -> bool:
    try:
        import numba.np.ufunc.omppool  # noqa: F401
    except ImportError:
        return False
    return True


def test_the_threading_layer_is_omp_and_falls_back_without_it():
    """engine.core.jit prefers GNU OpenMP (cheap launches); without libgomp
    numba takes the next layer (TBB where it loads, else workqueue) rather
    than failing, and an explicit NUMBA_THREADING_LAYER is kept. Every
    layer gives the same bits."""
    default = _probe("default")
    assert default["layer"] == ("omp" if _omp_loads() else default["layer"])
    assert default["layer"] in ("omp", "tbb", "workqueue")
    fallback = _probe("no-omp")
    assert fallback["layer"] in ("tbb", "workqueue")
    chosen = _probe("default", {"NUMBA_THREADING_LAYER": "workqueue"})
    assert chosen["layer"] == "workqueue"
    assert default["position"] == fallback["position"] == chosen["position"]


def _spawned_step(queue, seed):
    model = ragdoll_on_ground()
    state = model.initial_state(W)
    for c in random_controls(model, W, 3, seed=seed):
        e.step(model, state, c)
    queue.put(state.position)


def test_spawned_children_step_batches_after_the_parent_did():
    """The fork caveat (engine.core.jit): after a batched step, children that
    step batches are started with "spawn" (or "forkserver"), which runs them
    in a fresh interpreter; their steps are the parent's, bit for bit."""
    model = ragdoll_on_ground()
    state = model.initial_state(W)
    for c in random_controls(model, W, 3, seed=4):
        e.step(model, state, c)  # the parallel loops, in the parent
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    p = ctx.Process(target=_spawned_step, args=(queue, 4))
    p.start()
    try:
        position = queue.get(timeout=600)
    finally:
        p.join(timeout=60)
    assert p.exitcode == 0
    assert np.array_equal(position, state.position)


def test_every_scene_kind_runs_one_compiled_substeps_kernel():
    """The substeps kernel's arguments have the same numba types whatever
    the scene lacks (no contacts, no joints, no tree, Gauss-Seidel joints,
    each integrator) and however many worlds it has: it compiles once, and
    its compile (the largest of the engine's) is paid once."""
    from engine.core import world
    from engine.warmup import scenes

    models = [model for _, model in scenes()]
    b = e.SceneBuilder()
    b.add_body("free", e.Sphere(0.1), mass=1.0, position=(0, 0, 1.0))  # nothing but a body in the air
    models.append(b.build())
    for model in models:
        for num_worlds in (1, W):
            e.step(model, model.initial_state(num_worlds))
    assert len(world.substeps.signatures) == 1, world.substeps.signatures
