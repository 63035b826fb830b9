"""The model is read-only while it steps: one model stepping two different
states in turn gives each the bits it gets from a model of its own (as
MuJoCo's ``mjModel`` with one ``mjData`` per rollout)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import engine as e
from benchmarks import scenarios, scenes
from engine.humanoid import add_humanoid

STEPS = 40


def _ragdoll(**settings):
    b = e.SceneBuilder(**settings)
    b.add_ground()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b)
    return b.build()


def _breakable_chain():
    """Three spheres hanging from the world on ball joints that break beyond 30 N."""
    b = e.SceneBuilder()
    for i in range(3):
        b.add_body(f"s{i}", e.Sphere(0.05), mass=2.0, position=(0.2 * (i + 1), 0.0, 1.0))
    b.add_ball("pin", None, "s0", anchor=(0.1, 0.0, 1.0), break_force=30.0)
    b.add_ball("j1", "s0", "s1", anchor=(0.3, 0.0, 1.0), break_force=30.0)
    b.add_ball("j2", "s1", "s2", anchor=(0.5, 0.0, 1.0), break_force=30.0)
    return b.build()


#: name -> a factory of a fresh model: the compiled substeps with articulated
#: contacts, RK4, the loop rows' stage-by-stage solve, restitution, breaking.
MODELS = {
    "ragdoll": _ragdoll,
    "ragdoll_rk4": lambda: _ragdoll(integrator="rk4"),
    "chain_loop": lambda: scenes.chain_loop().model,
    "bouncing_ball": lambda: scenarios.bouncing_ball().build(),
    "breakable_chain": _breakable_chain,
}


def _two_states(model):
    """Two states of different batch sizes and poses, and their controls."""
    a, b = model.initial_state(1), model.initial_state(3)
    b.position[..., 2] += np.array([0.3, 0.6, 0.9])[:, None]
    b.velocity[..., 0] += 0.5
    rng = np.random.default_rng(3)
    A = model.num_actuators
    top = np.array([act.max_torque for act in model.actuators]) if A else np.zeros(0)

    def controls(worlds):
        return [e.Control(motor=rng.uniform(-1, 1, (worlds, A)) * top) if A else None for _ in range(STEPS)]

    return (a, controls(1)), (b, controls(3))


@pytest.mark.parametrize("name", list(MODELS))
def test_two_states_stepped_in_turn_on_one_model_equal_each_on_its_own(name):
    shared = MODELS[name]()
    (a, ua), (b, ub) = _two_states(shared)
    alone_a, alone_b = a.copy(), b.copy()
    events_a, events_b = [], []
    for k in range(STEPS):
        e.step(shared, a, ua[k])
        events_a += a.events
        e.step(shared, b, ub[k])
        events_b += b.events
    own_a, own_b = MODELS[name](), MODELS[name]()
    alone_events_a, alone_events_b = [], []
    for k in range(STEPS):
        e.step(own_a, alone_a, ua[k])
        alone_events_a += alone_a.events
    for k in range(STEPS):
        e.step(own_b, alone_b, ub[k])
        alone_events_b += alone_b.events
    assert a.equal(alone_a)
    assert b.equal(alone_b)
    assert events_a == alone_events_a and events_b == alone_events_b
    # The two states did step apart (the check is not of two copies of one run).
    assert not np.array_equal(a.position[0], b.position[0])
