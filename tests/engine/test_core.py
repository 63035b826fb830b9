"""Acceptance tests of the engine core: forces, integrators, springs, gravitation,
free rotation, batching, resets, determinism, control validation and the
non-finite check.

Every physics test compares against a closed form or a conservation law; the
tolerance and the reason for it are stated next to each assertion. Defaults:
dt = 1/60 s, 4 substeps, so the substep is h = 1/240 s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import (
    Box,
    Capsule,
    Control,
    Event,
    SceneBuilder,
    Settings,
    SimulationError,
    Sphere,
    State,
    apply_impulse,
    simulate,
    step,
)
from engine import diagnostics as D
from engine.effects.gravity import Gravity
from engine.math3d import (
    inverse_or_nan,
    quat_from_axis_angle,
    quat_normalize,
    quat_rotate_inv,
    quat_to_matrix,
)

G0 = 9.80665  # m/s², standard gravity


# ----------------------------------------------------------------- scene helpers
def springs_scene():
    """Three bodies of three shapes, gravity, gravitation between them, a compliant
    spring to the world, a stiff (implicit) spring and a breakable spring."""
    b = SceneBuilder()
    b.add_body("a", Sphere(0.1), mass=1.0, position=(0, 0, 1))
    b.add_body("b", Box((0.1, 0.2, 0.3)), mass=2.0, position=(1, 0, 1))
    b.add_body("c", Capsule(0.1, 0.2), mass=0.5, position=(0, 1, 1))
    b.add_spring("s1", None, "a", anchor_a=(0, 0, 2), stiffness=50.0, damping=0.3)
    b.add_spring("s2", "a", "b", anchor_b=(0.9, 0.1, 1.1), stiffness=1e6, damping=1.0)
    b.add_spring("s3", "b", "c", stiffness=20.0, elastic_limit=0.3)
    b.enable("gravitation", G=0.5)
    model = b.build()
    springs = model.effects["springs"]
    # Both spring paths are exercised: s1, s3 explicit, s2 implicit.
    assert springs.explicit.size == 2 and len(springs.stiff_colors) == 1
    return model


def joint_scene():
    """A chain hanging from the world: motorised hinge, limited damped hinge, limited ball."""
    b = SceneBuilder()
    b.add_body("p", Capsule(0.05, 0.2), mass=1.0, position=(0, 0, 1.0))
    b.add_body("q", Capsule(0.05, 0.2), mass=1.0, position=(0, 0, 0.5))
    b.add_body("r", Box((0.05, 0.05, 0.2)), mass=0.7, position=(0, 0, 0.0))
    b.add_hinge("h0", None, "p", anchor=(0, 0, 1.25), axis=(0, 1, 0), max_torque=5.0)
    b.add_hinge("h1", "p", "q", anchor=(0, 0, 0.75), axis=(1, 0, 0), limits=(-1.0, 1.0), damping=0.1)
    b.add_ball("b1", "q", "r", anchor=(0, 0, 0.2), swing_limits=(0.5, 0.8), twist_limits=(-0.3, 0.3),
               max_torque=2.0)
    return b.build()


def randomized(model, W, seed, pos=0.05, vel=1.0, spin=2.0):
    """W worlds of the model's scene with perturbed poses and random velocities."""
    rng = np.random.default_rng(seed)
    s = model.initial_state(W)
    dyn = model.dynamic
    n = int(dyn.sum())
    s.position[:, dyn] += rng.normal(0.0, pos, (W, n, 3))
    s.velocity[:, dyn] = rng.normal(0.0, vel, (W, n, 3))
    s.angular_velocity[:, dyn] = rng.normal(0.0, spin, (W, n, 3))
    s.orientation[:, dyn] = quat_normalize(s.orientation[:, dyn] + rng.normal(0.0, 0.1, (W, n, 4)))
    return s


def assert_states_identical(a: State, b: State):
    assert a.arrays.keys() == b.arrays.keys()
    for k, v in a.arrays.items():
        assert np.array_equal(v, b.arrays[k]), f"state.{k} differs"
    assert a.equal(b)


# ---------------------------------------------------------------- thesis example
def test_thesis_weight_of_2_5_kg():
    # The thesis's worked example: F = m g = 2.5 kg × 9.80665 m/s² = 24.516625 N.
    gravity = Gravity((0.0, 0.0, -G0), np.array([True]))
    # 1e-12 relative: one float multiplication, a few ulps at most.
    assert gravity.weight(2.5) == pytest.approx([0.0, 0.0, -24.516625], rel=1e-12, abs=1e-12)

    # The same force measured from the engine: F = m Δv / dt over one step of a free body.
    b = SceneBuilder()
    b.add_body("ball", Sphere(0.1), mass=2.5, position=(0, 0, 10))
    model = b.build()
    assert model.effects["gravity"].weight(2.5)[2] == pytest.approx(-24.516625, rel=1e-12)
    s = model.initial_state(1)
    step(model, s)
    force = 2.5 * s.velocity[0, 0] / model.settings.dt
    # 1e-12 relative: Δv is a sum of 4 substep increments g h, exact up to rounding.
    assert force == pytest.approx([0.0, 0.0, -24.516625], rel=1e-12, abs=1e-12)


