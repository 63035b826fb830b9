"""Linear and angular velocity damping: dv/dt = -c v, integrated implicitly,
v ← v / (1 + h c), which never reverses a velocity however large c h is (the
form Box2D v3 uses in ``b2IntegrateVelocitiesTask``). The update is a kernel
(:func:`engine.core.effects.velocity_effects`); this object holds the rates."""

from __future__ import annotations

import numpy as np


class Damping:
    name = "damping"

    def __init__(self, linear, angular):
        self.linear = np.asarray(linear, dtype=float)  # (N,) 1/s
        self.angular = np.asarray(angular, dtype=float)
