"""Time integration over one substep of h seconds: kernels for one world and
their batched entry points.

The schemes (see :mod:`engine.integrators` for when each is used):

* semi-implicit Euler: v ← v + h a(x, v), then x ← x + h v with the new
  velocity, the orientation by the free rotation below;
* the free rotation of Dullweber, Reich & Webster (1997, "Symplectic
  splitting methods for rigid body molecular dynamics"): the kinetic energy
  T = Σ L_a² / (2 I_a) is split into its three principal-axis terms, each of
  whose flows is an exact rotation about that body axis by θ = h L_a / I_a
  (the body-frame angular momentum L_b turns the opposite way, which is how
  a fixed world vector looks from the turning body); composed in the Strang
  order 1, 2, 3, 2, 1 (half, half, full, half, half substeps) this is
  second order and time-reversible, conserves the world angular momentum
  to rounding, the energy to O(h²) without drift, and shows the intermediate
  axis's flip (Dzhanibekov's effect);
* the thesis's explicit Euler (its equations 4 and 5): x ← x + h v,
  q ← q + h/2 (ω ⊗ q), v ← v + h a, ω ← ω + h I⁻¹(τ - ω × Iω), all from
  the state at the start of the substep;
* classical Runge-Kutta 4 over (x, q, v, ω) with the same derivatives, the
  stage quaternions renormalised, k = (k1 + 2 k2 + 2 k3 + k4) h / 6.

Each ``*_batch`` entry point runs its world kernel for every world of
(W, N, ...) arrays: in a ``prange`` loop, one world per thread, or on the
calling thread below ``SERIAL_BELOW`` worlds. A world's arithmetic never
depends on the others, the batch size or the thread count.
"""

from __future__ import annotations

import math

import numpy as np

from .effects import accumulate, acceleration, velocity_effects
from .jit import SERIAL_BELOW, kernel, parallel_kernel, prange
from .vec import (add, add_scaled, cross, inv_inertia_apply, load3, load4, mul, quat_integrate, quat_mul,
                  quat_normalize, rotate, rotate_inv, scale, store3, store4, sub)


# ------------------------------------------------------------ free rotation
@kernel
def principal_turn(q, lb, inertia, axis, dt):
    """The exact flow over dt seconds of the kinetic term L_a² / (2 I_a) of
    body axis ``axis`` (0, 1, 2): the body turns about that axis by
    θ = dt L_a / I_a, q ← q ⊗ (cos θ/2, sin θ/2 e_a), and the body-frame
    angular momentum ``lb`` (kg·m²/s) turns by -θ about it (L_a unchanged).
    Returns (q, lb)."""
    if axis == 0:
        la, lj, lk, ia = lb[0], lb[1], lb[2], inertia[0]
        qa, qj, qk = q[1], q[2], q[3]
    elif axis == 1:
        la, lj, lk, ia = lb[1], lb[2], lb[0], inertia[1]
        qa, qj, qk = q[2], q[3], q[1]
    else:
        la, lj, lk, ia = lb[2], lb[0], lb[1], inertia[2]
        qa, qj, qk = q[3], q[1], q[2]
    theta = dt * la / ia
    # The half angle's cosine and sine for the quaternion, the full angle's
    # from them (cos θ = ch² - sh², sin θ = 2 sh ch): two calls instead of
    # four, and c² + s² = (ch² + sh²)², one to rounding.
    ch, sh = math.cos(0.5 * theta), math.sin(0.5 * theta)
    c, s = ch * ch - sh * sh, 2.0 * sh * ch
    lj2 = c * lj + s * lk
    lk2 = c * lk - s * lj
    # q ⊗ (ch, sh e_a), its zero terms left out.
    qw = q[0]
    ow = qw * ch - qa * sh
    oa = qw * sh + qa * ch
    oj = qj * ch + qk * sh
    ok = qk * ch - qj * sh
    if axis == 0:
        return (ow, oa, oj, ok), (la, lj2, lk2)
    if axis == 1:
        return (ow, ok, oa, oj), (lk2, la, lj2)
    return (ow, oj, ok, oa), (lj2, lk2, la)


