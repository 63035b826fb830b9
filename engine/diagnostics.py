"""Conserved quantities and error measures per world, for tests and benchmarks.

Energies in joules, momenta in kg·m/s and kg·m²/s, per world (arrays (W,)).
"""

from __future__ import annotations

import numpy as np

from .math3d import cross, quat_rotate, quat_rotate_inv


def kinetic_energy(model, state) -> np.ndarray:
    """Σ ½ m v² + ½ ωᵀ I ω over dynamic bodies."""
    m = np.where(model.dynamic, model.mass, 0.0)
    lin = 0.5 * (m * (state.velocity ** 2).sum(-1)).sum(-1)
    wb = quat_rotate_inv(state.orientation, state.angular_velocity)
    inertia = np.where(model.dynamic[:, None], model.inertia_safe, 0.0)
    rot = 0.5 * (inertia * wb * wb).sum(-1).sum(-1)
    return lin + rot


def potential_energy(model, state) -> np.ndarray:
    """Sum of the potentials of the effects that have one (gravity, gravitation, springs)."""
    total = np.zeros(state.num_worlds)
    for effect in model.effects.values():
        if hasattr(effect, "potential"):
            total = total + effect.potential(model, state)
    return total


def total_energy(model, state) -> np.ndarray:
    return kinetic_energy(model, state) + potential_energy(model, state)


def linear_momentum(model, state) -> np.ndarray:
    """(W, 3) Σ m v over dynamic bodies."""
    m = np.where(model.dynamic, model.mass, 0.0)
    return (m[:, None] * state.velocity).sum(axis=1)


def angular_momentum(model, state, about=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(W, 3) Σ (x - about) × m v + I ω over dynamic bodies."""
    m = np.where(model.dynamic, model.mass, 0.0)
    r = state.position - np.asarray(about, dtype=float)
    orbital = (cross(r, m[:, None] * state.velocity)).sum(axis=1)
    inertia = np.where(model.dynamic[:, None], model.inertia_safe, 0.0)
    spin = quat_rotate(state.orientation, inertia * quat_rotate_inv(state.orientation, state.angular_velocity))
    return orbital + spin.sum(axis=1)


def center_of_mass(model, state) -> np.ndarray:
    """(W, 3) centre of mass of the dynamic bodies, m."""
    m = np.where(model.dynamic, model.mass, 0.0)
    return (m[:, None] * state.position).sum(axis=1) / m.sum()
