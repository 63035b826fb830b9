"""Contact acceptance tests against analytic results: bounce heights e²ⁿh,
static and kinetic friction on an incline, stopping distance v²/(2 μk g),
momentum and restitution in head-on collisions, resting contact, stacking,
fast bodies, and the humanoid landing."""

from __future__ import annotations

import math

import numpy as np
import pytest

import engine as e
from benchmarks import scenarios
from engine.diagnostics import linear_momentum
from engine.materials import Material

G = e.STANDARD_GRAVITY


def apex_heights(zs):
    """Heights of the local maxima of a sampled trajectory, refined by a
    parabola through the three samples around each (the step samples miss the
    true apex by up to g (dt/2)²/2)."""
    out = []
    for i in range(1, len(zs) - 1):
        if zs[i] > zs[i - 1] and zs[i] >= zs[i + 1]:
            a, b, c = zs[i - 1], zs[i], zs[i + 1]
            denom = a - 2 * b + c
            out.append(b - (a - c) ** 2 / (8 * denom) if denom < 0 else b)
    return np.array(out)


def bouncing_ball(restitution, drop=1.0, **settings):
    b = e.SceneBuilder(**settings)
    b.materials.add(Material("bouncy", 0.5, 0.4, restitution))
    b.add_ground(material="bouncy")
    b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0, 0, 0.1 + drop), material="bouncy")
    return b.build()


def test_bounce_apex_heights_follow_e_to_the_2n_within_2_percent():
    # Apex n after a drop from h is e^(2n) h. Semi-implicit Euler's apex from a
    # launch at speed u is u²/2g + O(u h); the bound leaves room for that.
    e_ = 0.8
    model = bouncing_ball(e_)
    state = model.initial_state(1)
    zs = []
    for _ in range(420):
        e.step(model, state)
        zs.append(state.position[0, 1, 2] - 0.1)
    apex = apex_heights(np.array(zs))
    apex = apex[apex > 0.02][:5]
    expected = 1.0 * e_ ** (2 * np.arange(1, 6))
    assert apex.size == 5
    np.testing.assert_allclose(apex, expected, rtol=0.02)


def test_ball_with_zero_restitution_stays_down():
    model = bouncing_ball(0.0)
    state = model.initial_state(1)
    heights = []
    for _ in range(120):
        e.step(model, state)
        heights.append(state.position[0, 1, 2] - 0.1)
    landed = int(np.argmax(np.array(heights) < 1e-3))
    assert landed > 0
    assert max(heights[landed:]) < 1e-3  # never leaves the ground again
    assert abs(state.velocity[0, 1, 2]) < 1e-3


def box_on_incline(angle_deg, material="wood"):
    th = math.radians(angle_deg)
    n = np.array([-math.sin(th), 0.0, math.cos(th)])
    b = e.SceneBuilder()
    b.add_ground(normal=n, material=material)
    q = e.math3d.quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), -th)
    b.add_body("box", e.Box((0.2, 0.15, 0.1)), mass=2.0, position=n * 0.1, orientation=q, material=material)
    return b.build(), n


def test_box_on_incline_below_friction_angle_stays_put():
    # wood/wood: μs = 0.5, atan(μs) = 26.6°; at 20° static friction holds.
    model, n = box_on_incline(20.0)
    state = model.initial_state(1)
    for _ in range(30):  # let the contact settle (sub-millimetre)
        e.step(model, state)
    start = state.position[0, 1].copy()
    for _ in range(300):  # 5 s
        e.step(model, state)
    drift = state.position[0, 1] - start
    assert np.linalg.norm(drift) < 1e-3


def test_box_on_incline_above_friction_angle_slides_with_kinetic_acceleration():
    # a = g (sin θ − μk cos θ) with μk = 0.2 (wood/wood), within 2%.
    th = 30.0
    model, n = box_on_incline(th)
    state = model.initial_state(1)
    dt = model.settings.dt
    d = []
    for _ in range(120):
        e.step(model, state)
        d.append(np.linalg.norm(state.position[0, 1] - model.initial_state(1).position[0, 1]))
    t = dt * np.arange(1, 121)
    acc = 2 * np.polyfit(t[30:], np.array(d)[30:], 2)[0]
    expected = G * (math.sin(math.radians(th)) - 0.2 * math.cos(math.radians(th)))
    assert acc == pytest.approx(expected, rel=0.02)


