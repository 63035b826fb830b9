"""Force effects: each module is one effect, compiled into a model only when the
scene declares it, so a scene pays nothing for what it lacks.

An effect object may define any of these hooks, called by the step:

``forces(model, bodies, acc)``
    add forces (N), torques (N·m) or accelerations (m/s²) at the current
    positions and velocities into ``acc`` (arrays (W, N, 3));
``velocity(model, state, h)``
    an implicit velocity update over the substep of ``h`` seconds, after the
    forces (damping, stiff springs);
``end_of_step(model, state, events)``
    once per step, after the positions are final (breaking).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class BodyView:
    """The kinematic quantities forces depend on (arrays (W, N, ...))."""

    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    spring_broken: np.ndarray | None = None
    joint_broken: np.ndarray | None = None

    @classmethod
    def of(cls, state, copy=False):
        c = (lambda a: a.copy()) if copy else (lambda a: a)
        return cls(c(state.position), c(state.orientation), c(state.velocity), c(state.angular_velocity),
                   state.arrays.get("spring_broken"), state.arrays.get("joint_broken"))


@dataclass
class Accumulator:
    """Per-body sums of force (N), torque (N·m) and acceleration (m/s²)."""

    force: np.ndarray
    torque: np.ndarray
    accel: np.ndarray

    @classmethod
    def zeros(cls, shape):
        return cls(np.zeros(shape), np.zeros(shape), np.zeros(shape))
