"""Soft constraints (Catto, "Solver2D" and "Soft Step", 2024; Box2D v3 ``b2MakeSoft``).

A constraint with stiffness ``hertz`` and damping ratio ``zeta`` on a substep
of ``h`` seconds solves, per row with effective mass m = 1/(J M⁻¹ Jᵀ),

    Δλ = -m · mass_scale · (J·u + bias_rate · C) - impulse_scale · λ

where, with ω = 2π·hertz, a1 = 2ζ + hω, a2 = hω·a1, a3 = 1/(1 + a2):
bias_rate = ω/a1, mass_scale = a2·a3, impulse_scale = a3. This is the implicit
(backward Euler) update of a spring-damper of that frequency and damping ratio
acting on the constraint error, so it is stable for any h. ``hertz = inf``
gives a rigid constraint with full Baumgarte bias C/h.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Softness:
    bias_rate: float  # 1/s
    mass_scale: float
    impulse_scale: float


def make_soft(hertz: float, zeta: float, h: float) -> Softness:
    if hertz == 0.0:
        return Softness(0.0, 1.0, 0.0)
    if math.isinf(hertz):
        return Softness(1.0 / h, 1.0, 0.0)
    omega = 2.0 * math.pi * hertz
    a1 = 2.0 * zeta + h * omega
    a2 = h * omega * a1
    a3 = 1.0 / (1.0 + a2)
    return Softness(omega / a1, a2 * a3, a3)


def select_softness(mask, a: Softness, b: Softness) -> Softness:
    """Each of a's terms where ``mask``, b's elsewhere (arrays of mask's shape)."""
    return Softness(np.where(mask, a.bias_rate, b.bias_rate), np.where(mask, a.mass_scale, b.mass_scale),
                    np.where(mask, a.impulse_scale, b.impulse_scale))


def implicit_spring_impulse(k, c, h, error, error_rate, inv_mass):
    """Backward-Euler impulse of a spring-damper on one constraint row.

    k: stiffness, c: damping, h: s, error C, error_rate Ċ = J·u, inv_mass =
    J M⁻¹ Jᵀ. From P = h F(t+h), F = -k C(t+h) - c Ċ(t+h), C(t+h) ≈ C + h Ċ(t+h)
    and Ċ(t+h) = Ċ + inv_mass P:
        P = -h (k C + (c + h k) Ċ) / (1 + h (c + h k) inv_mass).
    """
    return implicit_spring_impulse_from(h, implicit_spring_terms(k, c, h, error, inv_mass), error_rate)


def implicit_spring_terms(k, c, h, error, inv_mass):
    """The parts of ``implicit_spring_impulse`` that do not depend on Ċ:
    (k C, c + h k, 1 + h (c + h k) inv_mass), for rows swept several times
    at the same positions."""
    ck = c + h * k
    return k * error, ck, 1.0 + (h * ck) * inv_mass


def implicit_spring_impulse_from(h, terms, error_rate):
    """``implicit_spring_impulse`` from its ``implicit_spring_terms``."""
    k_error, ck, denominator = terms
    return -h * (k_error + ck * error_rate) / denominator
