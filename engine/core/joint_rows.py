"""Gauss-Seidel joint rows of one world: point and lock rows, one-sided
limits, the thesis's position correction and breaking.

The rows solved body by body (joints outside the tree: with
``joint_solver="gauss_seidel"``, loop-closing joints with
``joint_loops="gauss_seidel"``, limits outside the tree, the thesis
solver) in the soft step (Catto, "Soft Step", 2024; ``engine.soft``): per row
with effective mass m and error C,

    Δλ = -m s_m (J·u + bias) - s_i λ

with bias = rate·C capped at the push-out speed (1/s, the softness's bias
rate; ``joint_max_push_out`` m/s, ``joint_max_angular_push_out`` rad/s).

* point: the two anchors held together, a 3x3 block with
  K = (1/m_a + 1/m_b) 1 + [r_a]×ᵀ I_a⁻¹ [r_a]× + [r_b]×ᵀ I_b⁻¹ [r_b]×
  solved by the adjugate (as ``engine.math3d.sym3_solve``) on
  Ċ = (v_b + ω_b × r_b) - (v_a + ω_a × r_a), C = (x_b + r_b) - (x_a + r_a).
* hinge lock: the parent frame's y, z axes, a 2x2 block on ω_b - ω_a with
  the error a × c of the two hinge axes.
* fixed lock: all three rotations, a 3x3 block (I_a⁻¹ + I_b⁻¹), the error
  the small-angle rotation vector 2 vec(q) sign(w) of q = f_c ⊗ f_p⁻¹.
* one-sided limits (Box2D v3 joint limits) about the twist row (lower:
  C = θ - θ_lo, upper: C = θ_hi - θ) and the swing row (C = ``c_swing``),
  λ ≥ 0: while open (C > 0) rigid with the speculative bias C/h, when
  violated soft; within ``limit_soft_margin`` of its bound a violated row of
  an articulation in contact takes the tree joints' softness (per world and
  row, ``JointSet._soft_limit_zone``).

The joints are taken colour by colour (no moving body twice in a colour),
then one by one: a colour's joints share no moving body, so this gives the
numbers of a sweep of each colour at once, in the same order of
floating-point operations. The geometry (frames, lever arms, limit rows)
comes from ``engine.core.joints.JointGeometry`` at the solve's positions.
"""

from __future__ import annotations

import math

from .jit import SERIAL_BELOW, kernel, parallel_kernel, prange
from .joints import _add3
from .vec import add, cross, dot, load3, load4, mat3_vec, neg, quat_conj, quat_mul, rotate, scale, sub, sym3_inverse

#: Kinds of equality row, in the order a colour's rows are solved.
HINGE_LOCK, FIXED_LOCK, POINT = 0, 1, 2


# ------------------------------------------------------------------ helpers
@kernel
def _maximum(x, y):
    """max(x, y) that keeps a NaN x, as np.maximum does."""
    if x > y or x != x:
        return x
    return y


@kernel
def _minimum(x, y):
    """min(x, y) that keeps a NaN x, as np.minimum does."""
    if x < y or x != x:
        return x
    return y


@kernel
def _clamp_norm(a, limit):
    """a scaled down to length at most ``limit`` (``engine.math3d.clamp_norm``)."""
    n = math.sqrt(dot(a, a))
    return scale(_minimum(n, limit) / _maximum(n, 1e-300), a)


@kernel
def _sym3_solve(a00, a01, a02, a11, a12, a22, b):
    """x with K x = b for the symmetric K of upper triangle a, by the adjugate
    (``engine.math3d.sym3_solve``: the cofactors, the determinant by the first
    row, each entry of the inverse times b summed left to right; singular: 0)."""
    i00, i01, i02, i11, i12, i22 = sym3_inverse(a00, a01, a02, a11, a12, a22)
    return (i00 * b[0] + i01 * b[1] + i02 * b[2],
            i01 * b[0] + i11 * b[1] + i12 * b[2],
            i02 * b[0] + i12 * b[1] + i22 * b[2])