@kernel
def gyroscopic(bodies, i, q, w):
    """I_w⁻¹ (ω × I_w ω) of body i (rad/s²): the explicit schemes' gyroscopic
    term, zero on static bodies."""
    iw = inv_inertia_apply(q, load3(bodies.gyro_inertia, i), w)
    return inv_inertia_apply(q, load3(bodies.inv_inertia, i), cross(w, iw))


# ------------------------------------------------------------ one world
@kernel
def semi_implicit_velocities(bodies, gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken,
                             cforce, ctorque, motor, force, torque, h):
    """v ← v + h a, ω ← ω + h α of one world from its force effects (in place);
    ``force``, ``torque`` (N, 3) are scratch."""
    accumulate(gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken, cforce, ctorque, motor,
               force, torque)
    for i in range(x.shape[0]):
        lin, ang = acceleration(bodies, i, load4(q, i), force, torque)
        store3(v, i, add_scaled(load3(v, i), h, lin))
        store3(w, i, add_scaled(load3(w, i), h, ang))


#: The splitting's turns in the Strang order 1, 2, 3, 2, 1: (body axis, fraction of h).
STRANG = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


@kernel
def free_positions(bodies, x, q, v, w, lb, h):
    """x ← x + h v and the torque-free rotation (the splitting) of every body
    of one world, in place; ``lb`` (N, 3) is scratch for the body-frame
    angular momenta L_b = I ω_b (kg·m²/s).

    Each turn is swept over all the bodies before the next: one body's five
    turns are a chain of dependent divisions, sines and cosines, and sweeping
    lets the chains of different bodies overlap in the processor."""
    n = x.shape[0]
    for i in range(n):
        store3(x, i, add_scaled(load3(x, i), h, load3(v, i)))
        store3(lb, i, mul(load3(bodies.inertia, i), rotate_inv(load4(q, i), load3(w, i))))
    for axis, frac in STRANG:
        dt = frac * h
        for i in range(n):
            qi, li = principal_turn(load4(q, i), load3(lb, i), load3(bodies.inertia, i), axis, dt)
            store4(q, i, qi)
            store3(lb, i, li)
    for i in range(n):
        qi, li, inertia = quat_normalize(load4(q, i)), load3(lb, i), load3(bodies.inertia, i)
        store4(q, i, qi)
        store3(w, i, rotate(qi, (li[0] / inertia[0], li[1] / inertia[1], li[2] / inertia[2])))


@kernel
def explicit_euler_world(bodies, gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken,
                         cforce, ctorque, motor, force, torque, h):
    """The thesis's explicit Euler step of one world (in place): every update
    from the state at the start of the substep."""
    accumulate(gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken, cforce, ctorque, motor,
               force, torque)
    for i in range(x.shape[0]):
        qi, vi, wi = load4(q, i), load3(v, i), load3(w, i)
        lin, ang = acceleration(bodies, i, qi, force, torque)
        gyro = gyroscopic(bodies, i, qi, wi)
        store3(x, i, add_scaled(load3(x, i), h, vi))
        store4(q, i, quat_integrate(qi, wi, h))
        store3(v, i, add_scaled(vi, h, lin))
        store3(w, i, add_scaled(wi, h, sub(ang, gyro)))


@kernel
def derivative(bodies, i, q, v, w, force, torque):
    """(ẋ, q̇, v̇, ω̇) of body i at (q, v, w) under the accumulated ``force``
    and ``torque``: v, ½ (ω ⊗ q), a, α - I⁻¹(ω × Iω)."""
    lin, ang = acceleration(bodies, i, q, force, torque)
    wq = quat_mul((0.0, w[0], w[1], w[2]), q)
    dq = (0.5 * wq[0], 0.5 * wq[1], 0.5 * wq[2], 0.5 * wq[3])
    return v, dq, lin, sub(ang, gyroscopic(bodies, i, q, w))


