"""Universal gravitation between every pair of dynamic bodies (thesis equation 6):
F = G m_i m_j / r², along the line of centres; with a softening length ε the
law becomes G m_i m_j r / (r² + ε²)^(3/2), which keeps close passes finite. The
step's forces are a kernel (:mod:`engine.core.effects`) over the pairs here."""

from __future__ import annotations

import numpy as np

from ..math3d import dot


class Gravitation:
    name = "gravitation"

    def __init__(self, G, softening, mass, dynamic):
        idx = np.flatnonzero(dynamic)
        i, j = np.triu_indices(len(idx), k=1)
        self.i, self.j = idx[i], idx[j]
        self.G = float(G)
        self.eps2 = float(softening) ** 2
        self.gmm = self.G * mass[self.i] * mass[self.j]  # (P,)

    def potential(self, model, state):
        """Potential energy per world, J: -Σ G m_i m_j / sqrt(r² + ε²)."""
        if self.i.size == 0:
            return np.zeros(state.num_worlds)
        d = state.position[:, self.j] - state.position[:, self.i]
        return -(self.gmm / np.sqrt(dot(d, d) + self.eps2)).sum(axis=-1)