@kernel
def _sum_mat_vec(iinv, a, b, v):
    """(I_a⁻¹ + I_b⁻¹) v, the sum taken entry by entry first."""
    out0 = (iinv[a, 0, 0] + iinv[b, 0, 0]) * v[0] + (iinv[a, 0, 1] + iinv[b, 0, 1]) * v[1] \
        + (iinv[a, 0, 2] + iinv[b, 0, 2]) * v[2]
    out1 = (iinv[a, 1, 0] + iinv[b, 1, 0]) * v[0] + (iinv[a, 1, 1] + iinv[b, 1, 1]) * v[1] \
        + (iinv[a, 1, 2] + iinv[b, 1, 2]) * v[2]
    out2 = (iinv[a, 2, 0] + iinv[b, 2, 0]) * v[0] + (iinv[a, 2, 1] + iinv[b, 2, 1]) * v[1] \
        + (iinv[a, 2, 2] + iinv[b, 2, 2]) * v[2]
    return (out0, out1, out2)


@kernel
def _point_column(iinv, a, r, e):
    """Column of [r]×ᵀ I⁻¹ [r]× for the unit vector e: (I⁻¹ (r × e)) × r."""
    return cross(mat3_vec(iinv, a, cross(r, e)), r)


@kernel
def _g3(x, w, j):
    return (x[w, j, 0], x[w, j, 1], x[w, j, 2])


@kernel
def _g4(x, w, j):
    return (x[w, j, 0], x[w, j, 1], x[w, j, 2], x[w, j, 3])


@kernel
def _turn(iinv, a, b, L, angvel):
    """Angular impulse L on the child b, -L on the parent a."""
    _add3(angvel, a, mat3_vec(iinv, a, L), -1.0)
    _add3(angvel, b, mat3_vec(iinv, b, L), 1.0)


# ---------------------------------------------------------- equality rows
@kernel
def _point_row(J, j, iinv, inv_mass, g, w, pos, vel, angvel, lin, act, bias_rate, mass_scale, impulse_scale,
               max_push):
    """Joint j's point row: P = -s_m K⁻¹ (Ċ + clamp(rate C)) - s_i λ."""
    a, b = J.parent[j], J.child[j]
    ra, rb = _g3(g.ra, w, j), _g3(g.rb, w, j)
    va, vb = load3(vel, a), load3(vel, b)
    wa, wb = load3(angvel, a), load3(angvel, b)
    rhs = sub(sub(add(vb, cross(wb, rb)), va), cross(wa, ra))
    if bias_rate != 0.0:
        sep = sub(sub(add(load3(pos, b), rb), load3(pos, a)), ra)
        rhs = add(rhs, _clamp_norm(scale(bias_rate, sep), max_push))
    ca0 = _point_column(iinv, a, ra, (1.0, 0.0, 0.0))
    ca1 = _point_column(iinv, a, ra, (0.0, 1.0, 0.0))
    ca2 = _point_column(iinv, a, ra, (0.0, 0.0, 1.0))
    cb0 = _point_column(iinv, b, rb, (1.0, 0.0, 0.0))
    cb1 = _point_column(iinv, b, rb, (0.0, 1.0, 0.0))
    cb2 = _point_column(iinv, b, rb, (0.0, 0.0, 1.0))
    m = inv_mass[a] + inv_mass[b]
    x = _sym3_solve(((0.0 + ca0[0]) + cb0[0]) + m, (0.0 + ca1[0]) + cb1[0], (0.0 + ca2[0]) + cb2[0],
                    ((0.0 + ca1[1]) + cb1[1]) + m, (0.0 + ca2[1]) + cb2[1], ((0.0 + ca2[2]) + cb2[2]) + m, rhs)
    lam = load3(lin, j)
    P = sub(scale(-mass_scale, x), scale(impulse_scale, lam))
    P = scale(act, P)
    lin[j, 0], lin[j, 1], lin[j, 2] = lam[0] + P[0], lam[1] + P[1], lam[2] + P[2]
    _add3(vel, a, scale(inv_mass[a], P), -1.0)
    _add3(vel, b, scale(inv_mass[b], P), 1.0)
    _add3(angvel, a, mat3_vec(iinv, a, add(cross(ra, P), (0.0, 0.0, 0.0))), -1.0)
    _add3(angvel, b, mat3_vec(iinv, b, add(cross(rb, P), (0.0, 0.0, 0.0))), 1.0)


