"""Joint geometry of one world: frames, swing-twist angles and limit rows.

Each joint has a frame in its parent and in its child whose x axis is the
hinge or twist axis. In the world: f_p = q_p ⊗ frame_p, f_c = q_c ⊗ frame_c,
anchors' lever arms r_a = R(q_p) anchor_p, r_b = R(q_c) anchor_c. The
relative rotation q_rel = conj(f_p) ⊗ f_c is split as q_swing ⊗ q_twist with
the twist about x (the swing-twist decomposition of Jolt's
SwingTwistConstraint): the hinge angle is the twist angle; a ball joint's
swing is φ·(d_y, d_z), limited by an elliptic cone of half-angles
(cone_y, cone_z).

Limit rows (angular Jacobians, Ċ = J·(ω_c - ω_p), world vectors). Twist:
with a, c the parent's and child's x axes and φ the swing angle,
θ̇ = ω·(a + c)/(1 + cos φ) = ω·mid / cos(φ/2) exactly (the swing part of ω
has no component along a + c). Swing: C = φ_max (1 - f(s)) with
f(s) = ‖(s_y/c_y, s_z/c_z)‖ for the swing vector s = φ d, so the cone's
boundary is f = 1 and C ≈ φ_max - φ near it; with n = (0, d), m = a × n
(parent frame), ṡ = (ω·n) d + (φ/sin φ)(ω·m) d⊥ + φ θ̇ d⊥. Beyond a swing of
``TWIST_LIMIT_MAX_SWING`` the twist row is dropped (``twist_defined``
false; its axis, kept for a stored impulse and the tree's factorisation, is
then c) and |mid| and φ/sin φ in the swing row are held at their values
there, so the swing row stays bounded and continuous: both grow without
bound towards a swing of π, where the twist is undefined.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .jit import SERIAL_BELOW, kernel, parallel_kernel, prange
from .contacts import world_inv_inertia
from .vec import (add, column, cross, dot, load3, load4, mat3_vec, quat_conj, quat_mul, quat_to_matrix, rotate,
                  scale)

HINGE, BALL, FIXED = 0, 1, 2
#: Beyond this swing (rad) a ball joint's twist limit row is dropped: the twist
#: rate θ̇ = ω·(a + c)/(1 + cos φ) grows as 1/cos(φ/2) towards a swing of π.
TWIST_LIMIT_MAX_SWING = 5.0 * math.pi / 6.0
COS_HALF_TWIST_SWING = math.cos(TWIST_LIMIT_MAX_SWING / 2.0)


class JointArrays(NamedTuple):
    """The joints of a model, read-only (J joints)."""

    kind: np.ndarray  # (J,) int64: HINGE, BALL or FIXED
    parent: np.ndarray  # (J,) int64 body
    child: np.ndarray  # (J,) int64 body
    frame_p: np.ndarray  # (J, 4) joint frame in the parent body
    frame_c: np.ndarray  # (J, 4) joint frame in the child body
    anchor_p: np.ndarray  # (J, 3) m, anchor in the parent body
    anchor_c: np.ndarray  # (J, 3) m, anchor in the child body
    cone: np.ndarray  # (J, 2) rad, swing cone half-angles about y and z


class JointGeometry(NamedTuple):
    """Every joint's geometry at one set of positions (W worlds, J joints)."""

    fpw: np.ndarray  # (W, J, 4) parent joint frame in the world
    fcw: np.ndarray  # (W, J, 4) child joint frame in the world
    ra: np.ndarray  # (W, J, 3) m, parent anchor's lever arm
    rb: np.ndarray  # (W, J, 3) m, child anchor's lever arm
    twist: np.ndarray  # (W, J) rad, in [-π, π]
    phi: np.ndarray  # (W, J) rad, swing angle in [0, π]
    dy: np.ndarray  # (W, J) swing direction
    dz: np.ndarray  # (W, J)
    jt: np.ndarray  # (W, J, 3) twist limit row
    js: np.ndarray  # (W, J, 3) swing limit row
    c_swing: np.ndarray  # (W, J) rad, swing limit error (negative beyond the cone)
    twist_defined: np.ndarray  # (W, J) bool