def hinged_boxes_on_incline(angle_deg, **settings):
    """Three 1 kg wooden boxes (μs 0.5, μk 0.2) in a row up an incline,
    joined by hinges across the slope (``benchmarks.scenarios.hinged_boxes``):
    a jointed body whose friction must hold its neighbours' share of the load
    when the normal forces shift between them."""
    return scenarios.hinged_boxes(angle_deg, **settings).build()


PRESETS = {"defaults": {}, "SOFT_JOINTS": e.SOFT_JOINTS, "ACCURATE": e.ACCURATE}
RIGID_GAUSS_SEIDEL = pytest.param(
    {"articulated_contacts": False}, id="rigid joints, Gauss-Seidel contacts",
    marks=pytest.mark.xfail(strict=True, reason=(
        "rigid joints solved before body-by-body contacts share no friction load: a box whose "
        "normal force dips below m g sin θ / μs slips, passes 1 cm/s, takes the kinetic "
        "coefficient and the chain slides (21 m in 5 s at 24° with joint_hertz inf alone on the old "
        "defaults; ACCURATE before its articulated contacts crept 4.2 mm). Rigid joints (the defaults, "
        "ACCURATE) solve their contacts with the articulation's response (articulated_contacts) instead")))


@pytest.mark.parametrize("settings", [*PRESETS.values(), RIGID_GAUSS_SEIDEL],
                         ids=[*PRESETS, "rigid joints, Gauss-Seidel contacts"])
def test_hinged_boxes_below_the_friction_angle_stay_put(settings):
    # tan 24° = 0.445 < μs = 0.5: static friction holds the chain (the presets: under 1 µm).
    model = hinged_boxes_on_incline(24.0, **settings)
    state = model.initial_state(1)
    for _ in range(30):
        e.step(model, state)
    start = state.position[0, 1:].copy()
    for _ in range(180):  # 3 s
        e.step(model, state)
    assert np.linalg.norm(state.position[0, 1:] - start, axis=1).max() < 1e-4


@pytest.mark.parametrize("settings", PRESETS.values(), ids=PRESETS)
def test_hinged_boxes_above_the_friction_angle_slide_with_kinetic_acceleration(settings):
    # a = g (sin θ − μk cos θ) for the chain as for one box, within 1%.
    th = 30.0
    model = hinged_boxes_on_incline(th, **settings)
    state = model.initial_state(1)
    for _ in range(30):
        e.step(model, state)
    v0 = state.velocity[0, 1:].mean(axis=0)
    steps = 60
    for _ in range(steps):
        e.step(model, state)
    acc = np.linalg.norm(state.velocity[0, 1:].mean(axis=0) - v0) / (steps * model.settings.dt)
    expected = G * (math.sin(math.radians(th)) - 0.2 * math.cos(math.radians(th)))
    assert acc == pytest.approx(expected, rel=0.01)


def test_box_pushed_on_flat_ground_stops_after_v2_over_2_mu_g():
    v0, mu_k = 3.0, 0.2
    b = e.SceneBuilder()
    b.add_ground(material="wood")
    b.add_body("box", e.Box((0.2, 0.15, 0.1)), mass=2.0, position=(0, 0, 0.1), velocity=(v0, 0, 0),
               material="wood")
    model = b.build()
    state = model.initial_state(1)
    for _ in range(240):
        e.step(model, state)
    assert abs(state.velocity[0, 1, 0]) < 1e-6
    assert state.position[0, 1, 0] == pytest.approx(v0 ** 2 / (2 * mu_k * G), rel=0.02)


def spheres_in_a_row(velocities, restitution, masses=None, spacing=0.2):
    b = e.SceneBuilder(gravity=None)
    b.enable("contacts")
    b.enable("restitution")
    b.materials.add(Material("ball", 0.0, 0.0, restitution))
    for i, v in enumerate(velocities):
        m = 1.0 if masses is None else masses[i]
        b.add_body(f"s{i}", e.Sphere(0.1), mass=m, position=(i * spacing, 0, 0), velocity=(v, 0, 0),
                   material="ball")
    return b.build()