# --------------------------------------------------- free fall and projectiles
# Launch velocities of the batch: free fall from rest, straight up, and two projectiles.
LAUNCH = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 7.0], [3.0, 0.0, 4.0], [-2.0, 5.0, 1.5]])


@pytest.mark.parametrize("integrator, sign", [("symplectic", +1.0), ("euler", -1.0), ("rk4", 0.0)])
def test_free_fall_and_projectile_match_closed_form(integrator, sign):
    """x(t) = x0 + v0 t + g t²/2 exactly; the schemes' discrete solutions are
    semi-implicit Euler: x0 + v0 t + g t²/2 + g h t/2 (it uses the new velocity),
    explicit Euler:      x0 + v0 t + g t²/2 - g h t/2 (it uses the old one),
    RK4:                 exact (a quadratic is within its order),
    with g the gravity vector and h = dt / substeps."""
    b = SceneBuilder(integrator=integrator)
    b.add_body("ball", Sphere(0.1), mass=2.5, position=(0, 0, 100))
    model = b.build()
    W = len(LAUNCH)
    s = model.initial_state(W)
    s.velocity[:, 0] = LAUNCH
    x0 = s.position[:, 0].copy()
    g = np.array([0.0, 0.0, -G0])
    h = model.settings.substep_dt
    n = 90  # 1.5 s
    simulate(model, s, n)
    t = n * model.settings.dt
    exact = x0 + LAUNCH * t + 0.5 * g * t * t
    error = s.position[:, 0] - exact
    predicted = sign * g * h * t / 2  # |g h t / 2| = 0.0306 m here
    # 1e-9 m: the predicted errors are exact identities of the schemes for constant
    # acceleration; what remains is rounding over 360 substeps (~1e-13 m).
    np.testing.assert_allclose(error, np.broadcast_to(predicted, error.shape), rtol=0, atol=1e-9)
    # Horizontal motion has no acceleration, so every scheme is exact there.
    np.testing.assert_allclose(error[:, :2], 0.0, rtol=0, atol=1e-9)
    # Velocity v0 + g t is exact for all three (constant acceleration), to rounding.
    np.testing.assert_allclose(s.velocity[:, 0], LAUNCH + g * t, rtol=0, atol=1e-9)
    if sign != 0.0:
        # The bound is not vacuous: the scheme's error is far above the tolerance.
        assert abs(error[0, 2]) > 0.03


# ------------------------------------------------------------------- springs
def oscillator(k, m, c=0.0, limit=math.inf, x0=0.1, v0=0.0, **settings):
    """A mass on a spring to the world along x, rest length 1 m, no gravity."""
    b = SceneBuilder(gravity=None, **settings)
    b.add_body("mass", Sphere(0.05), mass=m, position=(1.0 + x0, 0, 0), velocity=(v0, 0, 0))
    b.add_spring("s", None, "mass", anchor_a=(0, 0, 0), stiffness=k, damping=c, rest_length=1.0,
                 elastic_limit=limit)
    return b.build()


def record_x(model, steps, W=1):
    s = model.initial_state(W)
    i = model.body_index("mass")
    xs = [s.position[:, i, 0] - 1.0]
    for _ in range(steps):
        step(model, s)
        xs.append(s.position[:, i, 0] - 1.0)
    return s, np.array(xs)  # (steps + 1, W)


def upward_crossings(x, dt):
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    return (i + (-x[i]) / (x[i + 1] - x[i])) * dt


def _substep_map_angle(integrator, omega, h):
    """The phase θ that one substep of ``integrator`` turns the undamped
    oscillator ẍ = -ω² x by: the argument of the eigenvalues of its linear
    map (x, v) → (x', v'). The discrete period is 2π h / θ."""
    if integrator == "symplectic":  # v' = v - h ω² x, x' = x + h v'
        m = np.array([[1 - (h * omega) ** 2, h], [-h * omega**2, 1.0]])
    elif integrator == "euler":  # x' = x + h v, v' = v - h ω² x
        m = np.array([[1.0, h], [-h * omega**2, 1.0]])
    else:  # RK4 of a linear system: the Taylor polynomial of exp(h A) to 4th order
        a = np.array([[0.0, 1.0], [-omega**2, 0.0]]) * h
        m = np.eye(2) + a + a @ a / 2 + a @ a @ a / 6 + a @ a @ a @ a / 24
    return abs(np.angle(np.linalg.eigvals(m)[0]))