@kernel
def _hinge_row(J, j, iinv, g, w, angvel, ang, act, bias_rate, mass_scale, impulse_scale, max_push):
    """Joint j's hinge lock: the 2x2 block of the parent frame's y, z axes
    (λ in slots 1, 2 of ``ang``)."""
    a, b = J.parent[j], J.child[j]
    fpw = _g4(g.fpw, w, j)
    by = rotate(fpw, (0.0, 1.0, 0.0))
    bz = rotate(fpw, (0.0, 0.0, 1.0))
    wrel = sub(load3(angvel, b), load3(angvel, a))
    c1, c2 = dot(wrel, by), dot(wrel, bz)
    if bias_rate != 0.0:
        ax_p = rotate(fpw, (1.0, 0.0, 0.0))
        ax_c = rotate(_g4(g.fcw, w, j), (1.0, 0.0, 0.0))
        err = _clamp_norm(scale(bias_rate, cross(ax_p, ax_c)), max_push)
        c1 = c1 + dot(err, by)
        c2 = c2 + dot(err, bz)
    isy, isz = _sum_mat_vec(iinv, a, b, by), _sum_mat_vec(iinv, a, b, bz)
    k11, k12, k22 = dot(by, isy), dot(by, isz), dot(bz, isz)
    det = k11 * k22 - k12 * k12
    inv_det = 1.0 / (det if det > 1e-30 else 1e-30)
    x1 = (k22 * c1 - k12 * c2) * inv_det
    x2 = (k11 * c2 - k12 * c1) * inv_det
    l1, l2 = ang[j, 1], ang[j, 2]
    d1 = (-mass_scale * x1 - impulse_scale * l1) * act
    d2 = (-mass_scale * x2 - impulse_scale * l2) * act
    ang[j, 1] = l1 + d1
    ang[j, 2] = l2 + d2
    _turn(iinv, a, b, add(scale(d1, by), scale(d2, bz)), angvel)


@kernel
def _fixed_row(J, j, iinv, g, w, angvel, ang, act, bias_rate, mass_scale, impulse_scale, max_push):
    """Joint j's fixed lock: the 3x3 block (I_a⁻¹ + I_b⁻¹) on ω_b - ω_a."""
    a, b = J.parent[j], J.child[j]
    rhs = sub(load3(angvel, b), load3(angvel, a))
    if bias_rate != 0.0:
        qd = quat_mul(_g4(g.fcw, w, j), quat_conj(_g4(g.fpw, w, j)))
        s = -1.0 if qd[0] < 0 else 1.0
        err = ((2.0 * qd[1]) * s, (2.0 * qd[2]) * s, (2.0 * qd[3]) * s)
        rhs = add(rhs, _clamp_norm(scale(bias_rate, err), max_push))
    x = _sym3_solve(iinv[a, 0, 0] + iinv[b, 0, 0], iinv[a, 0, 1] + iinv[b, 0, 1], iinv[a, 0, 2] + iinv[b, 0, 2],
                    iinv[a, 1, 1] + iinv[b, 1, 1], iinv[a, 1, 2] + iinv[b, 1, 2], iinv[a, 2, 2] + iinv[b, 2, 2],
                    rhs)
    lam = load3(ang, j)
    L = sub(scale(-mass_scale, x), scale(impulse_scale, lam))
    L = scale(act, L)
    ang[j, 0], ang[j, 1], ang[j, 2] = lam[0] + L[0], lam[1] + L[1], lam[2] + L[2]
    _turn(iinv, a, b, L, angvel)