@pytest.mark.parametrize("restitution", [1.0, 0.5, 0.0])
def test_head_on_collision_conserves_momentum_and_matches_restitution(restitution):
    m1, m2, u1, u2 = 1.0, 3.0, 4.0, -2.0
    model = spheres_in_a_row([u1, u2], restitution, masses=[m1, m2], spacing=0.5)
    state = model.initial_state(1)
    p0 = linear_momentum(model, state)[0]
    for _ in range(30):
        e.step(model, state)
        np.testing.assert_allclose(linear_momentum(model, state)[0], p0, rtol=1e-9, atol=1e-12)
    v1, v2 = state.velocity[0, 0, 0], state.velocity[0, 1, 0]
    # 1D collision: v1' = (m1u1 + m2u2 + m2 e (u2−u1))/(m1+m2), and likewise v2'.
    exp1 = (m1 * u1 + m2 * u2 + m2 * restitution * (u2 - u1)) / (m1 + m2)
    exp2 = (m1 * u1 + m2 * u2 + m1 * restitution * (u1 - u2)) / (m1 + m2)
    assert v1 == pytest.approx(exp1, abs=1e-6)
    assert v2 == pytest.approx(exp2, abs=1e-6)


def test_newtons_cradle_passes_the_impulse_down_the_row():
    # Five touching equal balls, e = 1: the first one's momentum ends up in the last.
    model = spheres_in_a_row([2.0, 0, 0, 0, 0], 1.0, spacing=0.2)
    state = model.initial_state(1)
    state.position[0, 0, 0] -= 0.1  # a gap before the first collision
    for _ in range(40):
        e.step(model, state)
    v = state.velocity[0, :, 0]
    assert v[-1] == pytest.approx(2.0, abs=0.05)
    assert np.abs(v[:-1]).max() < 0.05
    np.testing.assert_allclose(v.sum(), 2.0, rtol=1e-9)


@pytest.mark.parametrize("gap", [
    0.05,
    pytest.param(0.06, marks=pytest.mark.xfail(strict=True, reason=(
        "known: from 6 cm the first impact spans two steps and the row keeps 68% of its energy, "
        "v = (-0.54, 0.18, 0.18, 1.09, 1.09) m/s; at 2 m/s 2 of 20 approach distances in 1-20 cm miss, "
        "at 5 m/s 8 of 20"))),
    0.1,
])
def test_newtons_cradle_keeps_its_energy_from_any_approach_distance(gap):
    # The same row, the first ball ``gap`` m away (the others at
    # 0.2, 0.4, 0.6, 0.8 m + gap): whatever step the impact falls in, the last ball leaves
    # with all of the first one's speed and the row keeps its energy.
    model = spheres_in_a_row([2.0, 0, 0, 0, 0], 1.0, spacing=0.2)
    state = model.initial_state(1)
    state.position[0, 1:, 0] = np.array([0.2, 0.4, 0.6, 0.8]) + gap
    for _ in range(60):
        e.step(model, state)
    v = state.velocity[0, :, 0]
    np.testing.assert_allclose(v.sum(), 2.0, rtol=1e-9)
    assert 0.5 * (v ** 2).sum() == pytest.approx(2.0, rel=0.02)
    assert v[-1] == pytest.approx(2.0, abs=0.05)


@pytest.mark.parametrize("material", ["wood", "steel", "rubber"])
def test_box_landing_flat_bounces_to_e_squared_h_without_spin(material):
    # Four simultaneous corner impacts: apex e²h within 2%, and no spin or
    # sideways drift from the order the corners are solved in.
    h0 = 1.0
    b = e.SceneBuilder()
    b.add_ground(material=material)
    b.add_body("box", e.Box((0.2, 0.15, 0.1)), mass=2.0, position=(0, 0, 0.1 + h0), material=material)
    model = b.build()
    restitution = b.materials.get(material).restitution
    state = model.initial_state(1)
    while state.velocity[0, 1, 2] <= 0:
        e.step(model, state)
        assert state.step[0] < 60, "the box did not bounce"
    assert np.abs(state.angular_velocity[0, 1]).max() < 1e-3
    assert np.abs(state.velocity[0, 1, :2]).max() < 1e-4
    while state.velocity[0, 1, 2] > 0:
        z, vz = state.position[0, 1, 2] - 0.1, state.velocity[0, 1, 2]
        e.step(model, state)
    apex = z + vz ** 2 / (2 * 9.81)  # ballistic apex from the last rising step
    assert apex == pytest.approx(restitution ** 2 * h0, rel=0.02)


