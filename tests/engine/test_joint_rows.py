"""The Gauss-Seidel joint rows' kernels (engine.core.joint_rows): each row
against what it solves (a rigid row without bias zeroes its constraint
velocity and keeps the momenta), breaking, the thesis's projection, and the
determinism of the batch (W worlds together equal each alone, 1 and 2
threads give the same bits)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

import engine as e
from benchmarks import scenes
from engine.core import joint_rows
from engine.core.jit import SERIAL_BELOW, set_threads
from engine.math3d import quat_from_axis_angle, quat_rotate

RIGID = (0.0, 1.0, 0.0)  # bias rate, mass scale, impulse scale: no position error, rigid
PUSH = (3.0, 10.0)  # joint_max_push_out m/s, joint_max_angular_push_out rad/s


def _two_links(kind, num_worlds=3, seed=0, **settings):
    """Two free boxes joined at x = 0.2 m by a joint of ``kind``, no gravity,
    with random velocities and slightly turned; its JointSet prepared for a
    substep (world inverse inertias, geometry)."""
    b = e.SceneBuilder(gravity=None, joint_solver="gauss_seidel", **settings)
    b.add_body("a", e.Box((0.2, 0.05, 0.08)), mass=1.5, position=(0.0, 0, 0))
    b.add_body("b", e.Box((0.2, 0.1, 0.05)), mass=0.7, position=(0.4, 0, 0),
               orientation=quat_from_axis_angle(np.array([0.3, 1.0, 0.2]) / math.hypot(0.3, 1.0, 0.2), 0.2))
    if kind == "hinge":
        b.add_hinge("j", "a", "b", anchor=(0.2, 0, 0), axis=(0, 0, 1), limits=(-0.4, 0.4))
    elif kind == "fixed":
        b.add_fixed("j", "a", "b", anchor=(0.2, 0, 0))
    else:
        b.add_ball("j", "a", "b", anchor=(0.2, 0, 0), twist_axis=(1, 0, 0), swing_limits=(0.5, 0.3),
                   twist_limits=(-0.3, 0.3))
    model = b.build()
    state = model.initial_state(num_worlds)
    rng = np.random.default_rng(seed)
    state.velocity[...] = rng.normal(size=state.velocity.shape)
    state.angular_velocity[...] = 3.0 * rng.normal(size=state.angular_velocity.shape)
    js = model.joints
    js.begin_step(model, state, model.settings.substep_dt)
    return model, state, js


def _momenta(model, state, js):
    """Linear momentum (W, 3) and the angular momentum Σ I_w ω (W, 3) of
    the bodies about their centres (pure torques keep it)."""
    m = model.mass[None, :, None]
    p = (m * state.velocity).sum(axis=1)
    spin = np.linalg.solve(js._iinv, state.angular_velocity[..., None])[..., 0]
    return p, spin


def _angular_momentum(model, state, js):
    """Σ (x × m v + I_w ω) (W, 3) about the origin."""
    m = model.mass[None, :, None]
    _, spin = _momenta(model, state, js)
    return (np.cross(state.position, m * state.velocity) + spin).sum(axis=1)


def _solve_equality(model, state, js, soft=RIGID):
    joints, kinds, _, _ = js._row_orders
    joint_rows.solve_equality(js.arrays, joints, kinds, js._iinv, model.inv_mass, js.geometry(state),
                              state.position, state.velocity, state.angular_velocity, state.joint_linear_impulse,
                              state.joint_angular_impulse, state.joint_broken, *soft, *PUSH)


def _anchor_velocity(state, js):
    g = js.geometry(state)
    a, b = js.parent[0], js.child[0]
    ra, rb = g.ra[:, 0], g.rb[:, 0]
    return (state.velocity[:, b] + np.cross(state.angular_velocity[:, b], rb)
            - state.velocity[:, a] - np.cross(state.angular_velocity[:, a], ra))


@pytest.mark.parametrize("kind", ["ball", "hinge", "fixed"])
def test_rigid_rows_zero_their_constraint_velocity_and_keep_the_momenta(kind):
    model, state, js = _two_links(kind)
    p0 = _momenta(model, state, js)[0]
    L0 = _angular_momentum(model, state, js)
    g = js.geometry(state)
    # Hinge and fixed lock rows first, then the point row (a colour's order):
    # the point row solved last is exact, the locks' rows to the coupling
    # through the point row's angular impulse.
    _solve_equality(model, state, js)
    np.testing.assert_allclose(_anchor_velocity(state, js), 0.0, atol=1e-12)
    p1 = _momenta(model, state, js)[0]
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-12)
    # The anchors coincide, so the point impulses are equal and opposite at one point.
    np.testing.assert_allclose(_angular_momentum(model, state, js), L0, rtol=0, atol=1e-12)
    assert np.abs(state.joint_linear_impulse).max() > 0.1
    if kind == "fixed":
        # The lock alone (before the point row) zeroes the relative spin.
        model, state, js = _two_links(kind)
        only = np.array([0]), np.array([joint_rows.FIXED_LOCK])
        joint_rows.solve_equality(js.arrays, *only, js._iinv, model.inv_mass, g, state.position, state.velocity,
                                  state.angular_velocity, state.joint_linear_impulse, state.joint_angular_impulse,
                                  state.joint_broken, *RIGID, *PUSH)
        w = state.angular_velocity
        np.testing.assert_allclose(w[:, 1] - w[:, 0], 0.0, atol=1e-12)
    if kind == "hinge":
        model, state, js = _two_links(kind)
        only = np.array([0]), np.array([joint_rows.HINGE_LOCK])
        joint_rows.solve_equality(js.arrays, *only, js._iinv, model.inv_mass, g, state.position, state.velocity,
                                  state.angular_velocity, state.joint_linear_impulse, state.joint_angular_impulse,
                                  state.joint_broken, *RIGID, *PUSH)
        w = state.angular_velocity
        wrel = w[:, 1] - w[:, 0]
        f = g.fpw[:, 0]
        for axis in (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])):
            np.testing.assert_allclose((wrel * quat_rotate(f, np.broadcast_to(axis, wrel.shape))).sum(-1), 0.0,
                                       atol=1e-12)


def test_broken_joints_take_no_impulse():
    model, state, js = _two_links("ball")
    state.joint_broken[1] = True
    before = state.copy()
    _solve_equality(model, state, js)
    assert np.array_equal(state.velocity[1], before.velocity[1])
    assert np.array_equal(state.angular_velocity[1], before.angular_velocity[1])
    assert not np.array_equal(state.velocity[0], before.velocity[0])


def test_soft_point_row_is_the_implicit_spring_update():
    """Δλ = -m s_m (Ċ + rate C) - s_i λ: with a stored λ and an open joint,
    the new constraint velocity is (1 - s_m) Ċ - s_m rate C - s_i K λ."""
    model, state, js = _two_links("ball", num_worlds=1)
    state.position[0, 1] += (0.0, 0.01, -0.02)  # open the joint by about 2.2 cm
    js.positions_moved()
    soft = e.soft.make_soft(30.0, 1.0, model.settings.substep_dt)
    lam = np.array([0.3, -0.2, 0.1])
    state.joint_linear_impulse[0, 0] = lam
    g = js.geometry(state)
    a, b = 0, 1
    ra, rb = g.ra[0, 0], g.rb[0, 0]
    sep = state.position[0, b] + rb - state.position[0, a] - ra
    cdot = _anchor_velocity(state, js)[0]

    def skew(r):
        return np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])

    K = (model.inv_mass[a] + model.inv_mass[b]) * np.eye(3)
    for r, i in ((ra, js._iinv[0, a]), (rb, js._iinv[0, b])):
        K += skew(r).T @ i @ skew(r)
    _solve_equality(model, state, js, (soft.bias_rate, soft.mass_scale, soft.impulse_scale))
    dlam = state.joint_linear_impulse[0, 0] - lam
    expected = -soft.mass_scale * np.linalg.solve(K, cdot + soft.bias_rate * sep) - soft.impulse_scale * lam
    np.testing.assert_allclose(dlam, expected, rtol=1e-10, atol=1e-12)


def _limits(model, state, js, use_bias):
    _, _, twist_row, swing_row = js._row_orders
    h = model.settings.substep_dt
    joint_rows.solve_limits(js.arrays, js.gs_limit, twist_row, swing_row, js.lower, js.upper, js._iinv,
                            js.geometry(state), state.angular_velocity, state.joint_limit_impulse,
                            state.joint_broken, h, use_bias, 0.0, 1.0, 0.0, np.zeros((state.num_worlds, 0), bool),
                            0.0, 1.0, 0.0, 0.05, 10.0)


def test_violated_hinge_limit_stops_the_closing_rate_and_keeps_an_opening_one():
    """A hinge over 0.05 rad beyond its lower limit: a rigid row without bias (the
    relax) zeroes a closing twist rate and takes no impulse on an opening
    one; the angular momentum is kept."""
    model, state, js = _two_links("hinge", num_worlds=2)
    q = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), -0.5)
    state.orientation[:, 1] = q
    state.position[:, 1] = (0.2, 0, 0) + quat_rotate(q, np.array([0.2, 0.0, 0.0]))
    state.angular_velocity[...] = 0.0
    state.velocity[...] = 0.0
    state.angular_velocity[0, 1] = (0.0, 0.0, -2.0)  # closing: further below the lower limit
    state.angular_velocity[1, 1] = (0.0, 0.0, 2.0)  # opening
    js.positions_moved(model, state)
    g = js.geometry(state)
    assert (g.twist[:, 0] < js.lower[0] - 0.05).all()  # violated
    spin0 = _momenta(model, state, js)[1].sum(axis=1)
    before = state.angular_velocity.copy()
    _limits(model, state, js, use_bias=False)
    wrel = state.angular_velocity[:, 1] - state.angular_velocity[:, 0]
    rate = (wrel * g.jt[:, 0]).sum(-1)
    assert abs(rate[0]) < 1e-12 and state.joint_limit_impulse[0, 0, 0] > 0
    assert np.array_equal(state.angular_velocity[1], before[1]) and state.joint_limit_impulse[1, 0, 0] == 0.0
    np.testing.assert_allclose(_momenta(model, state, js)[1].sum(axis=1), spin0, atol=1e-12)


def test_open_limit_is_speculative():
    """Open by C, a row lets the joint close by C within the substep (bias
    C/h) and no further."""
    model, state, js = _two_links("hinge", num_worlds=1)
    h = model.settings.substep_dt
    state.angular_velocity[...] = 0.0
    state.angular_velocity[0, 1] = (0.0, 0.0, -100.0)  # at the lower limit in well under a substep
    _limits(model, state, js, use_bias=True)
    g = js.geometry(state)
    wrel = state.angular_velocity[0, 1] - state.angular_velocity[0, 0]
    C = g.twist[0, 0] - js.lower[0]
    assert float(wrel @ g.jt[0, 0]) == pytest.approx(-C / h, rel=1e-12)


def test_snap_breaks_overloaded_joints_and_zeroes_their_impulses():
    W, J = 2, 3
    lin_sum = np.zeros((W, J, 3))
    ang_sum = np.zeros((W, J))
    dt = 1 / 60
    lin_sum[0, 1] = (3.0, 4.0, 0.0)  # 5 N s over the step: 300 N
    ang_sum[1, 2] = 0.5  # 30 N m
    broken = np.zeros((W, J), dtype=bool)
    broken[1, 0] = True
    lin, ang, lim = (np.ones((W, J, 3)) for _ in range(3))
    snapped = np.zeros((W, J), dtype=bool)
    joint_rows.snap(lin_sum, ang_sum, dt, np.array([299.0, 299.0, 301.0]), np.array([29.0, 31.0, 29.0]),
                    broken, lin, ang, lim, snapped)
    expected = np.zeros((W, J), dtype=bool)
    expected[0, 1] = expected[1, 2] = True  # not 0, 0 (no load) nor 1, 0 (broken before)
    assert np.array_equal(snapped, expected)
    assert np.array_equal(broken, expected | (np.arange(J) == 0) & (np.arange(W) == 1)[:, None])
    for arr in (lin, ang, lim):
        assert np.array_equal(arr[expected], np.zeros((2, 3))) and (arr[~expected] == 1.0).all()


def test_add_load_sums_the_impulses():
    rng = np.random.default_rng(3)
    lin, ang, lim = (rng.normal(size=(2, 4, 3)) for _ in range(3))
    lin_sum, ang_sum = np.ones((2, 4, 3)), np.ones((2, 4))
    joint_rows.add_load(lin, ang, lim, lin_sum, ang_sum)
    np.testing.assert_array_equal(lin_sum, 1.0 + lin)
    np.testing.assert_allclose(ang_sum, 1.0 + np.linalg.norm(ang, axis=-1) + np.abs(lim).sum(-1), rtol=1e-15)


def test_thesis_projection_closes_a_joint_and_keeps_the_centre_of_mass():
    model, state, js = _two_links("ball", num_worlds=2, solver="thesis")
    state.position[:, 1] += (0.03, -0.02, 0.01)
    state.joint_broken[1] = True
    m = model.mass[None, :, None]
    centre = (m * state.position).sum(axis=1)
    before = state.position.copy()
    js.positions_moved()
    js.project_positions(model, state)
    js.positions_moved()
    assert js.anchor_error(state)[0, 0] < 1e-15
    np.testing.assert_allclose((m * state.position).sum(axis=1), centre, rtol=1e-15)
    assert np.array_equal(state.position[1], before[1])  # broken: not moved


def _gs_case(num_worlds):
    """The standing humanoid under random maximum torques with Gauss-Seidel
    joint rows and limits (SOFT_JOINTS: limits outside the tree, soft zone)
    and with the Gauss-Seidel joint solver, ``num_worlds`` each."""
    for settings in (e.SOFT_JOINTS, {"joint_solver": "gauss_seidel"}):
        case = scenes.ragdoll_max_torque(num_worlds=num_worlds)
        case.model = case.model.with_settings(**settings)
        yield case


def _run(case, state, steps):
    for k in range(steps):
        e.step(case.model, state, None if case.controller is None else case.controller(k, state))
    return state


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
def test_one_and_two_threads_give_the_same_bits(restore_threads):
    W = SERIAL_BELOW + 1  # the batch kernels' prange path
    for k in range(2):
        runs = []
        for threads in (1, 2):
            set_threads(threads)
            case = list(_gs_case(W))[k]
            runs.append(_run(case, case.state.copy(), 30))
        assert runs[0].equal(runs[1])
        assert (runs[0].joint_limit_impulse != 0).any()


def test_worlds_together_equal_each_alone():
    W = SERIAL_BELOW + 1
    for case in _gs_case(W):
        motors = [case.controller(k, None).motor.copy() for k in range(25)]
        together = case.state.copy()
        for m in motors:
            e.step(case.model, together, e.Control(motor=m))
        for w in (0, W - 1):
            alone = case.state.select([w])
            for m in motors:
                e.step(case.model, alone, e.Control(motor=m[w:w + 1]))
            assert alone.equal(together.select([w])), f"world {w}"


def test_breakable_chain_breaks_alike_alone_and_in_a_batch():
    """A chain with breakable ball, hinge and fixed joints under gravity at
    Gauss-Seidel settings, random start velocities: the same joints break at
    the same steps in a batch of W worlds and in each world alone."""
    W = SERIAL_BELOW + 1
    b = e.SceneBuilder(joint_solver="gauss_seidel")
    L = 0.2
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), math.pi / 2)
    prev = None
    for i in range(5):
        b.add_body(f"l{i}", e.Capsule(0.03, L / 2 - 0.03), mass=1.0, position=((i + 0.5) * L, 0, 2.0),
                   orientation=q)
        if i % 2:
            b.add_hinge(f"j{i}", prev, f"l{i}", anchor=(i * L, 0, 2.0), axis=(0, 1, 0), limits=(-0.5, 0.5),
                        break_torque=8.0)
        else:
            b.add_ball(f"j{i}", prev, f"l{i}", anchor=(i * L, 0, 2.0), twist_axis=(1, 0, 0),
                       swing_limits=(0.6, 0.4), twist_limits=(-0.4, 0.4), break_force=40.0 + 10 * i)
        prev = f"l{i}"
    b.add_body("box", e.Box((0.1, 0.1, 0.1)), mass=3.0, position=(5 * L + 0.1, 0, 2.0))
    b.add_fixed("weld", prev, "box", anchor=(5 * L, 0, 2.0), break_force=200.0)
    model = b.build()
    start = model.initial_state(W)
    start.angular_velocity[...] = np.random.default_rng(5).normal(scale=2.0, size=start.angular_velocity.shape)
    together = start.copy()
    events = []
    for _ in range(60):
        e.step(model, together)
        events += together.events
    assert events and together.joint_broken.any() and not together.joint_broken.all()
    for w in (0, 3, W - 1):
        alone = start.select([w])
        mine = []
        for _ in range(60):
            e.step(model, alone)
            mine += alone.events
        assert alone.equal(together.select([w])), f"world {w}"
        assert [(ev.name, ev.step) for ev in mine] == [(ev.name, ev.step) for ev in events if ev.world == w]