@pytest.mark.parametrize("integrator", ["symplectic", "euler", "rk4"])
def test_spring_period_of_each_integrator(integrator):
    """The period of a mass on a spring against 2π sqrt(m/k), and against
    the period each scheme's own map predicts (2π h / θ, θ the phase of one
    substep: RK4's is the exact period to 3e-8; semi-implicit Euler's,
    (2/h) asin(ω h / 2), is shorter by (ω h)²/24 = 7.2e-5 and explicit
    Euler's longer by 5.8e-4 relative here)."""
    k, m = 100.0, 1.0  # ω = 10 rad/s, T = 0.6283 s
    model = oscillator(k, m, integrator=integrator)
    assert model.effects["springs"].explicit.size == 1  # the explicit force path
    dt, h = model.settings.dt, model.settings.substep_dt
    _, x = record_x(model, 600)  # 10 s, about 16 periods
    x = x[:, 0]
    period = np.diff(upward_crossings(x, dt)).mean()
    exact = 2 * math.pi * math.sqrt(m / k)
    # Acceptance: within 0.5 % at the default dt.
    assert abs(period / exact - 1) < 5e-3
    # The scheme's own period: the crossing interpolation is good to ~1e-6
    # (explicit Euler's growing amplitude moves no zero of x), so 1e-5
    # separates the scheme's error from a wrong one.
    predicted = 2 * math.pi * h / _substep_map_angle(integrator, math.sqrt(k / m), h)
    assert abs(period / predicted - 1) < 1e-5


def test_damped_spring_decays_at_analytic_rate():
    k, m, c = 100.0, 1.0, 0.5
    gamma = c / (2 * m)  # amplitude ∝ exp(-γ t), γ = 0.25 /s
    model = oscillator(k, m, c=c)
    dt, h = model.settings.dt, model.settings.substep_dt
    x = record_x(model, 600)[1][:, 0]
    # Peaks of x, refined by a parabola through the three samples around each.
    i = np.flatnonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])) + 1
    y0, y1, y2 = x[i - 1], x[i], x[i + 1]
    d = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    t_peak = (i + d) * dt
    a_peak = y1 - 0.25 * (y0 - y2) * d
    assert len(a_peak) >= 10
    rate = -np.polyfit(t_peak, np.log(a_peak), 1)[0]
    # 1 %: semi-implicit Euler's map has determinant 1 - c h/m per substep, so its
    # envelope decays at -ln(1 - 2γh)/(2h) ≈ γ (1 + γ h), 0.1 % above γ; peak
    # interpolation adds well under 0.1 %.
    assert rate == pytest.approx(gamma, rel=1e-2)
    assert rate == pytest.approx(-math.log(1 - 2 * gamma * h) / (2 * h), rel=2e-3)
    # The damped period 2π/√(ω² - γ²) within 0.5 %, as the undamped one.
    period = np.diff(t_peak).mean()
    assert period == pytest.approx(2 * math.pi / math.sqrt(k / m - gamma**2), rel=5e-3)


def test_spring_breaks_once_past_elastic_limit_then_flies_free():
    k, m = 100.0, 1.0
    omega, amplitude, limit = 10.0, 0.2, 0.15  # released at rest length with v0 = A ω
    model = oscillator(k, m, limit=limit, x0=0.0, v0=amplitude * omega)
    dt = model.settings.dt
    W = 2
    s = model.initial_state(W)
    s.velocity[1] = 0.0  # world 1 never moves: its spring must never break
    events = []
    for _ in range(60):
        step(model, s)
        events += [(e, s.step[e.world], model.time(s)[e.world]) for e in s.events]
        if s.spring_broken[0, 0]:
            break
    broke_at = int(s.step[0])
    assert len(events) == 1
    event, step_count, time = events[0]
    assert event == Event("spring_broken", "s", 0, step_count, time)
    # The event reports the step that broke it: the state's step count and time after it.
    assert event.step == broke_at and event.time == pytest.approx(broke_at * dt, rel=1e-12)
    # Analytic: extension A sin(ω t) passes the limit at t* = asin(limit/A)/ω = 0.0848 s,
    # which lies inside step 6 (0.0833, 0.1]; the scheme's phase error (~1e-4) cannot
    # move it out of that step.
    t_star = math.asin(limit / amplitude) / omega
    assert (broke_at - 1) * dt < t_star <= broke_at * dt
    assert s.spring_broken.tolist() == [[True], [False]]

    # After breaking: no force, so the velocity stays bit-for-bit constant and the
    # body moves in a straight line; no further event; the flag stays set.
    v_free = s.velocity[0, 0].copy()
    x_start = s.position[0, 0].copy()
    for n in range(1, 31):
        step(model, s)
        assert s.events == []
        assert np.array_equal(s.velocity[0, 0], v_free)
    # 1e-12 m: 120 substeps of x += h v with a constant v, rounding only.
    np.testing.assert_allclose(s.position[0, 0], x_start + v_free * 30 * dt, rtol=0, atol=1e-12)
    assert s.spring_broken.tolist() == [[True], [False]]
    assert np.abs(s.position[0, 0, 0] - 1.0) > limit  # it did fly away
    assert np.array_equal(s.position[1], model.initial_state(1).position[0])