def test_newtons_cradle_with_partial_restitution_keeps_momentum_and_loses_energy():
    model = spheres_in_a_row([2.0, 0, 0, 0, 0], 0.9, spacing=0.2)
    state = model.initial_state(1)
    state.position[0, 0, 0] -= 0.1
    for _ in range(40):
        e.step(model, state)
    v = state.velocity[0, :, 0]
    np.testing.assert_allclose(v.sum(), 2.0, rtol=1e-9)
    assert 0.5 * (v ** 2).sum() < 0.5 * 2.0 ** 2
    assert v[-1] > 1.5 and np.all(np.diff(v) >= -1e-9)  # no ball overtakes the one in front


def test_box_resting_flat_has_four_points_and_settles():
    b = e.SceneBuilder()
    b.add_ground(material="wood")
    b.add_body("box", e.Box((0.2, 0.15, 0.1)), mass=2.0, position=(0, 0, 0.12), material="wood")
    model = b.build()
    state = model.initial_state(1)
    for _ in range(180):
        e.step(model, state)
    assert (state.contact_normal_impulse[0, 0] > 0).sum() == 4
    assert -state.contact_separation[0, 0] < 1e-3  # penetration under 1 mm
    assert np.abs(state.velocity[0, 1]).max() < 1e-3
    assert np.abs(state.angular_velocity[0, 1]).max() < 1e-2


@pytest.mark.parametrize("coloring, colors", [("ordered", 9), ("greedy", 2)])
def test_stack_of_ten_boxes_stands_for_10_s_with_top_drift_under_1_cm(coloring, colors):
    # Drift is measured from the settled stack (after 1 s): the soft contacts
    # first compress under the load (about 2 mm at the ground under 10 kg,
    # reported by benchmarks.accuracy), then the stack must hold still.
    # Ordered colours sweep the box-on-box rows one after another (9 colours);
    # greedy (first-fit) colours sweep them in 2.
    b = e.SceneBuilder(contact_coloring=coloring)
    b.add_ground(material="wood")
    h = 0.1
    for i in range(10):
        b.add_body(f"box{i}", e.Box((0.2, 0.2, h)), mass=1.0, position=(0, 0, h + 2 * h * i), material="wood")
    model = b.build()
    state = model.initial_state(1)
    for _ in range(60):
        e.step(model, state)
    top0 = state.position[0, -1].copy()
    for _ in range(600):
        e.step(model, state)
    assert np.linalg.norm(state.position[0, -1] - top0) < 0.01
    assert np.abs(state.velocity).max() < 1e-2
    assert len(model.contacts.rows.colors) == colors


def _fastest_speed(model, state, t0, t1):
    """Largest body speed (m/s) over [t0, t1] s of stepping ``state``."""
    dt, fastest = model.settings.dt, 0.0
    for k in range(int(round(t1 / dt))):
        e.step(model, state)
        if (k + 1) * dt >= t0:
            fastest = max(fastest, float(np.linalg.norm(state.velocity, axis=-1).max()))
    return fastest


@pytest.mark.parametrize("passes, bound", [(1, 0.005), (0, None)])
def test_stack_of_five_boxes_comes_to_rest_with_a_second_relax_pass(passes, bound):
    # 0.5 m boxes of 1 kg. With one relax pass the residual of the first
    # normal points of each row rocks the stack, the top box circling at
    # 0.02-0.03 m/s for as long as it stands; the pass over the rows of
    # unjointed bodies (the default) brings every box under 1 mm/s.
    b = e.SceneBuilder(free_contact_relax_passes=passes)
    b.add_ground()
    for i in range(5):
        b.add_body(f"box{i}", e.Box((0.25, 0.25, 0.25)), mass=1.0, position=(0, 0, 0.25 + i * 0.501))
    model = b.build()
    fastest = _fastest_speed(model, model.initial_state(1), 2.0, 3.0)
    if bound is None:
        assert fastest > 0.01  # the case the pass is for: without it the stack still moves
    else:
        assert fastest < bound


