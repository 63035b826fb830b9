"""The force effects of one world as kernels: accumulation and implicit velocity effects.

Each effect the scene declares is compiled at model build into a named tuple
of read-only arrays (``compile_effects``); an effect the scene lacks is the
same tuple with empty arrays, so its loops run zero times and the kernels
are compiled once for every scene. ``model.effects`` keeps the Python
objects (their parameters, potentials and breaking at the end of a step).

Force accumulation (``accumulate``), into per-body sums of force (N) and
torque (N·m), in this order:

* universal gravitation (thesis equation 6), softened:
  F_ij = G m_i m_j d / (|d|² + ε²)^(3/2), d = x_j - x_i, +F on i, -F on j;
* Hooke springs between body-local anchors (thesis equations 9-12), the
  explicit ones only: F_b = -(k (l - l₀) + c l̇) n, n the unit vector from
  anchor a to anchor b, -F_b on a, and the torques r × F at each end;
* the control's forces and torques at the body centres;
* joint motors: τ clamped to each axis's maximum, about the parent joint
  frame's axis, +τ on the child and -τ on the parent.

Uniform gravity is an acceleration g on every dynamic body, added in
``acceleration``: a = g + F/m, α = I_w⁻¹ τ.

Implicit velocity effects (``velocity_effects``), after the forces:

* stiff springs, the backward-Euler impulse of the spring-damper along its
  line (Catto, "Soft Constraints", GDC 2011):
  P = -h (k C + (c + h k) Ċ) / (1 + h (c + h k) / m_eff),
  one spring after another in colour order (no dynamic body twice in a
  colour), each from the velocities the springs before it left;
* linear and angular damping v ← v / (1 + h c) (Box2D v3's
  ``b2IntegrateVelocitiesTask``), which never reverses a velocity.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .jit import kernel
from .vec import (add, cross, dot, inv_inertia_apply, load3, load4, quat_mul, rotate, scale, store3,
                  sub)


class Bodies(NamedTuple):
    """Per-body constants (N = bodies, static ones included)."""

    inv_mass: np.ndarray  # (N,) 1/kg, 0 for static bodies
    inertia: np.ndarray  # (N, 3) principal moments, kg·m² (static bodies: 1, to divide by)
    inv_inertia: np.ndarray  # (N, 3) 1/(kg·m²), 0 for static bodies
    gyro_inertia: np.ndarray  # (N, 3) kg·m², 0 for static bodies (the explicit gyroscopic torque)
    gravity: np.ndarray  # (N, 3) m/s², g on dynamic bodies and 0 on static ones; (0, 3) without gravity


class Gravitation(NamedTuple):
    """Pairs of dynamic bodies (P = pairs; 0 without gravitation)."""

    i: np.ndarray  # (P,) int64
    j: np.ndarray  # (P,) int64
    gmm: np.ndarray  # (P,) G m_i m_j, N·m²
    eps2: float  # softening length squared, m²


class Springs(NamedTuple):
    """Every spring (S; 0 without springs) and the two sets they are integrated in."""

    a: np.ndarray  # (S,) int64 body of the first end
    b: np.ndarray  # (S,) int64 body of the second end
    anchor_a: np.ndarray  # (S, 3) m, in body a's frame
    anchor_b: np.ndarray  # (S, 3) m, in body b's frame
    rest: np.ndarray  # (S,) m
    k: np.ndarray  # (S,) N/m
    c: np.ndarray  # (S,) N·s/m
    explicit: np.ndarray  # (E,) int64: the springs integrated as forces
    stiff: np.ndarray  # (K,) int64: the stiff springs, colour after colour (implicit update)
    breakable: bool  # any finite elastic limit: a broken spring's flag is read


class Motors(NamedTuple):
    """Actuated joint axes (A; 0 without motors)."""

    parent: np.ndarray  # (A,) int64 body
    child: np.ndarray  # (A,) int64 body
    frame: np.ndarray  # (A, 4) the joint frame in the parent's body frame
    axis: np.ndarray  # (A,) int64: 0, 1, 2 for the frame's x, y, z
    max_torque: np.ndarray  # (A,) N·m
    joint: np.ndarray  # (A,) int64: the joint, for its broken flag
    breakable: bool  # any joint can break: a broken joint's flag is read


class Damping(NamedTuple):
    """Velocity damping rates (N,), or (0,) without damping."""

    linear: np.ndarray  # 1/s
    angular: np.ndarray  # 1/s


class EffectArrays(NamedTuple):
    """Everything the integration kernels read of a model (``Model.effect_arrays``)."""

    bodies: Bodies
    gravitation: Gravitation
    springs: Springs
    motors: Motors
    damping: Damping


def _ro(a, dtype=float, shape=None):
    """A read-only C-contiguous copy of ``a`` (of ``shape`` if given): every
    scene's arrays then have the same numba types, compiled once."""
    a = np.array(a, dtype=dtype, order="C")
    if shape is not None:
        a = a.reshape(shape)
    a.flags.writeable = False
    return a