def test_stiff_spring_is_stable_and_does_not_gain_energy():
    k, m = 1e7, 1.0
    model = oscillator(k, m, x0=0.1)
    h = model.settings.substep_dt
    assert k * h * h / m > 100  # k h²/m = 174: explicit integration would explode
    springs = model.effects["springs"]
    assert springs.explicit.size == 0 and len(springs.stiff_colors) == 1  # the implicit path
    W = 3
    s = model.initial_state(W)
    s.velocity[1, 0] = (0.0, 0.5, 0.3)  # swinging sideways as well
    s.velocity[2, 0] = (30.0, 0.0, 0.0)
    energy = [D.total_energy(model, s)]
    for _ in range(300):
        step(model, s)
        assert np.all(np.isfinite(s.position)) and np.all(np.isfinite(s.velocity))
        energy.append(D.total_energy(model, s))
    energy = np.array(energy)
    # Backward Euler on a spring is contractive in the energy norm: the energy never
    # rises from one step to the next (1e-9 relative allows rounding only).
    assert np.all(np.diff(energy, axis=0) <= 1e-9 * energy[0])
    assert np.all(energy[-1] < energy[0])


# ------------------------------------------------------------------ gravitation
def test_two_body_circular_orbit_has_keplers_period():
    G, m1, m2, r = 1.0, 1.0, 3.0, 1.0
    omega = math.sqrt(G * (m1 + m2) / r**3)
    period = 2 * math.pi / omega  # Kepler's third law: 3.14 s
    b = SceneBuilder(gravity=None)
    # Circular orbit about the centre of mass at the origin.
    r1, r2 = r * m2 / (m1 + m2), r * m1 / (m1 + m2)
    b.add_body("a", Sphere(0.05), mass=m1, position=(-r1, 0, 0), velocity=(0, -omega * r1, 0))
    b.add_body("b", Sphere(0.05), mass=m2, position=(r2, 0, 0), velocity=(0, omega * r2, 0))
    b.enable("gravitation", G=G)
    model = b.build()
    assert "gravitation" in model.effect_names and "gravity" not in model.effect_names
    s = model.initial_state(1)
    n = int(2.2 * period / model.settings.dt)
    angle, dist = [0.0], [r]
    e0 = D.total_energy(model, s)[0]
    for _ in range(n):
        step(model, s)
        d = s.position[0, 1] - s.position[0, 0]
        angle.append(math.atan2(d[1], d[0]))
        dist.append(math.hypot(d[0], d[1]))
    angle = np.unwrap(angle)
    t = np.arange(n + 1) * model.settings.dt
    measured = np.interp(2 * math.pi, angle, t)
    measured2 = np.interp(4 * math.pi, angle, t) / 2
    # 1 % (acceptance); the symplectic scheme's phase error is O((ω h)²) ~ 1e-4 here.
    assert measured == pytest.approx(period, rel=1e-2)
    assert measured2 == pytest.approx(period, rel=1e-2)
    # The orbit stays circular (radius within 1 %) and energy is conserved to O(h²).
    assert np.max(np.abs(np.array(dist) / r - 1)) < 1e-2
    assert D.total_energy(model, s)[0] == pytest.approx(e0, rel=1e-3)
    # Momentum: gravitation is an internal force, zero total momentum stays zero (rounding).
    np.testing.assert_allclose(D.linear_momentum(model, s), 0.0, atol=1e-12)