@pytest.mark.parametrize("setting, off, on", [("free_contact_relax_passes", 0, 1),
                                               ("contact_load_stiffening", 1.0, 1.25)])
def test_rows_on_jointed_bodies_step_as_without_the_free_row_settings(setting, off, on):
    # The further relax pass and the load stiffening act on rows between
    # bodies without joints: a ragdoll's contacts (all on jointed bones) are
    # solved exactly as without them, bit for bit; a box dropped beside it is not.
    from engine.humanoid import add_humanoid

    states = []
    for value in (off, on):
        b = e.SceneBuilder(**{setting: value})
        b.add_ground()
        add_humanoid(b, position=(0, 0, 1.0))
        b.add_body("box", e.Box((0.2, 0.2, 0.2)), mass=1.0, position=(2.0, 0, 0.5))
        model = b.build()
        state = model.initial_state(1)
        for _ in range(60):
            e.step(model, state)
        states.append(state)
    box = states[0].position.shape[1] - 1
    assert np.array_equal(states[0].position[:, :box], states[1].position[:, :box])
    assert np.array_equal(states[0].angular_velocity[:, :box], states[1].angular_velocity[:, :box])
    assert not np.array_equal(states[0].velocity[:, box], states[1].velocity[:, box])


@pytest.mark.parametrize("stiffening", [1.0, 1.25])
def test_resting_depth_is_the_load_over_the_soft_spring(stiffening):
    """A soft contact point rests where its spring, s m_n ω² (m_n its effective
    mass, ω = 2π 60 Hz, s the load stiffening), holds its load F: at
    F / (s m_n ω²). A 1 kg box alone on the ground (each corner carrying the
    weight of its own m_n: s = 1) sinks g/ω² = 0.069 mm with or without the
    stiffening; the bottom of a stack of five carries five times that and
    sinks 5 g/ω² without it, 5 g/(1.25 ω²) with it; the box-on-box points
    (m_n halved, so twice as deep) likewise."""
    b = e.SceneBuilder(contact_load_stiffening=stiffening)
    b.add_ground()
    for i in range(5):
        b.add_body(f"box{i}", e.Box((0.25, 0.25, 0.25)), mass=1.0, position=(0, 0, 0.25 + i * 0.501))
    b.add_body("alone", e.Box((0.25, 0.25, 0.25)), mass=1.0, position=(3.0, 0, 0.25))
    model = b.build()
    state = model.initial_state(1)
    for _ in range(120):
        e.step(model, state)
    z = state.position[0, 1:, 2]
    unit = G / (2 * math.pi * 60.0) ** 2  # g / ω², m
    s = min(stiffening, 1.25)
    assert 0.25 - z[5] == pytest.approx(unit, rel=0.01)
    assert 0.25 - z[0] == pytest.approx(5 * unit / s, rel=0.02)
    for k in range(1, 5):  # the interface under box k carries 5 - k boxes
        assert 0.5 - (z[k] - z[k - 1]) == pytest.approx(2 * (5 - k) * unit / s, rel=0.02)


@pytest.mark.parametrize("target", ["ground", "thin_box"])
def test_capsule_at_100_m_per_s_does_not_pass_through(target):
    b = e.SceneBuilder(gravity=None)
    b.add_ground()
    if target == "thin_box":
        # A 5 cm thick plate, wide enough that the deflected capsule stays over it.
        b.add_body("plate", e.Box((5.0, 5.0, 0.025)), static=True, position=(0, 0, 1.0))
        floor = 1.025
    else:
        floor = 0.0
    q = e.math3d.quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.3)
    b.add_body("bullet", e.Capsule(0.05, 0.2), mass=1.0, position=(0, 0, floor + 2.0), orientation=q,
               velocity=(0, 0, -100.0))
    model = b.build()
    state = model.initial_state(1)
    lowest = np.inf
    for _ in range(20):
        e.step(model, state)
        z = state.position[0, -1, 2]
        lowest = min(lowest, z)
    # The capsule's centre never gets below the surface (it would need to pass
    # by its radius plus its tilted half-length to tunnel).
    assert lowest > floor


