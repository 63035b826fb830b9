"""Materials and the per-pair friction and restitution table.

Friction is Coulomb's law with a static coefficient μs (the largest tangential
to normal force ratio a resting contact holds) and a kinetic coefficient μk
(the ratio while sliding). The default table is the textbook table of
coefficients of friction (Serway & Jewett, *Physics for Scientists and
Engineers*, table 5.1), the table the thesis reproduces as its table 1. Pairs
not in the table combine the two materials' own coefficients by the geometric
mean, μ = sqrt(μa μb), as Box2D and Bullet do; restitution combines by the
maximum, as Box2D does, so a bouncy ball bounces on any floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Material:
    """A surface material.

    static_friction, kinetic_friction: Coulomb coefficients against itself (≥ 0).
    restitution: coefficient e in [0, 1] (ratio of separating to closing speed).
    density: kg/m³, used when a body is given a material but no mass.
    """

    name: str
    static_friction: float
    kinetic_friction: float
    restitution: float = 0.0
    density: float = 1000.0

    def validate(self) -> None:
        for field, value in (
            ("static_friction", self.static_friction),
            ("kinetic_friction", self.kinetic_friction),
            ("restitution", self.restitution),
            ("density", self.density),
        ):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise ValueError(
                    f"material {self.name!r}: {field} must be a finite number >= 0, got {value!r}"
                )
        if self.restitution > 1.0:
            raise ValueError(f"material {self.name!r}: restitution must be <= 1, got {self.restitution}")
        if self.kinetic_friction > self.static_friction:
            raise ValueError(f"material {self.name!r}: kinetic_friction {self.kinetic_friction} exceeds "
                             f"static_friction {self.static_friction} (a sliding contact never holds more "
                             f"than a resting one)")
        if self.density <= 0:
            raise ValueError(f"material {self.name!r}: density must be > 0, got {self.density}")


# Materials with their own coefficients (μs, μk), a typical restitution and a
# density. Metals without a self-pair row in the table take their row against steel.
DEFAULT_MATERIALS = {
    "default": Material("default", 0.6, 0.5, 0.0, 1000.0),
    "steel": Material("steel", 0.74, 0.57, 0.6, 7850.0),
    "aluminium": Material("aluminium", 0.61, 0.47, 0.5, 2700.0),
    "copper": Material("copper", 0.53, 0.36, 0.4, 8960.0),
    "rubber": Material("rubber", 1.0, 0.8, 0.8, 1100.0),
    "concrete": Material("concrete", 1.0, 0.8, 0.1, 2400.0),
    "wood": Material("wood", 0.5, 0.2, 0.4, 700.0),
    "glass": Material("glass", 0.94, 0.4, 0.7, 2500.0),
    "ice": Material("ice", 0.1, 0.03, 0.1, 917.0),
    "teflon": Material("teflon", 0.04, 0.04, 0.1, 2200.0),
    "snow": Material("snow", 0.14, 0.1, 0.0, 300.0),
    "bone": Material("bone", 0.6, 0.5, 0.0, 1050.0),
}

# Pair coefficients (μs, μk) from the textbook table, keyed by sorted name pair.
DEFAULT_PAIRS = {
    ("steel", "steel"): (0.74, 0.57),
    ("aluminium", "steel"): (0.61, 0.47),
    ("copper", "steel"): (0.53, 0.36),
    ("concrete", "rubber"): (1.0, 0.8),
    ("wood", "wood"): (0.5, 0.2),
    ("glass", "glass"): (0.94, 0.4),
    ("snow", "wood"): (0.14, 0.1),
    ("teflon", "teflon"): (0.04, 0.04),
    ("ice", "ice"): (0.1, 0.03),
}


class MaterialTable:
    """Materials by name and the friction pairs between them.

    >>> table = MaterialTable()
    >>> table.add(Material("felt", 0.7, 0.6))
    >>> table.set_pair("felt", "wood", static_friction=0.6, kinetic_friction=0.45)
    """

    def __init__(self, materials=None, pairs=None):
        self.materials = dict(DEFAULT_MATERIALS if materials is None else materials)
        self.pairs = dict(DEFAULT_PAIRS if pairs is None else pairs)

    def add(self, material: Material) -> None:
        material.validate()
        self.materials[material.name] = material

    def get(self, name: str, what: str = "") -> Material:
        if name not in self.materials:
            prefix = f"{what}: " if what else ""
            raise ValueError(
                f"{prefix}unknown material {name!r}; known materials: {sorted(self.materials)}"
            )
        return self.materials[name]

    def set_pair(self, a: str, b: str, static_friction: float, kinetic_friction: float) -> None:
        self.get(a)
        self.get(b)
        Material(f"{a}/{b}", static_friction, kinetic_friction).validate()
        self.pairs[tuple(sorted((a, b)))] = (float(static_friction), float(kinetic_friction))

    def friction(self, a: str, b: str) -> tuple[float, float]:
        """(μs, μk) for the pair: the table's entry, else geometric means."""
        key = tuple(sorted((a, b)))
        if key in self.pairs:
            return self.pairs[key]
        ma, mb = self.get(a), self.get(b)
        return (
            math.sqrt(ma.static_friction * mb.static_friction),
            math.sqrt(ma.kinetic_friction * mb.kinetic_friction),
        )

    def restitution(self, a: str, b: str) -> float:
        return max(self.get(a).restitution, self.get(b).restitution)

    def copy(self) -> "MaterialTable":
        return MaterialTable(self.materials, self.pairs)