@kernel
def _equality_world(J, joint, row_kind, iinv, inv_mass, g, w, pos, vel, angvel, lin, ang, broken, bias_rate,
                    mass_scale, impulse_scale, max_push, max_angular_push):
    """World w's equality rows in ``joint`` (kinds ``row_kind``: colour by
    colour its hinge locks, fixed locks, then point rows); a broken joint
    takes no impulse."""
    for k in range(joint.size):
        j = joint[k]
        act = 0.0 if broken[j] else 1.0
        kind = row_kind[k]
        if kind == HINGE_LOCK:
            _hinge_row(J, j, iinv, g, w, angvel, ang, act, bias_rate, mass_scale, impulse_scale, max_angular_push)
        elif kind == FIXED_LOCK:
            _fixed_row(J, j, iinv, g, w, angvel, ang, act, bias_rate, mass_scale, impulse_scale, max_angular_push)
        else:
            _point_row(J, j, iinv, inv_mass, g, w, pos, vel, angvel, lin, act, bias_rate, mass_scale,
                       impulse_scale, max_push)


@parallel_kernel
def solve_equality(J, joint, row_kind, iinv, inv_mass, g, pos, vel, angvel, lin, ang, broken, bias_rate,
                   mass_scale, impulse_scale, max_push, max_angular_push):
    """One Gauss-Seidel sweep of the equality rows of every world (``iinv``
    (W, N, 3, 3): world inverse inertias; softness terms scalars, the bias
    rate 0 for no position error)."""
    nw = vel.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _equality_world(J, joint, row_kind, iinv[w], inv_mass, g, w, pos[w], vel[w], angvel[w], lin[w], ang[w],
                            broken[w], bias_rate, mass_scale, impulse_scale, max_push, max_angular_push)
    else:
        for w in prange(nw):
            _equality_world(J, joint, row_kind, iinv[w], inv_mass, g, w, pos[w], vel[w], angvel[w], lin[w], ang[w],
                            broken[w], bias_rate, mass_scale, impulse_scale, max_push, max_angular_push)


# ------------------------------------------------------------- limit rows
@kernel
def _effective_mass(iinv, a, b, axis):
    """1 / (axis·I_a⁻¹ axis + axis·I_b⁻¹ axis), the denominator at least 1e-30."""
    k = dot(axis, mat3_vec(iinv, a, axis)) + dot(axis, mat3_vec(iinv, b, axis))
    return 1.0 / _maximum(k, 1e-30)


@kernel
def _one_sided(iinv, a, b, axis, C, m, lim, slot, j, broken, angvel, h, use_bias, bias_rate, mass_scale,
               impulse_scale, in_zone, zone_bias_rate, zone_mass_scale, zone_impulse_scale, margin, max_push):
    """A one-sided angular row about ``axis`` with error C (C >= 0 allowed)
    and effective mass m, its λ >= 0 in ``lim[j, slot]``: speculative bias
    C/h, rigid, while open; the given softness when violated, the zone's
    within ``margin`` of the bound (``in_zone``: the row's world and
    articulation take it this step)."""
    open_ = C > 0.0
    br, ms, isc = bias_rate, mass_scale, impulse_scale
    if use_bias and in_zone and not open_ and C > -margin:
        br, ms, isc = zone_bias_rate, zone_mass_scale, zone_impulse_scale
    if open_:
        bias = C / h
        gain = -m * 1.0
        isc = 0.0
    else:
        bias = _maximum(br * C, -max_push)
        gain = -m * ms
    wa, wb = load3(angvel, a), load3(angvel, b)
    lam = lim[j, slot]
    d = gain * (dot(sub(wb, wa), axis) + bias)
    if isc != 0.0:
        d = d - isc * lam
    if lam == 0.0 and not d > 0.0:
        return  # the row holds no impulse and takes none
    new = _maximum(lam + d, 0.0)
    if broken:
        new = new * 0.0
    d = new - lam
    lim[j, slot] = new
    _turn(iinv, a, b, scale(d, axis), angvel)