def _ints(a):
    return _ro(a, np.int64, (-1,))


def compile_effects(model):
    """The arrays of ``model``'s bodies, effects and motors for the kernels
    (an ``EffectArrays``); the effects the scene lacks are empty."""
    dyn = model.dynamic
    gravity = model.effects.get("gravity")
    bodies = Bodies(
        inv_mass=_ro(model.inv_mass),
        inertia=_ro(model.inertia_safe, shape=(-1, 3)),
        inv_inertia=_ro(model.inv_inertia, shape=(-1, 3)),
        gyro_inertia=_ro(np.where(dyn[:, None], model.inertia_safe, 0.0), shape=(-1, 3)),
        gravity=_ro(np.zeros((0, 3)) if gravity is None else gravity.accel, shape=(-1, 3)),
    )
    g = model.effects.get("gravitation")
    gravitation = Gravitation(_ints(g.i), _ints(g.j), _ro(g.gmm, shape=(-1,)), float(g.eps2)) if g is not None \
        else Gravitation(_ints([]), _ints([]), _ro([]), 0.0)
    s = model.effects.get("springs")
    if s is not None:
        stiff = np.concatenate([np.zeros(0, dtype=np.int64)] + [np.asarray(c, dtype=np.int64) for c in s.stiff_colors])
        springs = Springs(_ints(s.a), _ints(s.b), _ro(s.anchor_a, shape=(-1, 3)), _ro(s.anchor_b, shape=(-1, 3)),
                          _ro(s.rest), _ro(s.k), _ro(s.c), _ints(s.explicit), _ints(stiff), bool(s.breakable))
    else:
        springs = Springs(_ints([]), _ints([]), _ro(np.zeros((0, 3))), _ro(np.zeros((0, 3))), _ro([]), _ro([]),
                          _ro([]), _ints([]), _ints([]), False)
    j = model.joints
    if j is not None and j.actuators:
        act = j.act_joint
        motors = Motors(_ints(j.parent[act]), _ints(j.child[act]), _ro(j.frame_p[act], shape=(-1, 4)),
                        _ints(j.act_axis), _ro(j.act_max), _ints(act), bool(j.breakable))
    else:
        motors = Motors(_ints([]), _ints([]), _ro(np.zeros((0, 4))), _ints([]), _ro([]), _ints([]), False)
    d = model.effects.get("damping")
    damping = Damping(_ro(d.linear), _ro(d.angular)) if d is not None else Damping(_ro([]), _ro([]))
    return EffectArrays(bodies, gravitation, springs, motors, damping)


# ------------------------------------------------------------------ springs
@kernel
def spring_ends(springs, s, x, q, v, w):
    """Lever arms ra, rb (m, world frame), unit direction n from anchor a to
    anchor b, length l (m) and its rate l̇ = v_rel·n (m/s) of spring ``s``."""
    a, b = springs.a[s], springs.b[s]
    qa, qb = load4(q, a), load4(q, b)
    ra = rotate(qa, load3(springs.anchor_a, s))
    rb = rotate(qb, load3(springs.anchor_b, s))
    d = sub(sub(add(load3(x, b), rb), load3(x, a)), ra)
    length = math.sqrt(dot(d, d))
    den = 1e-12 if length < 1e-12 else length  # a NaN length stays NaN
    n = (d[0] / den, d[1] / den, d[2] / den)
    vrel = sub(sub(add(load3(v, b), cross(load3(w, b), rb)), load3(v, a)), cross(load3(w, a), ra))
    return ra, rb, n, length, dot(vrel, n)


@kernel
def implicit_spring_impulse(k, c, h, error, error_rate, inv_mass):
    """Backward-Euler impulse (N·s) of a spring-damper on one row over h seconds.

    k: N/m, c: N·s/m, error C (m), error_rate Ċ (m/s), inv_mass = J M⁻¹ Jᵀ
    (1/kg). From P = h F(t+h), F = -k C(t+h) - c Ċ(t+h),
    C(t+h) ≈ C + h Ċ(t+h) and Ċ(t+h) = Ċ + inv_mass P:
        P = -h (k C + (c + h k) Ċ) / (1 + h (c + h k) inv_mass).
    """
    ck = c + h * k
    return -h * (k * error + ck * error_rate) / (1.0 + (h * ck) * inv_mass)


# -------------------------------------------------------------- accumulation
@kernel
def add_at(a, i, v):
    """a[i] += v for a row of an (n, 3) array."""
    a[i, 0] += v[0]
    a[i, 1] += v[1]
    a[i, 2] += v[2]


@kernel
def sub_at(a, i, v):
    """a[i] -= v for a row of an (n, 3) array."""
    a[i, 0] -= v[0]
    a[i, 1] -= v[1]
    a[i, 2] -= v[2]


