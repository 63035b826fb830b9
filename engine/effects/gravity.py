"""Uniform gravity: every dynamic body accelerates by g (thesis equation 6 at the
Earth's surface: F = m g, so 2.5 kg under 9.80665 m/s² feels 24.516625 N). The
step adds ``accel`` in its kernels (:mod:`engine.core.effects`)."""

from __future__ import annotations

import numpy as np


class Gravity:
    name = "gravity"

    def __init__(self, gravity, dynamic):
        # (N, 3): g on dynamic bodies, zero on static ones.
        self.accel = np.where(dynamic[:, None], np.asarray(gravity, dtype=float)[None, :], 0.0)
        self.g = np.asarray(gravity, dtype=float)

    def weight(self, mass):
        """Force in N that gravity exerts on a mass in kg: F = m g."""
        return np.asarray(mass, dtype=float)[..., None] * self.g

    def potential(self, model, state):
        """Gravitational potential energy per world, J: -Σ m g·x over dynamic bodies."""
        m = np.where(model.dynamic, model.mass, 0.0)
        gx = (state.position * self.g).sum(axis=-1)
        return -(m * gx).sum(axis=-1)
