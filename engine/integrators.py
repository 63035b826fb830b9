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
Each function here is one call of a compiled kernel over every world
(:mod:`engine.core.integrate`, the force effects in :mod:`engine.core.effects`),
with the model's arrays compiled at build (``Model.effect_arrays``).
"""

from __future__ import annotations

import numpy as np

from .core import integrate as K


def _control_arrays(control, num_worlds):
    """The control's (W, N, 3) forces and torques and (W, A) motor torques
    as float arrays for the kernels; (W, 0, 3) and (W, 0) where absent."""
    force = torque = motor = None
    if control is not None:
        force, torque, motor = control.force, control.torque, control.motor
    none3 = np.empty((num_worlds, 0, 3))
    return (none3 if force is None else np.ascontiguousarray(force, dtype=np.float64),
            none3 if torque is None else np.ascontiguousarray(torque, dtype=np.float64),
            np.empty((num_worlds, 0)) if motor is None else np.ascontiguousarray(motor, dtype=np.float64))


def _joint_broken(state):
    broken = state.arrays.get("joint_broken")
    return np.zeros((state.num_worlds, 0), dtype=bool) if broken is None else broken


def _force_arguments(model, state, control):
    fx = model.effect_arrays
    return (fx.bodies, fx.gravitation, fx.springs, fx.motors, state.position, state.orientation, state.velocity,
            state.angular_velocity, state.spring_broken, _joint_broken(state),
            *_control_arrays(control, state.num_worlds))


def integrate_velocities(model, state, control, h):
    """Semi-implicit velocity update v += h a(x, v), ω += h α."""
    K.integrate_velocities_batch(*_force_arguments(model, state, control), h)


def velocity_effects(model, state, h):
    """The implicit velocity effects after the forces: the stiff springs'
    backward-Euler impulses, then damping v ← v / (1 + h c)."""
    fx = model.effect_arrays
    if fx.springs.stiff.size == 0 and fx.damping.linear.size == 0:
        return
    K.velocity_effects_batch(fx.bodies, fx.springs, fx.damping, state.position, state.orientation, state.velocity,
                             state.angular_velocity, state.spring_broken, h)


def integrate_positions(model, state, h):
    """x += h v; free rotation with the gyroscopic term (splitting)."""
    K.integrate_positions_batch(model.effect_arrays.bodies, state.position, state.orientation, state.velocity,
                                state.angular_velocity, h)


def explicit_euler(model, state, control, h):
    """Thesis equations 4 and 5: positions from the old velocities, velocities
    from the old forces; ω̇ = I⁻¹(τ - ω × Iω) explicitly."""
    K.explicit_euler_batch(*_force_arguments(model, state, control), h)


def runge_kutta4(model, state, control, h):
    """Classical RK4 over (x, q, v, ω) under the force effects; the quaternion
    is renormalised at the end. Returns nothing; updates the state."""
    K.runge_kutta4_batch(*_force_arguments(model, state, control), h)