@kernel
def swing_twist(q):
    """(twist, φ, d_y, d_z) of a relative rotation q = q_swing ⊗ q_twist with
    q_twist = (w, x, 0, 0)/‖·‖; the swing quaternion (s_w, 0, s_y, s_z) is
    kept in the w ≥ 0 hemisphere, so φ = 2 atan2(|s|, s_w) lies in [0, π]."""
    w, x, y, z = q
    tn = math.sqrt(w * w + x * x)
    if tn < 1e-9:
        tw, tx = 1.0, 0.0
    else:
        tw, tx = w / tn, x / tn
    sw = w * tw + x * tx
    sy = y * tw - z * tx
    sz = z * tw + y * tx
    twist = 2.0 * math.atan2(tx, tw)
    if twist > math.pi:
        twist -= 2 * math.pi
    elif twist < -math.pi:
        twist += 2 * math.pi
    if sw < 0:
        sw, sy, sz = -sw, -sy, -sz
    s = math.sqrt(sy * sy + sz * sz)
    phi = 2.0 * math.atan2(s, sw)
    if s > 1e-12:
        return twist, phi, sy / s, sz / s
    return twist, phi, 1.0, 0.0


@kernel
def _geometry_world(J, x, q, out, w):
    """``JointGeometry`` of world w's joints at positions x (N, 3) and
    orientations q (N, 4)."""
    for j in range(J.kind.size):
        qa, qb = load4(q, J.parent[j]), load4(q, J.child[j])
        fpw = quat_mul(qa, load4(J.frame_p, j))
        fcw = quat_mul(qb, load4(J.frame_c, j))
        ra = rotate(qa, load3(J.anchor_p, j))
        rb = rotate(qb, load3(J.anchor_c, j))
        for k in range(4):
            out.fpw[w, j, k] = fpw[k]
            out.fcw[w, j, k] = fcw[k]
        for k in range(3):
            out.ra[w, j, k] = ra[k]
            out.rb[w, j, k] = rb[k]
        twist, phi, dy, dz = swing_twist(quat_mul(quat_conj(fpw), fcw))
        out.twist[w, j], out.phi[w, j], out.dy[w, j], out.dz[w, j] = twist, phi, dy, dz
        # Limit rows.
        ax_p = rotate(fpw, (1.0, 0.0, 0.0))
        ax_c = rotate(fcw, (1.0, 0.0, 0.0))
        ball = J.kind[j] == BALL
        defined = (not ball) or phi <= TWIST_LIMIT_MAX_SWING
        mid = add(ax_p, ax_c)
        mid2 = dot(mid, mid)  # |a + c|² = 4 cos²(φ/2)
        d = max(mid2, 1e-24)
        mid = ((mid[0] / d) * 2.0, (mid[1] / d) * 2.0, (mid[2] / d) * 2.0)  # |mid| = 1/cos(φ/2)
        if not defined:
            mid = scale(0.5 * math.sqrt(mid2) / COS_HALF_TWIST_SWING, mid)
        jt = (mid if defined else ax_c) if ball else ax_p
        cy, cz = J.cone[j, 0], J.cone[j, 1]
        gy, gz = dy / (cy * cy), dz / (cz * cz)
        f_dir = math.sqrt(gy * dy + gz * dz)  # f(d) = 1/φ_max
        phi_max = 1.0 / f_dir
        gy, gz = gy * phi_max, gz * phi_max  # ∇f at s (homogeneous of degree 0)
        g_n = gy * dy + gz * dz
        g_m = -gy * dz + gz * dy
        n = rotate(fpw, (0.0, dy, dz))
        m = rotate(fpw, (0.0, -dz, dy))
        phi_r = min(phi, TWIST_LIMIT_MAX_SWING)
        sin_phi = math.sin(phi_r)
        ratio = phi_r / sin_phi if sin_phi > 1e-6 else 1.0
        s = add(add(scale(g_n, n), scale(g_m * ratio, m)), scale(g_m * phi_r, mid))
        js = scale(-phi_max, s)
        for k in range(3):
            out.jt[w, j, k] = jt[k]
            out.js[w, j, k] = js[k]
        out.c_swing[w, j] = phi_max * (1.0 - phi * f_dir)
        out.twist_defined[w, j] = defined