@kernel
def _limits_world(J, gs, twist_row, swing_row, lower, upper, iinv, g, w, angvel, lim, broken, h, use_bias,
                  bias_rate, mass_scale, impulse_scale, zone, zone_bias_rate, zone_mass_scale, zone_impulse_scale,
                  margin, max_push):
    """World w's Gauss-Seidel limit rows, joint ``gs[k]`` by joint (colour by
    colour): its lower and upper twist rows if ``twist_row[k]``, its swing
    row if ``swing_row[k]``. A twist bound that is infinite, or a twist the
    swing leaves undefined, gives an error of 1e9 (the row never acts)."""
    zoned = zone.size > 0
    for k in range(gs.size):
        j = gs[k]
        a, b = J.parent[j], J.child[j]
        in_zone = zoned and zone[k]
        if twist_row[k]:
            jt = _g3(g.jt, w, j)
            twist = g.twist[w, j]
            defined = g.twist_defined[w, j]
            lo, hi = lower[j], upper[j]
            c_lo = twist - lo if math.isfinite(lo) and defined else 1e9
            c_hi = hi - twist if math.isfinite(hi) and defined else 1e9
            m = _effective_mass(iinv, a, b, jt)
            _one_sided(iinv, a, b, jt, c_lo, m, lim, 0, j, broken[j], angvel, h, use_bias, bias_rate, mass_scale,
                       impulse_scale, in_zone, zone_bias_rate, zone_mass_scale, zone_impulse_scale, margin, max_push)
            _one_sided(iinv, a, b, neg(jt), c_hi, m, lim, 1, j, broken[j], angvel, h, use_bias, bias_rate,
                       mass_scale, impulse_scale, in_zone, zone_bias_rate, zone_mass_scale, zone_impulse_scale,
                       margin, max_push)
        if swing_row[k]:
            js = _g3(g.js, w, j)
            _one_sided(iinv, a, b, js, g.c_swing[w, j], _effective_mass(iinv, a, b, js), lim, 2, j, broken[j],
                       angvel, h, use_bias, bias_rate, mass_scale, impulse_scale, in_zone, zone_bias_rate,
                       zone_mass_scale, zone_impulse_scale, margin, max_push)


@parallel_kernel
def solve_limits(J, gs, twist_row, swing_row, lower, upper, iinv, g, angvel, lim, broken, h, use_bias, bias_rate,
                 mass_scale, impulse_scale, zone, zone_bias_rate, zone_mass_scale, zone_impulse_scale, margin,
                 max_push):
    """One sweep of the Gauss-Seidel limit rows of every world over a
    substep of h s (``lower``, ``upper``: each joint's twist bounds in rad;
    ``zone`` (W, rows) bool: the rows soft within ``margin`` rad of their
    bound, (W, 0) for none; ``max_push``: rad/s)."""
    nw = angvel.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _limits_world(J, gs, twist_row, swing_row, lower, upper, iinv[w], g, w, angvel[w], lim[w], broken[w], h,
                          use_bias, bias_rate, mass_scale, impulse_scale, zone[w], zone_bias_rate, zone_mass_scale,
                          zone_impulse_scale, margin, max_push)
    else:
        for w in prange(nw):
            _limits_world(J, gs, twist_row, swing_row, lower, upper, iinv[w], g, w, angvel[w], lim[w], broken[w], h,
                          use_bias, bias_rate, mass_scale, impulse_scale, zone[w], zone_bias_rate, zone_mass_scale,
                          zone_impulse_scale, margin, max_push)