def test_humanoid_dropped_from_1_m_settles_without_sinking_or_jitter():
    from engine.humanoid import add_humanoid

    b = e.SceneBuilder()
    b.add_ground()
    add_humanoid(b, position=(0, 0, 1.0))
    model = b.build()
    state = model.initial_state(1)
    for _ in range(180):  # 3 s
        e.step(model, state)
    sep = state.contact_separation[np.isfinite(state.contact_separation)]
    assert -sep.min() < 0.005  # no part more than 5 mm below the ground
    assert np.linalg.norm(state.velocity[0], axis=-1).max() < 0.01


def test_impacts_of_a_world_do_not_depend_on_the_other_worlds():
    # Sequential impacts iterate until each row settles; a world stepped in a
    # batch must match the same world stepped alone, bit for bit.
    model = spheres_in_a_row([2.0, 0, 0, 0, 0], 0.7, spacing=0.2)
    batch = model.initial_state(3)
    batch.position[:, 0, 0] -= np.array([0.1, 0.05, 0.13])
    batch.velocity[:, 0, 0] = [2.0, 3.5, 1.2]
    alone = batch.select([1])
    for _ in range(30):
        e.step(model, batch)
        e.step(model, alone)
    assert alone.equal(batch.select([1]))


def test_declared_contacts_bring_friction_without_a_ground():
    # A box sliding on a static slab, contacts declared with enable("contacts")
    # (no ground): friction comes with them and it stops after v²/2μg.
    v0, mu_k = 3.0, 0.2
    b = e.SceneBuilder()
    b.enable("contacts")
    b.add_body("slab", e.Box((5.0, 5.0, 0.1)), position=(0, 0, -0.1), static=True, material="wood")
    b.add_body("box", e.Box((0.2, 0.15, 0.1)), mass=2.0, position=(0, 0, 0.1), velocity=(v0, 0, 0),
               material="wood")
    model = b.build()
    assert {"contacts", "friction", "restitution"} <= set(model.effect_names)
    state = model.initial_state(1)
    for _ in range(240):
        e.step(model, state)
    box = model.body_index("box")
    assert abs(state.velocity[0, box, 0]) < 1e-6
    assert state.position[0, box, 0] == pytest.approx(v0 ** 2 / (2 * mu_k * G), rel=0.02)


def _rows_scene(**settings):
    """Boxes stacked on the ground and a ball on a hinge beside them, three
    worlds at different heights (world 2 in the air)."""
    b = e.SceneBuilder(**settings)
    b.add_ground(material="rubber")
    for i in range(3):
        b.add_body(f"box{i}", e.Box((0.1, 0.1, 0.1)), mass=1.0 + i, position=(0.01 * i, 0, 0.099 + 0.199 * i),
                   material="rubber")
    b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0.5, 0, 0.099))
    b.add_hinge("pin", None, "ball", anchor=(0.5, 0, 0.5), axis=(0, 1, 0))
    model = b.build()
    state = model.initial_state(3)
    state.position[1, 1:, 2] -= 0.002
    state.position[2, 1:, 2] += 1.0
    return model, state