# --------------------------------------------------------------- free rotation
def test_torque_free_box_intermediate_axis_flips_major_axis_does_not():
    """Dzhanibekov's effect: a box with principal moments I1 < I2 < I3 spun near its
    intermediate axis keeps flipping over; spun near the major (or minor) axis it
    stays put. Kinetic energy and angular momentum are conserved throughout."""
    b = SceneBuilder(gravity=None)
    b.add_body("box", Box((0.4, 0.2, 0.1)), mass=2.0)
    model = b.build()
    inertia = model.inertia[0]
    assert inertia[0] < inertia[1] < inertia[2]  # x minor, y intermediate, z major
    s = model.initial_state(3)
    for w, axis in enumerate((1, 2, 0)):
        wb = np.full(3, 0.01)
        wb[axis] = 10.0
        # A tilted start, so the body frame differs from the world frame.
        q = quat_from_axis_angle(np.array([1.0, 2.0, 3.0]), 0.7)
        s.orientation[w, 0] = q
        s.angular_velocity[w, 0] = quat_to_matrix(q) @ wb  # world-frame ω
    k0 = D.kinetic_energy(model, s)
    l0 = D.angular_momentum(model, s)
    n = int(round(10.0 / model.settings.dt))
    wb_hist = []
    max_dk = np.zeros(3)
    max_dl = np.zeros(3)
    for _ in range(n):
        step(model, s)
        wb_hist.append(quat_rotate_inv(s.orientation[:, 0], s.angular_velocity[:, 0]))
        max_dk = np.maximum(max_dk, np.abs(D.kinetic_energy(model, s) / k0 - 1))
        dl = np.linalg.norm(D.angular_momentum(model, s) - l0, axis=-1) / np.linalg.norm(l0, axis=-1)
        max_dl = np.maximum(max_dl, dl)
    wb_hist = np.array(wb_hist)  # (steps, worlds, 3)
    flips = [int(np.sum(np.diff(np.sign(wb_hist[:, w, axis])) != 0)) for w, axis in enumerate((1, 2, 0))]
    # Growth rate ω √((I2-I1)(I3-I2)/(I1 I3)) = 6 /s here: the first flip comes after
    # about 3 s, and it keeps flipping back and forth.
    assert flips[0] >= 2, f"spin about the intermediate axis flipped {flips[0]} times in 10 s"
    assert flips[1] == 0 and flips[2] == 0, "spin about the major/minor axis flipped"
    # The major-axis spin stays within a few degrees of its axis.
    assert np.all(wb_hist[:, 1, 2] > 0.99 * 10.0)
    # 1e-3 relative over 10 s (acceptance): the splitting conserves |L| exactly and
    # energy to O(h²) without drift.
    assert np.all(max_dk < 1e-3), max_dk
    assert np.all(max_dl < 1e-3), max_dl


