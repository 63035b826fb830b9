"""Hooke springs between body-local anchor points, with damping and an elastic limit.

Force on the second body (thesis equations 9-12): F_b = -(k (l - l₀) + c l̇) n,
with n the unit vector from anchor a to anchor b, l its length, l₀ the rest
length, k the stiffness (N/m), c the damping (N·s/m); the first body feels -F_b.
Past the elastic limit (|l - l₀| > limit, thesis section 4.3.2) the spring
breaks for good in that world and an event says so.

Two integration paths, chosen per spring at build time:

* compliant springs (ω h < 1 with ω² = k / m_reduced, h the substep; the
  symplectic update is stable to ω h < 2) are
  explicit forces, integrated symplectically: no artificial damping, energy
  conserved to O(h²);
* stiff springs (k h² / m far above 1, where explicit integration explodes) are
  an implicit velocity update, the backward-Euler impulse of the spring-damper
  along its line (Catto, "Soft Constraints", GDC 2011):
  P = -h (k C + (c + h k) Ċ) / (1 + h (c + h k) / m_eff),
  unconditionally stable, at the price of numerical damping.
  They are updated one after another, colour after colour (no dynamic body
  twice in a colour).

The step's forces and impulses are kernels (:mod:`engine.core.effects`, from
the arrays here); this object keeps the parameters, the breaking at the end
of a step and the elastic energy.
"""

from __future__ import annotations

import numpy as np

from ..coloring import color_pairs
from ..math3d import cross, dot, quat_rotate
from ..state import Event

STIFF_OMEGA_H = 1.0


class Springs:
    name = "springs"

    def __init__(self, specs, mass, dynamic, inv_mass, substep_dt):
        self.names = tuple(s.name for s in specs)
        self.a = np.array([s.body_a for s in specs], dtype=np.int64)
        self.b = np.array([s.body_b for s in specs], dtype=np.int64)
        self.anchor_a = np.array([s.anchor_a for s in specs], dtype=float).reshape(-1, 3)
        self.anchor_b = np.array([s.anchor_b for s in specs], dtype=float).reshape(-1, 3)
        self.rest = np.array([s.rest_length for s in specs], dtype=float)
        self.k = np.array([s.stiffness for s in specs], dtype=float)
        self.c = np.array([s.damping for s in specs], dtype=float)
        self.limit = np.array([s.elastic_limit for s in specs], dtype=float)
        self.breakable = bool(np.isfinite(self.limit).any())
        inv_red = inv_mass[self.a] + inv_mass[self.b]
        omega = np.sqrt(self.k * inv_red)
        stiff = omega * substep_dt >= STIFF_OMEGA_H
        self.explicit = np.flatnonzero(~stiff)
        self.stiff_colors = color_pairs(self.a[stiff], self.b[stiff], dynamic)
        stiff_idx = np.flatnonzero(stiff)
        self.stiff_colors = [stiff_idx[c] for c in self.stiff_colors]

    # Geometry ----------------------------------------------------------------
    def _ends(self, idx, position, orientation, velocity, angular_velocity):
        a, b = self.a[idx], self.b[idx]
        ra = quat_rotate(orientation[:, a], self.anchor_a[idx])
        rb = quat_rotate(orientation[:, b], self.anchor_b[idx])
        d = position[:, b] + rb - position[:, a] - ra
        length = np.sqrt(dot(d, d))
        n = d / np.maximum(length, 1e-12)[..., None]
        vrel = velocity[:, b] + cross(angular_velocity[:, b], rb) - velocity[:, a] - cross(angular_velocity[:, a], ra)
        return a, b, ra, rb, n, length, dot(vrel, n)

    def end_of_step(self, model, state, events):
        if not self.breakable:
            return
        idx = np.arange(self.a.size)
        _, _, _, _, _, length, _ = self._ends(
            idx, state.position, state.orientation, state.velocity, state.angular_velocity)
        snapped = (np.abs(length - self.rest) > self.limit) & ~state.spring_broken
        if snapped.any():
            state.spring_broken |= snapped
            for w, s in zip(*np.nonzero(snapped)):
                step = int(state.step[w]) + 1  # the count after this step, as joints and SimulationError
                events.append(Event("spring_broken", self.names[s], int(w), step, step * model.settings.dt))

    def potential(self, model, state):
        """Elastic energy per world, J: Σ ½ k (l - l₀)² over unbroken springs."""
        idx = np.arange(self.a.size)
        _, _, _, _, _, length, _ = self._ends(
            idx, state.position, state.orientation, state.velocity, state.angular_velocity)
        e = 0.5 * self.k * (length - self.rest) ** 2
        return np.where(state.spring_broken, 0.0, e).sum(axis=-1)