def test_the_steps_rows_are_gathered_by_pair_then_world_with_their_bodies_and_warm_start():
    model, state = _rows_scene()
    cs = model.contacts
    rng = np.random.default_rng(0)
    lam_n = rng.random(state.contact_normal_impulse.shape)
    lam_t = rng.random(state.contact_friction_impulse.shape)
    state.contact_normal_impulse[...] = lam_n
    state.contact_friction_impulse[...] = lam_t
    cs.begin_step(model, state, model.settings.dt / model.settings.substeps)
    rows = cs.rows
    keep = np.isfinite(state.contact_separation)  # the pairs with a valid point
    p, w = np.nonzero(keep.T)
    assert np.array_equal(rows.p, p) and np.array_equal(rows.w, w)
    assert not ((rows.w == 2) & ~rows.dyn_a).any()  # in the air: rows between the boxes only
    a, b = cs.pair_a[p], cs.pair_b[p]
    assert np.array_equal(rows.a, a) and np.array_equal(rows.b, b)
    assert np.array_equal(rows.dyn_a, model.dynamic[a]) and np.array_equal(rows.dyn_b, model.dynamic[b])
    assert np.array_equal(rows.inv_ma, model.inv_mass[a]) and np.array_equal(rows.inv_mb, model.inv_mass[b])
    ball = model.body_index("ball")
    assert np.array_equal(rows.jointed, (a == ball) | (b == ball))
    assert np.array_equal(rows.arrays.free, ~rows.jointed)
    assert np.array_equal(rows.e, cs.restitution[p]) and rows.bouncy
    g = np.array(model.gravity)
    assert np.array_equal(rows.gravity_n, (rows.n @ g) * (rows.dyn_b * 1.0 - rows.dyn_a * 1.0))
    # The warm start of the valid slots; the state's impulses restart at 0.
    assert np.array_equal(rows.lam_n, np.where(rows.valid, lam_n[w, p], 0.0))
    assert np.array_equal(rows.lam_n_start, rows.lam_n)
    assert not state.contact_normal_impulse.any() and not state.contact_friction_impulse.any()
    assert not rows.max_lam_n.any() and not rows.s_close.any()


@pytest.mark.parametrize("coloring", ["ordered", "greedy"])
def test_the_sweep_order_is_by_world_then_colour_then_row_with_no_body_twice_in_a_colour(coloring):
    model, state = _rows_scene(contact_coloring=coloring)
    cs = model.contacts
    h = model.settings.dt / model.settings.substeps
    cs.begin_step(model, state, h)
    rows = cs.rows
    color = rows.color
    key = (rows.w, color, np.arange(rows.w.size))
    assert np.array_equal(rows.order, np.lexsort(key[::-1]))
    assert np.array_equal(rows.world_start, np.searchsorted(rows.w[rows.order], np.arange(4)))
    for c in rows.colors:
        keys = np.concatenate(((rows.w * 10 + rows.a)[c][rows.dyn_a[c]], (rows.w * 10 + rows.b)[c][rows.dyn_b[c]]))
        assert np.unique(keys).size == keys.size
    # Each world's colours are those of its rows alone (keys: its bodies).
    for w in (0, 1):
        alone = state.select([w])
        cs.begin_step(model, alone, h)
        assert np.array_equal(cs.rows.color, color[rows.w == w])


def test_the_thesis_projection_moves_a_body_out_by_its_depth_beyond_the_slop():
    b = e.SceneBuilder(solver="thesis")
    b.add_ground()
    b.add_body("box", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=(0, 0, 0.1 - 0.03))
    b.add_body("light", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=(1.0, 0, 0.1 - 0.01))
    b.add_body("heavy", e.Box((0.1, 0.1, 0.1)), mass=3.0, position=(1.0, 0, 0.29 - 0.01))
    model = b.build()
    state = model.initial_state(1)
    before = state.position.copy()
    cs = model.contacts
    cs.begin_step(model, state, model.settings.dt / model.settings.substeps)
    cs.rows.project_positions(model, state)
    slop = model.settings.linear_slop
    rise = state.position[0, :, 2] - before[0, :, 2]
    box, light, heavy = (model.body_index(n) for n in ("box", "light", "heavy"))
    assert rise[box] == pytest.approx(0.03 - slop, abs=1e-12)
    # The pair of boxes 1 cm into each other: 3/4 of it to the light one, 1/4 to the heavy one; the light
    # one's ground row first lifts it by its own depth (the rows' depths are read before any move).
    assert rise[heavy] == pytest.approx(0.25 * (0.01 - slop), abs=1e-12)
    assert rise[light] == pytest.approx(0.01 - slop - 0.75 * (0.01 - slop), abs=1e-12)
    assert np.array_equal(state.position[..., :2], before[..., :2])