# ------------------------------------------------------------------ diagnostics
def test_diagnostics_on_a_spinning_moving_box():
    b = SceneBuilder()
    b.add_body("box", Box((0.3, 0.2, 0.1)), mass=3.0, position=(1.0, 2.0, 3.0))
    b.add_body("ball", Sphere(0.5), mass=2.0, position=(-1.0, 0.0, 0.0))
    model = b.build()
    s = model.initial_state(2)
    q = quat_from_axis_angle(np.array([0.3, -1.0, 0.5]), 1.1)
    R = quat_to_matrix(q)
    s.orientation[:, 0] = q
    omega = np.array([1.5, -2.0, 0.7])  # world frame
    s.angular_velocity[:, 0] = omega
    s.velocity[:, 0] = (0.5, 0.0, -1.0)
    s.velocity[1, 1] = (0.0, 2.0, 0.0)
    hx, hy, hz = 0.3, 0.2, 0.1
    i_body = 3.0 / 3.0 * np.array([hy**2 + hz**2, hx**2 + hz**2, hx**2 + hy**2])
    np.testing.assert_allclose(model.inertia[0], i_body, rtol=1e-15)
    i_world = R @ np.diag(i_body) @ R.T
    # ½ ωᵀ I ω with I = R I_b Rᵀ, plus ½ m v²; 1e-12 relative (rounding).
    ke_box = 0.5 * omega @ i_world @ omega + 0.5 * 3.0 * 1.25
    ke = D.kinetic_energy(model, s)
    assert ke[0] == pytest.approx(ke_box, rel=1e-12)
    assert ke[1] == pytest.approx(ke_box + 0.5 * 2.0 * 4.0, rel=1e-12)
    # Angular momentum about the origin: x × m v + I ω.
    L = np.cross([1.0, 2.0, 3.0], 3.0 * np.array([0.5, 0.0, -1.0])) + i_world @ omega
    np.testing.assert_allclose(D.angular_momentum(model, s)[0], L, rtol=1e-12, atol=1e-12)
    L1 = L + np.cross([-1.0, 0.0, 0.0], [0.0, 4.0, 0.0])
    np.testing.assert_allclose(D.angular_momentum(model, s)[1], L1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(D.linear_momentum(model, s)[1], [1.5, 4.0, -3.0], rtol=1e-12)
    np.testing.assert_allclose(D.center_of_mass(model, s)[0], [0.2, 1.2, 1.8], rtol=1e-12)
    # Gravity's potential: Σ m g z = 9.80665 × 3 × 3.
    assert D.potential_energy(model, s)[0] == pytest.approx(G0 * 9.0, rel=1e-12)
    assert D.total_energy(model, s)[0] == pytest.approx(ke_box + G0 * 9.0, rel=1e-12)


# ------------------------------------------------------------------- batching
def step_batch_and_singles(model, state, steps, controls=None):
    """Step ``state`` as one batch and each of its worlds alone; return both."""
    W = state.num_worlds
    singles = [state.select([w]) for w in range(W)]
    batch = state.copy()
    batch_events, single_events = [], []
    for n in range(steps):
        c = None if controls is None else controls[n]
        step(model, batch, c)
        batch_events += [(e.kind, e.name, e.world, e.step) for e in batch.events]
        for w in range(W):
            cw = None if c is None else Control(
                **{k: None if getattr(c, k) is None else getattr(c, k)[w:w + 1]
                   for k in ("motor", "force", "torque")})
            step(model, singles[w], cw)
            single_events += [(e.kind, e.name, w, e.step) for e in singles[w].events]
    return batch, State.concatenate(singles), sorted(batch_events), sorted(single_events)


def test_batched_worlds_equal_single_worlds_springs_gravitation():
    model = springs_scene()
    W = 5
    s = randomized(model, W, seed=1)
    batch, singles, be, se = step_batch_and_singles(model, s, 60)
    assert_states_identical(batch, singles)
    assert be == se
    # The scene did something: the breakable spring s3 broke (events compared above)
    # and every world moved.
    assert batch.spring_broken[:, 2].all() and len(be) == W
    assert not np.array_equal(batch.position, s.position)
    assert batch.nonfinite_worlds().size == 0


def test_batched_worlds_equal_single_worlds_joints():
    model = joint_scene()
    assert model.num_joints == 3 and model.num_actuators >= 1
    W = 3
    s = randomized(model, W, seed=2, pos=0.0)
    rng = np.random.default_rng(3)
    steps = 25
    controls = [Control(motor=rng.uniform(-3, 3, (W, model.num_actuators))) for _ in range(steps)]
    batch, singles, be, se = step_batch_and_singles(model, s, steps, controls)
    assert_states_identical(batch, singles)
    assert be == se
    assert batch.nonfinite_worlds().size == 0


def test_step_works_for_1_to_1024_worlds_and_agrees():
    """No Python loop over worlds in the hot path means any batch size works and a
    world's result does not depend on the batch it is stepped in."""
    model = springs_scene()
    big = randomized(model, 1024, seed=4)
    ref = big.copy()
    simulate(model, ref, 5)
    assert ref.nonfinite_worlds().size == 0
    for W in (1, 2, 3, 17, 128):
        sub = big.select(np.arange(W) * 7 % 1024)
        simulate(model, sub, 5)
        assert_states_identical(sub, ref.select(np.arange(W) * 7 % 1024))


# ------------------------------------------------------- reset, select, assign
def test_reset_worlds_resets_only_those_worlds():
    model = springs_scene()
    s = randomized(model, 5, seed=5)
    simulate(model, s, 3)
    before = s.copy()
    model.reset_worlds(s, [1, 3])
    init = model.initial_state(1)
    for w in range(5):
        for k, v in s.arrays.items():
            expected = init.arrays[k][0] if w in (1, 3) else before.arrays[k][w]
            assert np.array_equal(v[w], expected), (w, k)
    # Reset to a given source state, one per selected world.
    src = randomized(model, 2, seed=6)
    model.reset_worlds(s, [4, 0], source=src)
    assert s.select([4, 0]).equal(src)
    assert s.select([1, 2, 3]).equal(
        State.concatenate([init, before.select([2]), init]))


def test_select_assign_concatenate_round_trip():
    model = springs_scene()
    s = randomized(model, 6, seed=7)
    simulate(model, s, 2)
    original = s.copy()
    # select then assign back is the identity.
    part = s.select([4, 1])
    s.assign([4, 1], part)
    assert s.equal(original)
    # select is a copy, not a view.
    part.position[...] = 0.0
    assert s.equal(original)
    # Concatenating every world selected alone gives the state back.
    assert State.concatenate([s.select([w]) for w in range(6)]).equal(original)
    # Boolean masks and slices select the same worlds as indices.
    mask = np.array([True, False, True, False, False, True])
    assert s.select(mask).equal(s.select([0, 2, 5]))
    assert s.select(slice(1, 4)).equal(s.select([1, 2, 3]))
    # Swapping two worlds by assign, twice, is the identity.
    s.assign([0, 5], original.select([5, 0]))
    assert np.array_equal(s.position[0], original.position[5])
    assert not s.equal(original)
    s.assign([0, 5], original.select([0, 5]))
    assert s.equal(original)


# ---------------------------------------------------------------- determinism
def test_replay_is_bit_identical():
    model = springs_scene()
    W = 4
    rng = np.random.default_rng(8)
    start = randomized(model, W, seed=9)
    controls = [Control(force=rng.normal(0, 5, (W, model.num_bodies, 3)),
                        torque=rng.normal(0, 1, (W, model.num_bodies, 3))) for _ in range(40)]
    runs = []
    for _ in range(2):
        s = start.copy()
        for c in controls:
            step(model, s, c)
        runs.append(s)
    assert_states_identical(runs[0], runs[1])
    assert not runs[0].equal(start)

    jmodel = joint_scene()
    jstart = randomized(jmodel, 2, seed=10, pos=0.0)
    motors = [Control(motor=rng.uniform(-5, 5, (2, jmodel.num_actuators))) for _ in range(10)]
    jruns = []
    for _ in range(2):
        s = jstart.copy()
        for c in motors:
            step(jmodel, s, c)
        jruns.append(s)
    assert_states_identical(jruns[0], jruns[1])


# --------------------------------------------------------- control validation
@pytest.mark.parametrize("bad", [
    "motor_shape", "motor_flat", "motor_nan", "motor_inf", "force_shape", "force_nan",
    "force_inf", "torque_ninf", "not_a_control",
])
def test_invalid_control_raises_and_leaves_state_unchanged(bad):
    model = joint_scene()
    W, A, N = 2, model.num_actuators, model.num_bodies
    s = randomized(model, W, seed=11, pos=0.0)
    step(model, s, Control.zeros(model, W))  # something in the warm-start caches
    motor = np.zeros((W, A))
    force = np.zeros((W, N, 3))
    control = {
        "motor_shape": lambda: Control(motor=np.zeros((W, A + 1))),
        "motor_flat": lambda: Control(motor=np.zeros(A)),
        "motor_nan": lambda: Control(motor=np.where(np.arange(A) == 0, np.nan, motor)),
        "motor_inf": lambda: Control(motor=np.full((W, A), np.inf)),
        "force_shape": lambda: Control(force=np.zeros((W, N + 1, 3))),
        "force_nan": lambda: Control(force=np.where(np.arange(3) == 2, np.nan, force)),
        "force_inf": lambda: Control(motor=motor, force=np.where(np.arange(3) == 0, np.inf, force)),
        "torque_ninf": lambda: Control(torque=np.full((W, N, 3), -np.inf)),
        "not_a_control": lambda: np.zeros((W, A)),
    }[bad]()
    before = s.copy()
    with pytest.raises(ValueError):
        step(model, s, control)
    assert_states_identical(s, before)
    assert s.events == before.events


# --------------------------------------------------------- non-finite detection
def two_balls(**settings):
    b = SceneBuilder(**settings)
    b.add_body("a", Sphere(0.1), mass=1.0, position=(0, 0, 1))
    b.add_body("b", Sphere(0.1), mass=1.0, position=(1, 0, 1))
    b.add_spring("s", None, "a", anchor_a=(0, 0, 2), stiffness=10.0)
    return b.build()


def test_nonfinite_state_names_world_body_and_step():
    model = two_balls()
    s = model.initial_state(4)
    simulate(model, s, 2)
    s.velocity[2, 1, 0] = np.nan
    with pytest.raises(SimulationError) as info:
        step(model, s)
    err = info.value
    assert err.worlds == (2,)
    assert err.bodies == ("b",)
    assert err.step == 3
    message = str(err)
    assert "world 2" in message and "'b'" in message and "step 3" in message


def test_nonfinite_flagged_without_check_and_isolated_to_its_world():
    model = two_balls(check_finite=False)
    clean = model.initial_state(4)
    clean.velocity[:, 0] = np.arange(4)[:, None] * 0.1
    s = clean.copy()
    s.velocity[2, 1, 0] = np.nan
    assert s.nonfinite_worlds().tolist() == [2]
    simulate(model, s, 5)  # no exception
    simulate(model, clean, 5)
    assert s.nonfinite_worlds().tolist() == [2]
    # The other worlds are untouched by the NaN: bit-for-bit the clean run.
    keep = [0, 1, 3]
    assert_states_identical(s.select(keep), clean.select(keep))
    assert not np.isfinite(s.position[2, 1]).all() and np.isfinite(s.position[2, 0]).all()
    s.position[1, 0, 2] = np.inf
    assert s.nonfinite_worlds().tolist() == [1, 2]


def test_huge_but_finite_state_is_not_reported_as_nonfinite():
    # Summing a world's entries would overflow to inf; the check must not.
    b = SceneBuilder(gravity=None)
    b.add_body("a", Sphere(0.1), mass=1.0)
    b.add_body("b", Sphere(0.1), mass=1.0, position=(1, 0, 0))
    model = b.build()
    state = model.initial_state(3)
    state.position[1, :, 0] = 1e308
    assert state.nonfinite_worlds().tolist() == []
    state.velocity[2, 0, 1] = np.nan
    assert state.nonfinite_worlds().tolist() == [2]


def test_inverse_or_nan_marks_only_the_singular_matrices():
    A = np.stack([np.diag([2.0, 4.0, 5.0]), np.zeros((3, 3)), np.ones((3, 3))])
    inv = inverse_or_nan(A)
    np.testing.assert_allclose(inv[0], np.diag([0.5, 0.25, 0.2]))
    assert np.isnan(inv[1:]).all()


def test_a_diverging_ragdoll_is_reported_not_a_linalg_error():
    """The humanoid with soft joints (``engine.SOFT_JOINTS``) under random
    torques at dt 1/30 with 1 substep and no relax solve diverges (bodies
    1e17 m apart by step 40; the defaults' rigid joints stay finite); a joint pivot then
    turns singular in floating point. The step reports that world as
    non-finite (SimulationError naming world and step), as for any other
    divergence, instead of stopping with numpy's LinAlgError; without the
    check the other world of the batch steps on unharmed."""
    from benchmarks import accuracy
    from engine import SOFT_JOINTS

    model = accuracy._ragdoll_model(Settings(dt=1 / 30, substeps=1, relax_iterations=0, **SOFT_JOINTS))
    torques = accuracy._ragdoll_torques(model, 3.0)
    per = round(accuracy.SAMPLE_DT * 30)
    s = model.initial_state(2)
    with pytest.raises(SimulationError) as info:
        for k in range(90):
            motor = np.stack([torques[k // per], np.zeros(model.num_actuators)])
            step(model, s, Control(motor=motor))
    assert info.value.worlds == (0,)
    assert "world 0" in str(info.value)
    unchecked = model.with_settings(check_finite=False)
    s = unchecked.initial_state(2)
    for k in range(90):
        step(unchecked, s, Control(motor=np.stack([torques[k // per], np.zeros(model.num_actuators)])))
    assert s.nonfinite_worlds().tolist() == [0]


def test_a_built_model_does_not_follow_its_builder():
    b = SceneBuilder()
    b.add_body("a", Sphere(0.1), mass=1.0)
    model = b.build()
    b.add_body("c", Sphere(0.1), mass=1.0)
    b.bodies[0].mass = 50.0
    again = model.with_settings(dt=0.01)
    assert model.num_bodies == again.num_bodies == 1
    assert model.mass[0] == again.mass[0] == 1.0


def test_nonfinite_error_names_the_moving_bodies_not_the_static_ones():
    # A NaN on a jointed rod reaches the static world body through 0 · NaN;
    # the error names the rod.
    b = SceneBuilder(gravity=None)
    b.add_body("rod", Capsule(0.05, 0.2), mass=2.0)
    b.add_hinge("h", None, "rod", anchor=(0, 0, 0.25), axis=(0, 1, 0))
    model = b.build()
    s = model.initial_state(2)
    s.angular_velocity[1, 0, 1] = np.nan
    with pytest.raises(SimulationError) as info:
        step(model, s)
    assert info.value.bodies == ("rod",)
    assert info.value.worlds == (1,)


def events_scene():
    """A spring that breaks at once in the worlds where its ball starts 1 m out."""
    b = SceneBuilder(gravity=None)
    b.add_body("a", Sphere(0.1), mass=1.0)
    b.add_spring("s", "a", None, anchor_b=(0, 0, 0), stiffness=10.0, elastic_limit=0.01)
    return b.build()


@pytest.mark.parametrize("worlds", [[2], [-1], np.array([False, False, True]), slice(2, 3)],
                         ids=["index", "negative", "mask", "slice"])
def test_select_keeps_a_worlds_events_numbered_in_the_new_state(worlds):
    model = events_scene()
    s = model.initial_state(3)
    s.position[2, 0, 0] = 1.0
    step(model, s)
    assert [(ev.world, ev.name) for ev in s.events] == [(2, "s")]
    picked = s.select(worlds)
    assert [(ev.world, ev.name) for ev in picked.events] == [(0, "s")]
    assert s.select([0, 2, 2]).events and [ev.world for ev in s.select([0, 2, 2]).events] == [1, 2]
    assert s.select([0, 1]).events == []


def test_assign_names_a_wrong_world_count_or_another_models_state():
    model = events_scene()
    s = model.initial_state(3)
    before = s.copy()
    with pytest.raises(ValueError, match="state of 3 worlds to 2 selected worlds"):
        s.assign([0, 1], model.initial_state(3))
    with pytest.raises(ValueError, match="per world in the other state .* another model"):
        s.assign([0], two_balls().initial_state(1))
    assert s.equal(before)


@pytest.mark.parametrize("worlds", [np.array([False, True, True]), slice(1, 3), [1, -1]],
                         ids=["mask", "slice", "indices"])
def test_apply_impulse_takes_worlds_as_select_does(worlds):
    model = events_scene()
    s = model.initial_state(3)
    apply_impulse(model, s, "a", (2.0, 0.0, 0.0), worlds=worlds)
    np.testing.assert_array_equal(s.velocity[:, 0, 0], [0.0, 2.0, 2.0])