@parallel_kernel
def joint_geometry(J, pos, ori, out):
    """``JointGeometry`` of every world (``out``: arrays with a leading world axis)."""
    nw = pos.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _geometry_world(J, pos[w], ori[w], out, w)
    else:
        for w in prange(nw):
            _geometry_world(J, pos[w], ori[w], out, w)


def empty_geometry(num_worlds, num_joints) -> JointGeometry:
    W, n = num_worlds, num_joints
    return JointGeometry(np.empty((W, n, 4)), np.empty((W, n, 4)), np.empty((W, n, 3)), np.empty((W, n, 3)),
                         np.empty((W, n)), np.empty((W, n)), np.empty((W, n)), np.empty((W, n)),
                         np.empty((W, n, 3)), np.empty((W, n, 3)), np.empty((W, n)),
                         np.empty((W, n), dtype=np.bool_))


# ------------------------------------------------------------- warm start
@kernel
def _add3(a, i, v, sign):
    a[i, 0] += sign * v[0]
    a[i, 1] += sign * v[1]
    a[i, 2] += sign * v[2]


@kernel
def _warm_start_world(J, order, iinv, inv_mass, g, w, lin, ang, lim, vel, angvel):
    """Apply each joint's stored impulses of world w again: the point impulse
    P at the anchors, the lock rows' angular impulse (a hinge's in its parent
    frame's y, z axes) and the limit rows' (λ_lower - λ_upper) J_twist +
    λ_swing J_swing; joints in ``order`` (colour by colour)."""
    for k in range(order.size):
        j = order[k]
        a, b = J.parent[j], J.child[j]
        P = load3(lin, j)
        L = load3(ang, j)
        if J.kind[j] == HINGE:
            f = (g.fpw[w, j, 0], g.fpw[w, j, 1], g.fpw[w, j, 2], g.fpw[w, j, 3])
            by, bz = rotate(f, (0.0, 1.0, 0.0)), rotate(f, (0.0, 0.0, 1.0))
            L = add(scale(L[1], by), scale(L[2], bz))
        l0, l1, l2 = lim[j, 0], lim[j, 1], lim[j, 2]
        if l0 != 0.0 or l1 != 0.0 or l2 != 0.0:
            jt = (g.jt[w, j, 0], g.jt[w, j, 1], g.jt[w, j, 2])
            js = (g.js[w, j, 0], g.js[w, j, 1], g.js[w, j, 2])
            L = add(L, add(scale(l0 - l1, jt), scale(l2, js)))
        ra = (g.ra[w, j, 0], g.ra[w, j, 1], g.ra[w, j, 2])
        rb = (g.rb[w, j, 0], g.rb[w, j, 1], g.rb[w, j, 2])
        ang_a = mat3_vec(iinv, a, add(cross(ra, P), L))
        ang_b = mat3_vec(iinv, b, add(cross(rb, P), L))
        _add3(vel, a, scale(inv_mass[a], P), -1.0)
        _add3(angvel, a, ang_a, -1.0)
        _add3(vel, b, scale(inv_mass[b], P), 1.0)
        _add3(angvel, b, ang_b, 1.0)


@parallel_kernel
def warm_start(J, order, iinv, inv_mass, g, lin, ang, lim, vel, angvel):
    """The joints' warm start of every world (``iinv`` (W, N, 3, 3): the
    step's world inverse inertias)."""
    nw = vel.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _warm_start_world(J, order, iinv[w], inv_mass, g, w, lin[w], ang[w], lim[w], vel[w], angvel[w])
    else:
        for w in prange(nw):
            _warm_start_world(J, order, iinv[w], inv_mass, g, w, lin[w], ang[w], lim[w], vel[w], angvel[w])