@kernel
def add_scaled4(a, s, b):
    """a + s b of quaternions."""
    return (a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2], a[3] + s * b[3])


@kernel
def runge_kutta4_world(bodies, gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken,
                       cforce, ctorque, motor, force, torque, xs, qs, vs, ws, sx, sq, sv, sw, h):
    """Classical RK4 of one world over h (in place). (xs, qs, vs, ws): the
    stage state, (sx, sq, sv, sw): the running sum k1 + 2 k2 + 2 k3 + k4,
    both (N, 3) and (N, 4) scratch like ``force`` and ``torque``."""
    n = x.shape[0]
    # k1 at the state; the sum starts as k1.
    accumulate(gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken, cforce, ctorque, motor,
               force, torque)
    for i in range(n):
        dx, dq, dv, dw = derivative(bodies, i, load4(q, i), load3(v, i), load3(w, i), force, torque)
        store3(sx, i, dx)
        store4(sq, i, dq)
        store3(sv, i, dv)
        store3(sw, i, dw)
        _stage(x, q, v, w, xs, qs, vs, ws, i, 0.5 * h, dx, dq, dv, dw)
    # k2 and k3 (weight 2, each giving the next stage at h/2 and h), k4 (weight 1).
    for stage in range(1, 4):
        accumulate(gravitation, springs, motors, xs, qs, vs, ws, spring_broken, joint_broken, cforce, ctorque,
                   motor, force, torque)
        for i in range(n):
            dx, dq, dv, dw = derivative(bodies, i, load4(qs, i), load3(vs, i), load3(ws, i), force, torque)
            if stage < 3:
                store3(sx, i, add_scaled(load3(sx, i), 2.0, dx))
                store4(sq, i, add_scaled4(load4(sq, i), 2.0, dq))
                store3(sv, i, add_scaled(load3(sv, i), 2.0, dv))
                store3(sw, i, add_scaled(load3(sw, i), 2.0, dw))
                _stage(x, q, v, w, xs, qs, vs, ws, i, (0.5 if stage == 1 else 1.0) * h, dx, dq, dv, dw)
            else:
                store3(sx, i, add(load3(sx, i), dx))
                store4(sq, i, add_scaled4(load4(sq, i), 1.0, dq))
                store3(sv, i, add(load3(sv, i), dv))
                store3(sw, i, add(load3(sw, i), dw))
    s = h / 6.0
    for i in range(n):
        store3(x, i, add(load3(x, i), scale(s, load3(sx, i))))
        store4(q, i, quat_normalize(add_scaled4(load4(q, i), s, load4(sq, i))))
        store3(v, i, add(load3(v, i), scale(s, load3(sv, i))))
        store3(w, i, add(load3(w, i), scale(s, load3(sw, i))))


@kernel
def _stage(x, q, v, w, xs, qs, vs, ws, i, dt, dx, dq, dv, dw):
    """Body i of the stage state: the state plus dt times the derivative k."""
    store3(xs, i, add_scaled(load3(x, i), dt, dx))
    store4(qs, i, quat_normalize(add_scaled4(load4(q, i), dt, dq)))
    store3(vs, i, add_scaled(load3(v, i), dt, dv))
    store3(ws, i, add_scaled(load3(w, i), dt, dw))


# ------------------------------------------------------ batched entry points
# Arrays (W, N, ...) of the state; the control's cforce, ctorque (W, N, 3) or
# (W, 0, 3) and motor (W, A) or (W, 0); joint_broken (W, J) or (W, 0).

