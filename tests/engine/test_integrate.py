"""The integration kernels (engine.core.integrate, engine.core.effects) through
their entry points in engine.integrators: a batch of worlds gives bit for bit
what each world gives alone, at any thread count, with every force and
velocity effect in the scene; the free rotation conserves the angular
momentum to rounding and turns a body spun near its intermediate axis over.
"""

from __future__ import annotations

import numpy as np
import pytest

from engine import Box, Capsule, Control, SceneBuilder, Sphere, integrators
from engine.core.jit import SERIAL_BELOW, get_threads, set_threads
from engine.math3d import quat_from_axis_angle, quat_normalize, quat_rotate, quat_to_matrix


def every_effect_scene(integrator):
    """Gravity, gravitation, damping, explicit, stiff and breakable springs
    (one to the world), motors on breakable joints: every effect the
    integration kernels hold."""
    b = SceneBuilder(integrator=integrator)
    b.add_body("a", Sphere(0.1), mass=1.0, position=(0, 0, 1), linear_damping=0.3, angular_damping=0.7)
    b.add_body("b", Box((0.1, 0.2, 0.3)), mass=2.0, position=(1, 0, 1), angular_damping=0.2)
    b.add_body("c", Capsule(0.1, 0.2), mass=0.5, position=(0, 1, 1), linear_damping=1.5)
    b.add_body("d", Box((0.3, 0.1, 0.2)), mass=1.5, position=(1, 1, 0))
    b.add_spring("s1", None, "a", anchor_a=(0, 0, 2), stiffness=50.0, damping=0.3)
    b.add_spring("s2", "a", "b", anchor_a=(0.05, 0, 0), anchor_b=(0.9, 0.1, 1.1), stiffness=1e6, damping=1.0)
    b.add_spring("s3", "b", "c", stiffness=20.0, elastic_limit=0.3)
    b.add_spring("s4", "c", "d", anchor_b=(1, 1, 0.1), stiffness=3e5, damping=2.0, elastic_limit=5.0)
    b.add_body("p", Capsule(0.05, 0.2), mass=1.0, position=(3, 0, 1.0))
    b.add_body("q", Box((0.05, 0.05, 0.2)), mass=0.7, position=(3, 0, 0.5))
    b.add_hinge("h", None, "p", anchor=(3, 0, 1.25), axis=(0, 1, 0), max_torque=5.0)
    b.add_ball("j", "p", "q", anchor=(3, 0, 0.75), max_torque=2.0, break_force=1e3)
    b.enable("gravitation", G=0.5, softening=0.05)
    model = b.build()
    springs = model.effects["springs"]
    assert springs.explicit.size and springs.stiff_colors and springs.breakable
    assert {"damping", "gravitation", "gravity", "motors", "joint_breaking"} <= set(model.effect_names)
    return model


def random_state(model, W, seed):
    rng = np.random.default_rng(seed)
    s = model.initial_state(W)
    dyn = model.dynamic
    n = int(dyn.sum())
    s.position[:, dyn] += rng.normal(0.0, 0.05, (W, n, 3))
    s.velocity[:, dyn] = rng.normal(0.0, 1.0, (W, n, 3))
    s.angular_velocity[:, dyn] = rng.normal(0.0, 3.0, (W, n, 3))
    s.orientation[:, dyn] = quat_normalize(s.orientation[:, dyn] + rng.normal(0.0, 0.3, (W, n, 4)))
    s.spring_broken[...] = rng.random(s.spring_broken.shape) < 0.25
    s.joint_broken[...] = rng.random(s.joint_broken.shape) < 0.25
    control = Control(motor=rng.uniform(-8, 8, (W, model.num_actuators)),
                      force=rng.normal(0, 5, (W, model.num_bodies, 3)),
                      torque=rng.normal(0, 1, (W, model.num_bodies, 3)))
    return s, control


def integrate(model, state, control, substeps=6):
    """The integration stages of ``substeps`` substeps, without the constraints."""
    h = model.settings.substep_dt
    for _ in range(substeps):
        if model.settings.integrator == "symplectic":
            integrators.integrate_velocities(model, state, control, h)
            integrators.velocity_effects(model, state, h)
            integrators.integrate_positions(model, state, h)
        elif model.settings.integrator == "euler":
            integrators.explicit_euler(model, state, control, h)
            integrators.velocity_effects(model, state, h)
        else:
            integrators.runge_kutta4(model, state, control, h)
            integrators.velocity_effects(model, state, h)


KEYS = ("position", "orientation", "velocity", "angular_velocity")