@kernel
def accumulate(gravitation, springs, motors, x, q, v, w, spring_broken, joint_broken, cforce, ctorque, motor,
               force, torque):
    """The forces (N) and torques (N·m) on every body of one world at the
    positions x (N, 3), orientations q (N, 4), velocities v and world angular
    velocities w (N, 3), into ``force`` and ``torque`` (N, 3), overwritten.

    spring_broken (S,), joint_broken (J,): the world's broken flags (read
    only where something can break); cforce, ctorque (N, 3) or (0, 3): the
    control's forces and torques at the centres; motor (A,) or (0,): its motor
    torques (N·m, clamped here)."""
    n = force.shape[0]
    for i in range(n):
        for k in range(3):
            force[i, k] = 0.0
            torque[i, k] = 0.0
    # Gravitation between every pair of dynamic bodies.
    eps2 = gravitation.eps2
    for p in range(gravitation.i.shape[0]):
        i, j = gravitation.i[p], gravitation.j[p]
        d = sub(load3(x, j), load3(x, i))
        r2 = dot(d, d) + eps2
        f = scale(gravitation.gmm[p] / (r2 * math.sqrt(r2)), d)
        add_at(force, i, f)
        sub_at(force, j, f)
    # Explicit springs.
    for e in range(springs.explicit.shape[0]):
        s = springs.explicit[e]
        if springs.breakable and spring_broken[s]:
            continue
        ra, rb, nrm, length, ldot = spring_ends(springs, s, x, q, v, w)
        mag = springs.k[s] * (length - springs.rest[s]) + springs.c[s] * ldot
        fb = scale(-mag, nrm)  # the force on body b
        a, b = springs.a[s], springs.b[s]
        add_at(force, b, fb)
        sub_at(force, a, fb)
        add_at(torque, b, cross(rb, fb))
        sub_at(torque, a, cross(ra, fb))
    # The control's forces and torques at the centres.
    if cforce.shape[0] > 0:
        for i in range(n):
            add_at(force, i, load3(cforce, i))
    if ctorque.shape[0] > 0:
        for i in range(n):
            add_at(torque, i, load3(ctorque, i))
    # Motors (none of a broken joint).
    if motor.shape[0] > 0:
        for m in range(motors.parent.shape[0]):
            if motors.breakable and joint_broken[motors.joint[m]]:
                continue
            t = motor_torque(motors, m, q, motor[m])
            add_at(torque, motors.child[m], t)
            sub_at(torque, motors.parent[m], t)


@kernel
def motor_torque(motors, m, q, u):
    """The world torque (N·m) of actuator ``m`` at command u (N·m): u clamped
    to ±max_torque about its axis of the parent joint frame R(q_p ⊗ f_p) e."""
    limit = motors.max_torque[m]
    tau = min(max(u, -limit), limit)
    frame = quat_mul(load4(q, motors.parent[m]), load4(motors.frame, m))
    k = motors.axis[m]
    e = (1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0)
    return scale(tau, rotate(frame, e))


@kernel
def acceleration(bodies, i, qi, force, torque):
    """Linear (m/s²) and world angular (rad/s²) acceleration of body i
    (orientation qi) from its accumulated force and torque: a = g + F/m,
    α = I_w⁻¹ τ = R (I_b⁻¹ ⊙ Rᵀ τ)."""
    f = scale(bodies.inv_mass[i], load3(force, i))
    if bodies.gravity.shape[0] > 0:
        f = add(load3(bodies.gravity, i), f)
    return f, inv_inertia_apply(qi, load3(bodies.inv_inertia, i), load3(torque, i))


# ---------------------------------------------------------- velocity effects
@kernel
def velocity_effects(bodies, springs, damping, x, q, v, w, spring_broken, h):
    """The implicit velocity effects of one world over a substep of h seconds,
    in place on v and w (N, 3): the stiff springs' impulses, then damping."""
    inv_m, inv_i = bodies.inv_mass, bodies.inv_inertia
    for t in range(springs.stiff.shape[0]):
        s = springs.stiff[t]
        if springs.breakable and spring_broken[s]:
            continue
        a, b = springs.a[s], springs.b[s]
        ra, rb, n, length, ldot = spring_ends(springs, s, x, q, v, w)
        rna, rnb = cross(ra, n), cross(rb, n)
        ia = inv_inertia_apply(load4(q, a), load3(inv_i, a), rna)
        ib = inv_inertia_apply(load4(q, b), load3(inv_i, b), rnb)
        inv_meff = inv_m[a] + inv_m[b] + dot(rna, ia) + dot(rnb, ib)
        p = implicit_spring_impulse(springs.k[s], springs.c[s], h, length - springs.rest[s], ldot, inv_meff)
        pn = scale(p, n)
        store3(v, b, add(load3(v, b), scale(inv_m[b], pn)))
        store3(v, a, sub(load3(v, a), scale(inv_m[a], pn)))
        store3(w, b, add(load3(w, b), scale(p, ib)))
        store3(w, a, sub(load3(w, a), scale(p, ia)))
    if damping.linear.shape[0] > 0:
        for i in range(v.shape[0]):
            store3(v, i, scale(1.0 / (1.0 + h * damping.linear[i]), load3(v, i)))
            store3(w, i, scale(1.0 / (1.0 + h * damping.angular[i]), load3(w, i)))