@parallel_kernel
def integrate_velocities_batch(bodies, gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken,
                               cforce, ctorque, motor, h):
    """Semi-implicit velocity update of every world."""
    nw, n = x.shape[0], x.shape[1]
    force, torque = np.empty((nw, n, 3)), np.empty((nw, n, 3))
    if nw < SERIAL_BELOW:
        for k in range(nw):
            semi_implicit_velocities(bodies, gravitation, springs, motors, x[k], q[k], v[k], w[k],
                                     spring_broken[k], joint_broken[k], cforce[k], ctorque[k], motor[k],
                                     force[k], torque[k], h)
    else:
        for k in prange(nw):
            semi_implicit_velocities(bodies, gravitation, springs, motors, x[k], q[k], v[k], w[k],
                                     spring_broken[k], joint_broken[k], cforce[k], ctorque[k], motor[k],
                                     force[k], torque[k], h)


@parallel_kernel
def velocity_effects_batch(bodies, springs, damping, x, q, v, w, spring_broken, h):
    """The implicit velocity effects (stiff springs, damping) of every world."""
    nw = x.shape[0]
    if nw < SERIAL_BELOW:
        for k in range(nw):
            velocity_effects(bodies, springs, damping, x[k], q[k], v[k], w[k], spring_broken[k], h)
    else:
        for k in prange(nw):
            velocity_effects(bodies, springs, damping, x[k], q[k], v[k], w[k], spring_broken[k], h)


@parallel_kernel
def integrate_positions_batch(bodies, x, q, v, w, h):
    """Positions and free rotation of every world."""
    nw = x.shape[0]
    lb = np.empty((nw, x.shape[1], 3))
    if nw < SERIAL_BELOW:
        for k in range(nw):
            free_positions(bodies, x[k], q[k], v[k], w[k], lb[k], h)
    else:
        for k in prange(nw):
            free_positions(bodies, x[k], q[k], v[k], w[k], lb[k], h)


@parallel_kernel
def explicit_euler_batch(bodies, gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken,
                         cforce, ctorque, motor, h):
    """The thesis's explicit Euler step of every world."""
    nw, n = x.shape[0], x.shape[1]
    force, torque = np.empty((nw, n, 3)), np.empty((nw, n, 3))
    if nw < SERIAL_BELOW:
        for k in range(nw):
            explicit_euler_world(bodies, gravitation, springs, motors, x[k], q[k], v[k], w[k],
                                 spring_broken[k], joint_broken[k], cforce[k], ctorque[k], motor[k],
                                 force[k], torque[k], h)
    else:
        for k in prange(nw):
            explicit_euler_world(bodies, gravitation, springs, motors, x[k], q[k], v[k], w[k],
                                 spring_broken[k], joint_broken[k], cforce[k], ctorque[k], motor[k],
                                 force[k], torque[k], h)


@parallel_kernel
def runge_kutta4_batch(bodies, gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken,
                       cforce, ctorque, motor, h):
    """Classical RK4 of every world."""
    nw, n = x.shape[0], x.shape[1]
    force, torque = np.empty((nw, n, 3)), np.empty((nw, n, 3))
    xs, vs, ws = np.empty((nw, n, 3)), np.empty((nw, n, 3)), np.empty((nw, n, 3))
    sx, sv, sw = np.empty((nw, n, 3)), np.empty((nw, n, 3)), np.empty((nw, n, 3))
    qs, sq = np.empty((nw, n, 4)), np.empty((nw, n, 4))
    if nw < SERIAL_BELOW:
        for k in range(nw):
            runge_kutta4_world(bodies, gravitation, springs, motors, x[k], q[k], v[k], w[k],
                               spring_broken[k], joint_broken[k], cforce[k], ctorque[k], motor[k],
                               force[k], torque[k], xs[k], qs[k], vs[k], ws[k], sx[k], sq[k], sv[k], sw[k], h)
    else:
        for k in prange(nw):
            runge_kutta4_world(bodies, gravitation, springs, motors, x[k], q[k], v[k], w[k],
                               spring_broken[k], joint_broken[k], cforce[k], ctorque[k], motor[k],
                               force[k], torque[k], xs[k], qs[k], vs[k], ws[k], sx[k], sq[k], sv[k], sw[k], h)