# ------------------------------------------------- the thesis's projection
@kernel
def _project_world(J, order, inv_mass, pos, ori, broken):
    """Move each unbroken joint's two anchors together, joint by joint in
    ``order`` (colour by colour), the separation split by inverse mass: the
    parent moves by sep m_a⁻¹/(m_a⁻¹ + m_b⁻¹), the child back by the rest."""
    for k in range(order.size):
        j = order[k]
        a, b = J.parent[j], J.child[j]
        ra = rotate(load4(ori, a), load3(J.anchor_p, j))
        rb = rotate(load4(ori, b), load3(J.anchor_c, j))
        sep = sub(sub(add(load3(pos, b), rb), load3(pos, a)), ra)
        ma, mb = inv_mass[a], inv_mass[b]
        total = _maximum(ma + mb, 1e-30)
        act = 0.0 if broken[j] else 1.0
        fa, fb = ma / total, mb / total
        _add3(pos, a, (sep[0] * fa * act, sep[1] * fa * act, sep[2] * fa * act), 1.0)
        _add3(pos, b, (sep[0] * fb * act, sep[1] * fb * act, sep[2] * fb * act), -1.0)


@parallel_kernel
def project_positions(J, order, inv_mass, pos, ori, broken):
    """The thesis's position correction of every world."""
    nw = pos.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _project_world(J, order, inv_mass, pos[w], ori[w], broken[w])
    else:
        for w in prange(nw):
            _project_world(J, order, inv_mass, pos[w], ori[w], broken[w])


# --------------------------------------------------------------- breaking
@kernel
def _add_load_world(lin, ang, lim, lin_sum, ang_sum):
    for j in range(lin.shape[0]):
        for i in range(3):
            lin_sum[j, i] += lin[j, i]
        L = load3(ang, j)
        ang_sum[j] += math.sqrt(dot(L, L)) + ((abs(lim[j, 0]) + abs(lim[j, 1])) + abs(lim[j, 2]))


@parallel_kernel
def add_load(lin, ang, lim, lin_sum, ang_sum):
    """Sum a substep's joint impulses into the step's load: the point
    impulse (N·s) component-wise, |λ_lock| + Σ|λ_limit| (N·m·s) per joint."""
    nw = lin.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _add_load_world(lin[w], ang[w], lim[w], lin_sum[w], ang_sum[w])
    else:
        for w in prange(nw):
            _add_load_world(lin[w], ang[w], lim[w], lin_sum[w], ang_sum[w])


@kernel
def _snap_world(lin_sum, ang_sum, dt, break_force, break_torque, broken, lin, ang, lim, snapped):
    for j in range(broken.size):
        force = math.sqrt(dot(load3(lin_sum, j), load3(lin_sum, j))) / dt
        torque = ang_sum[j] / dt
        snap = (force > break_force[j] or torque > break_torque[j]) and not broken[j]
        snapped[j] = snap
        if snap:
            broken[j] = True
            for i in range(3):
                lin[j, i] = 0.0
                ang[j, i] = 0.0
                lim[j, i] = 0.0


@parallel_kernel
def snap(lin_sum, ang_sum, dt, break_force, break_torque, broken, lin, ang, lim, snapped):
    """Break the joints whose step load (the summed impulses over the step's
    dt s: |ΣP|/dt N, Σ(|λ_lock| + Σ|λ_limit|)/dt N·m) exceeds their
    ``break_force`` or ``break_torque``: mark them broken, zero their
    impulses, and flag them in ``snapped`` (W, J)."""
    nw = broken.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _snap_world(lin_sum[w], ang_sum[w], dt, break_force, break_torque, broken[w], lin[w], ang[w], lim[w],
                        snapped[w])
    else:
        for w in prange(nw):
            _snap_world(lin_sum[w], ang_sum[w], dt, break_force, break_torque, broken[w], lin[w], ang[w], lim[w],
                        snapped[w])
