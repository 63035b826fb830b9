"""Time integration of rigid bodies over one substep of h seconds.

Three schemes, chosen by ``Settings.integrator``:

* ``"euler"``: the thesis's explicit Euler (its equations 4 and 5 as written):
  x ← x + h v, then v ← v + h F/m, all from the state at the start of the
  substep; rotation likewise with the explicit gyroscopic torque -ω × Iω.
  First order, and it gains energy on every orbit and oscillation.
* ``"symplectic"`` (default): semi-implicit Euler, v ← v + h F/m, then
  x ← x + h v with the new velocity. Symplectic, so energy errors stay bounded.
  The free rotation is the splitting of Dullweber, Reich & Webster (1997,
  "Symplectic splitting methods for rigid body molecular dynamics"): the body
  turns about its three principal axes in turn (Strang order 1, 2, 3, 2, 1),
  each an exact rotation, so |L| is conserved exactly and energy to O(h²) with
  no drift, and the gyroscopic effect (Dzhanibekov's flip) comes out right.
* ``"rk4"``: classical Runge-Kutta on the free motion under the force
  effects (4 force evaluations per substep); constraint impulses are added
  after it as velocity changes that also move the positions (h Δv).

Angular velocities are world-frame; inertia is diagonal in the body frame.
"""

from __future__ import annotations

import numpy as np

from .effects import Accumulator, BodyView
from .math3d import cross, quat_integrate, quat_mul, quat_normalize, quat_rotate, quat_rotate_inv

# Strang splitting of the free rigid body: (axis, fraction of h).
_SPLIT = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


def inv_inertia_apply(model, q, v):
    """World-frame I⁻¹ v for every body: R (I_b⁻¹ ⊙ (Rᵀ v)), arrays (W, N, ...)."""
    return quat_rotate(q, model.inv_inertia * quat_rotate_inv(q, v))


def inertia_apply(model, q, v):
    """World-frame I v for every body (static bodies: 0)."""
    inertia = np.where(model.dynamic[:, None], model.inertia_safe, 0.0)
    return quat_rotate(q, inertia * quat_rotate_inv(q, v))


def accumulate(model, view, control):
    """Sum every force effect at ``view``; returns (linear acc, angular acc)."""
    acc = Accumulator.zeros(view.position.shape)
    for effect in model.force_hooks:
        effect.forces(model, view, acc)
    if control is not None:
        if control.force is not None:
            acc.force += control.force
        if control.torque is not None:
            acc.torque += control.torque
        if control.motor is not None and model.joints is not None:
            model.joints.motor_torques(model, view, control.motor, acc)
    lin = acc.accel + acc.force * model.inv_mass[:, None]
    ang = inv_inertia_apply(model, view.orientation, acc.torque)
    return lin, ang


def rotate_free(model, q, omega, h):
    """Torque-free rotation over h by the principal-axis splitting.

    Returns the new orientation and world angular velocity; the body-frame
    angular momentum L_b = I ω_b is turned opposite to each partial rotation,
    which is exactly how a fixed world vector looks from the turning body.
    """
    inertia = model.inertia_safe
    lb = inertia * quat_rotate_inv(q, omega)
    for axis, frac in _SPLIT:
        j, k = (axis + 1) % 3, (axis + 2) % 3
        theta = (frac * h) * lb[..., axis] / inertia[:, axis]
        c, s = np.cos(theta), np.sin(theta)
        lj, lk = lb[..., j].copy(), lb[..., k]
        lb[..., j] = c * lj + s * lk
        lb[..., k] = c * lk - s * lj
        q = _turn_about_axis(q, axis, np.cos(0.5 * theta), np.sin(0.5 * theta))
    q = quat_normalize(q)
    return q, quat_rotate(q, lb / inertia)


def _turn_about_axis(q, axis, c, s):
    """q ⊗ (c, s e_axis): the Hamilton product with a rotation about a body
    axis, its zero terms left out (the same sums as ``quat_mul``)."""
    j, k = 1 + (axis + 1) % 3, 1 + (axis + 2) % 3
    a = 1 + axis
    qw, qa, qj, qk = q[..., 0], q[..., a], q[..., j], q[..., k]
    out = np.empty(q.shape)
    out[..., 0] = qw * c - qa * s
    out[..., a] = qw * s + qa * c
    out[..., j] = qj * c + qk * s
    out[..., k] = qk * c - qj * s
    return out


def integrate_velocities(model, state, control, h):
    """Semi-implicit velocity update v += h a(x, v), ω += h α."""
    view = BodyView.of(state)
    lin, ang = accumulate(model, view, control)
    state.velocity += h * lin
    state.angular_velocity += h * ang


def integrate_positions(model, state, h):
    """x += h v; free rotation with the gyroscopic term (splitting)."""
    state.position += h * state.velocity
    q, w = rotate_free(model, state.orientation, state.angular_velocity, h)
    state.orientation[...] = q
    state.angular_velocity[...] = w


def explicit_euler(model, state, control, h):
    """Thesis equations 4 and 5: positions from the old velocities, velocities
    from the old forces; ω̇ = I⁻¹(τ - ω × Iω) explicitly."""
    view = BodyView.of(state, copy=True)
    lin, ang = accumulate(model, view, control)
    w = view.angular_velocity
    gyro = inv_inertia_apply(model, view.orientation, cross(w, inertia_apply(model, view.orientation, w)))
    state.position += h * view.velocity
    state.orientation[...] = quat_integrate(view.orientation, w, h)
    state.velocity += h * lin
    state.angular_velocity += h * (ang - gyro)


def _derivative(model, view, control):
    lin, ang = accumulate(model, view, control)
    w = view.angular_velocity
    gyro = inv_inertia_apply(model, view.orientation, cross(w, inertia_apply(model, view.orientation, w)))
    zeros = np.zeros(w.shape[:-1] + (1,))
    qdot = 0.5 * quat_mul(np.concatenate((zeros, w), axis=-1), view.orientation)
    return view.velocity, qdot, lin, ang - gyro


def runge_kutta4(model, state, control, h):
    """Classical RK4 over (x, q, v, ω) under the force effects; the quaternion
    is renormalised at the end. Returns nothing; updates the state."""
    x0, q0, v0, w0 = state.position, state.orientation, state.velocity, state.angular_velocity
    base = BodyView.of(state)
    k1 = _derivative(model, base, control)
    stages = [k1]
    for frac in (0.5, 0.5, 1.0):
        k = stages[-1]
        view = BodyView(x0 + frac * h * k[0], quat_normalize(q0 + frac * h * k[1]),
                        v0 + frac * h * k[2], w0 + frac * h * k[3], base.spring_broken, base.joint_broken)
        stages.append(_derivative(model, view, control))
    k1, k2, k3, k4 = stages
    comb = [(a + 2 * b + 2 * c + d) * (h / 6.0) for a, b, c, d in zip(k1, k2, k3, k4)]
    state.position += comb[0]
    state.orientation[...] = quat_normalize(q0 + comb[1])
    state.velocity += comb[2]
    state.angular_velocity += comb[3]
