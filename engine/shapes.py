"""Collision shapes and their exact mass properties.

Each shape is expressed in its body's frame, centred on the body's centre of
mass, with its symmetry axes along the body axes, so the inertia tensor is
diagonal in the body frame (the body frame is the principal frame).

Units: metres, kilograms, kilograms per cubic metre, kg·m².
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Shape type codes used in the compiled model's ``shape_type`` array.
SPHERE = 0
CAPSULE = 1
BOX = 2
PLANE = 3
NONE = 4

SHAPE_NAMES = {SPHERE: "sphere", CAPSULE: "capsule", BOX: "box", PLANE: "plane", NONE: "none"}


def _positive(name: str, value: float, what: str) -> float:
    try:
        if isinstance(value, (str, bytes)):
            raise TypeError
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: {name} must be a positive finite number, got {value!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{what}: {name} must be a positive finite number, got {value!r}")
    return value


@dataclass(frozen=True)
class Sphere:
    """Solid sphere of ``radius`` metres."""

    radius: float

    type_code = SPHERE

    def validate(self, what: str) -> None:
        _positive("radius", self.radius, what)

    def volume(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius**3

    def unit_inertia(self) -> np.ndarray:
        """Principal moments per kilogram: 2/5 r²."""
        return np.full(3, 0.4 * self.radius**2)

    def params(self) -> np.ndarray:
        return np.array([self.radius, 0.0, 0.0])

    def bounding_radius(self) -> float:
        return self.radius


@dataclass(frozen=True)
class Capsule:
    """Solid capsule: a cylinder of ``radius`` and length ``2 * half_length``
    along the body's local z axis, capped by two hemispheres."""

    radius: float
    half_length: float

    type_code = CAPSULE

    def validate(self, what: str) -> None:
        _positive("radius", self.radius, what)
        _positive("half_length", self.half_length, what)

    def volume(self) -> float:
        r, h = self.radius, self.half_length
        return math.pi * r * r * 2.0 * h + 4.0 / 3.0 * math.pi * r**3

    def unit_inertia(self) -> np.ndarray:
        """Principal moments per kilogram.

        Cylinder (mass m_c, length 2h) plus two hemispheres (total mass m_s):
        I_z = m_c r²/2 + m_s 2r²/5;
        I_x = m_c (r²/4 + (2h)²/12) + m_s (2r²/5 + h² + 3hr/4),
        the last term from each hemisphere's own 83/320 m r² moved by the
        parallel-axis theorem to its centroid h + 3r/8 from the centre.
        """
        r, h = self.radius, self.half_length
        vc = math.pi * r * r * 2.0 * h
        vs = 4.0 / 3.0 * math.pi * r**3
        fc, fs = vc / (vc + vs), vs / (vc + vs)
        iz = fc * r * r / 2.0 + fs * 0.4 * r * r
        ix = fc * (r * r / 4.0 + (2.0 * h) ** 2 / 12.0) + fs * (0.4 * r * r + h * h + 0.75 * h * r)
        return np.array([ix, ix, iz])

    def params(self) -> np.ndarray:
        return np.array([self.radius, self.half_length, 0.0])

    def bounding_radius(self) -> float:
        return self.radius + self.half_length


@dataclass(frozen=True)
class Box:
    """Solid box with half extents ``(hx, hy, hz)`` metres along the body axes."""

    half_extents: tuple

    type_code = BOX

    def __post_init__(self):
        object.__setattr__(self, "half_extents", tuple(float(v) for v in np.ravel(self.half_extents)))

    def validate(self, what: str) -> None:
        if len(self.half_extents) != 3:
            raise ValueError(f"{what}: half_extents must have 3 entries, got {len(self.half_extents)}")
        for axis, v in zip("xyz", self.half_extents):
            _positive(f"half_extents[{axis}]", v, what)

    def volume(self) -> float:
        hx, hy, hz = self.half_extents
        return 8.0 * hx * hy * hz

    def unit_inertia(self) -> np.ndarray:
        """Principal moments per kilogram: (b² + c²)/3 with half extents a, b, c."""
        hx, hy, hz = self.half_extents
        return np.array([hy * hy + hz * hz, hx * hx + hz * hz, hx * hx + hy * hy]) / 3.0

    def params(self) -> np.ndarray:
        return np.array(self.half_extents)

    def bounding_radius(self) -> float:
        return float(np.linalg.norm(self.half_extents))


@dataclass(frozen=True)
class Plane:
    """Infinite static half-space whose surface passes through the body origin,
    with outward normal along the body's local +z axis."""

    type_code = PLANE

    def validate(self, what: str) -> None:
        return None

    def volume(self) -> float:
        return math.inf

    def unit_inertia(self) -> np.ndarray:
        return np.zeros(3)

    def params(self) -> np.ndarray:
        return np.zeros(3)

    def bounding_radius(self) -> float:
        return math.inf


Shape = Sphere | Capsule | Box | Plane