@pytest.mark.parametrize("integrator", ["symplectic", "euler", "rk4"])
def test_worlds_together_are_bit_identical_to_each_alone(integrator):
    """A batch large enough for the parallel loop (``SERIAL_BELOW`` and more
    worlds), at one thread and at all, against each world on its own (the
    serial loop): the same bits, with every effect in the scene."""
    model = every_effect_scene(integrator)
    W = 2 * SERIAL_BELOW + 3
    start, control = random_state(model, W, seed=1)
    threads = get_threads()
    results = []
    try:
        for n in sorted({1, threads}):
            set_threads(n)
            batch = start.copy()
            integrate(model, batch, control)
            results.append(batch)
    finally:
        set_threads(threads)
    for w in range(W):
        alone = start.select([w])
        integrate(model, alone, control.worlds(w, w + 1))
        for batch in results:
            for k in KEYS:
                assert np.array_equal(batch.arrays[k][w], alone.arrays[k][0]), (w, k)
    # It did something, and differently in different worlds.
    moved = results[0]
    assert not np.array_equal(moved.velocity, start.velocity)
    assert not np.array_equal(moved.velocity[0], moved.velocity[1])
    assert np.isfinite(moved.position).all() and np.isfinite(moved.angular_velocity).all()


def test_effects_absent_from_the_scene_are_empty_arrays():
    """A scene without springs, gravitation, damping or motors compiles them
    as empty arrays (no kernel code runs for them); its effect names are
    what the scene declares."""
    b = SceneBuilder()
    b.add_body("a", Sphere(0.1), mass=1.0)
    model = b.build()
    fx = model.effect_arrays
    assert fx.springs.a.size == fx.springs.explicit.size == fx.springs.stiff.size == 0
    assert fx.gravitation.i.size == 0 and fx.motors.parent.size == 0 and fx.damping.linear.size == 0
    assert fx.bodies.gravity.shape == (1, 3)
    assert model.effect_names == ("gravity",)
    assert not fx.bodies.inv_mass.flags.writeable


def free_body(inertia_axes=(0.4, 0.2, 0.1)):
    b = SceneBuilder(gravity=None)
    b.add_body("box", Box(inertia_axes), mass=2.0)
    return b.build()


def world_angular_momentum(model, state):
    """(W, 3) I_w ω of body 0, kg·m²/s."""
    q, w = state.orientation[:, 0], state.angular_velocity[:, 0]
    R = quat_to_matrix(q)
    i_body = np.diag(model.inertia[0])
    return np.einsum("wij,jk,wlk,wl->wi", R, i_body, R, w)


def test_free_rotation_conserves_angular_momentum_to_rounding_and_flips():
    """The splitting's turns are exact rotations about the body axes, each
    the flow of a part of the kinetic energy, so the world angular momentum
    is conserved up to rounding alone, here over 20,000 substeps (83 s) of a
    box spun near its intermediate axis (world 0), which flips over again
    and again (Dzhanibekov), and near its major axis (world 1), which does
    not. The energy stays within O(h²) of its start without drift."""
    model = free_body()
    inertia = model.inertia[0]
    assert inertia[0] < inertia[1] < inertia[2]
    s = model.initial_state(2)
    q0 = quat_from_axis_angle(np.array([1.0, 2.0, 3.0]), 0.7)
    for w, axis in enumerate((1, 2)):
        wb = np.full(3, 0.01)
        wb[axis] = 10.0
        s.orientation[w, 0] = q0
        s.angular_velocity[w, 0] = quat_rotate(q0, wb)
    L0 = world_angular_momentum(model, s)
    h = model.settings.substep_dt
    body_spin = []
    max_dl, energy = np.zeros(2), []
    for n in range(20000):
        integrators.integrate_positions(model, s, h)
        if n % 50 == 0:
            dl = np.linalg.norm(world_angular_momentum(model, s) - L0, axis=-1) / np.linalg.norm(L0, axis=-1)
            max_dl = np.maximum(max_dl, dl)
            wb = np.einsum("wji,wj->wi", quat_to_matrix(s.orientation[:, 0]), s.angular_velocity[:, 0])
            body_spin.append(wb)
            energy.append(0.5 * (inertia * wb * wb).sum(-1))
    # Rounding only: in exact arithmetic every turn keeps L. The state holds ω,
    # so L goes through I Rᵀ ω and back each substep, about one rounding
    # (1.1e-16) a substep; 1e-15 a substep allows ten.
    assert np.all(max_dl < 1e-15 * 20000), max_dl
    body_spin = np.array(body_spin)  # (samples, 2, 3)
    flips = int(np.sum(np.diff(np.sign(body_spin[:, 0, 1])) != 0))
    # Growth rate ω √((I2-I1)(I3-I2)/(I1 I3)) = 6 /s: a flip every few seconds.
    assert flips >= 10, flips
    assert np.all(body_spin[:, 1, 2] > 0.99 * 10.0)  # the major-axis spin stays put
    energy = np.array(energy)
    # The splitting's energy error is O((ω h)²) with (ω h)² = (10/240)² ≈ 2e-3
    # times a small factor, and bounded: 1e-4 relative; no drift: the second
    # half of the run is no further off than the first (10 % allows for where
    # the samples fall on the oscillation).
    drift = np.abs(energy / energy[0] - 1)
    half = len(drift) // 2
    assert drift.max() < 1e-4, drift.max()
    assert np.all(drift[half:].max(axis=0) < 1.1 * drift[:half].max(axis=0))