# ---------------------------------------------------------------- passive
@kernel
def _passive_world(J, order, iinv, g, w, stiffness, damping, rest, broken, angvel, h):
    """Muscle tone of world w: an implicit spring-damper on each joint axis
    towards the rest angles (k N·m/rad, c N·m·s/rad), backward Euler, so
    stable for any stiffness: with the axis's inverse inertia m⁻¹ = a·I_a⁻¹a
    + a·I_b⁻¹a, P = -h (k C + (c + h k) Ċ) / (1 + h (c + h k) m⁻¹). A hinge
    acts about its axis, a ball joint about its frame's three axes (twist,
    swing y, swing z); joints in ``order`` (colour by colour)."""
    for k in range(order.size):
        j = order[k]
        kind = J.kind[j]
        if kind == FIXED or broken[j]:
            continue
        a, b = J.parent[j], J.child[j]
        f = (g.fpw[w, j, 0], g.fpw[w, j, 1], g.fpw[w, j, 2], g.fpw[w, j, 3])
        twist, phi = g.twist[w, j], g.phi[w, j]
        naxes = 1 if kind == HINGE else 3
        kj, cj = stiffness[j], damping[j]
        ck = cj + h * kj
        for n in range(naxes):
            if n == 0:
                axis, angle = rotate(f, (1.0, 0.0, 0.0)), twist
            elif n == 1:
                axis, angle = rotate(f, (0.0, 1.0, 0.0)), phi * g.dy[w, j]
            else:
                axis, angle = rotate(f, (0.0, 0.0, 1.0)), phi * g.dz[w, j]
            err = angle - rest[j, n]
            if abs(err) > math.pi:
                # The short way round to the rest angle (angles lie in [-π, π]).
                err = err - 2.0 * math.pi * np.rint(err / (2.0 * math.pi))
            inv_m = dot(axis, mat3_vec(iinv, a, axis)) + dot(axis, mat3_vec(iinv, b, axis))
            den = 1.0 + (h * ck) * inv_m
            wa, wb = load3(angvel, a), load3(angvel, b)
            rate = dot((wb[0] - wa[0], wb[1] - wa[1], wb[2] - wa[2]), axis)
            p = -h * (kj * err + ck * rate) / den
            impulse = scale(p, axis)
            _add3(angvel, a, mat3_vec(iinv, a, impulse), -1.0)
            _add3(angvel, b, mat3_vec(iinv, b, impulse), 1.0)


@parallel_kernel
def passive(J, order, iinv, g, stiffness, damping, rest, broken, angvel, h):
    """The passive joint springs and dampers of every world over a substep of h s."""
    nw = angvel.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _passive_world(J, order, iinv[w], g, w, stiffness, damping, rest, broken[w], angvel[w], h)
    else:
        for w in prange(nw):
            _passive_world(J, order, iinv[w], g, w, stiffness, damping, rest, broken[w], angvel[w], h)


@kernel
def _inertia_world(ori, inv_inertia, rot, iinv):
    """Every body's rotation matrix rot (N, 3, 3) and world inverse inertia
    iinv = R diag(I_b⁻¹) Rᵀ (N, 3, 3), 1/(kg m²), of one world."""
    for i in range(ori.shape[0]):
        q = load4(ori, i)
        c = quat_to_matrix(q)
        for col in range(3):
            v = column(c, col)
            for r in range(3):
                rot[i, r, col] = v[r]
        world_inv_inertia(q, (inv_inertia[i, 0], inv_inertia[i, 1], inv_inertia[i, 2]), iinv, i)


@parallel_kernel
def inertia(ori, inv_inertia, rot, iinv):
    """``_inertia_world`` of every world: ori (W, N, 4), inv_inertia (N, 3) principal inverse moments."""
    nw = ori.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            _inertia_world(ori[w], inv_inertia, rot[w], iinv[w])
    else:
        for w in prange(nw):
            _inertia_world(ori[w], inv_inertia, rot[w], iinv[w])
