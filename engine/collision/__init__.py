"""Collision detection (geometry only): broad phase and narrow-phase manifolds.

Broad phase (:mod:`.broadphase`): ``candidate_pairs`` once at build time,
``aabb`` + ``overlapping`` each step. Narrow phase (:mod:`.narrowphase`):
one function per shape pair kind returning a :class:`Manifold` of up to 4
points per pair for arrays of any (W, P) leading shape, ``collide`` to
dispatch by shape types and ``collide_rows`` for pairs of mixed kinds. These
are numpy-facing wrappers of the compiled kernels in
:mod:`engine.core.collide`, where the geometry is; a step's detection
(``ContactSet.begin_step``) calls those kernels directly. The contact solver
lives elsewhere and consumes the manifolds. Units: metres.
"""

from .broadphase import aabb, candidate_pairs, overlapping
from .manifold import INVALID_SEPARATION, MAX_POINTS, Manifold
from .narrowphase import (
    PAIR_FUNCTIONS,
    TYPE_ORDER,
    box_box,
    capsule_box,
    capsule_capsule,
    collide,
    collide_rows,
    is_canonical,
    kind_code,
    pair_function,
    plane_box,
    plane_capsule,
    plane_sphere,
    sphere_box,
    sphere_capsule,
    sphere_sphere,
)

__all__ = [
    "Manifold", "MAX_POINTS", "INVALID_SEPARATION", "collide", "collide_rows", "kind_code", "pair_function",
    "is_canonical", "PAIR_FUNCTIONS", "TYPE_ORDER", "plane_sphere", "plane_capsule", "plane_box",
    "sphere_sphere", "sphere_capsule", "sphere_box", "capsule_capsule", "capsule_box", "box_box",
    "candidate_pairs", "aabb", "overlapping",
]
