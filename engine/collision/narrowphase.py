"""Narrow phase: contact manifolds for every pair kind, and a dispatcher.

Every pair function has the signature

    f(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold

with positions (W, P, 3) in metres, unit quaternions (W, P, 4) in (w, x, y, z)
order, shape parameters (P, 3) as in :mod:`engine.shapes`, and ``margin``
the speculative distance in metres, a number or one per pair (W, P) (points
with separation < margin are valid; the box pair keeps its four points among
them). The normal points from shape a to shape b. The canonical order of
shape types is plane, sphere, capsule, box; :func:`collide` swaps arguments
(and flips the normal) for the other order.

All functions are vectorised over worlds and pairs, use no Python loop over
them and no BLAS, so a batch of W worlds gives bit for bit what W separate
calls give.
"""

from __future__ import annotations

from ..shapes import BOX, CAPSULE, PLANE, SHAPE_NAMES, SPHERE
from .boxes import box_box
from .box_round import capsule_box, sphere_box
from .manifold import INVALID_SEPARATION, MAX_POINTS, Manifold
from .plane import plane_box, plane_capsule, plane_sphere
from .round import capsule_capsule, sphere_capsule, sphere_sphere

#: Rank of each shape type in the canonical pair order (lower rank is shape a).
TYPE_ORDER = {PLANE: 0, SPHERE: 1, CAPSULE: 2, BOX: 3}

#: Pair function for each canonical (type_a, type_b).
PAIR_FUNCTIONS = {
    (PLANE, SPHERE): plane_sphere,
    (PLANE, CAPSULE): plane_capsule,
    (PLANE, BOX): plane_box,
    (SPHERE, SPHERE): sphere_sphere,
    (SPHERE, CAPSULE): sphere_capsule,
    (SPHERE, BOX): sphere_box,
    (CAPSULE, CAPSULE): capsule_capsule,
    (CAPSULE, BOX): capsule_box,
    (BOX, BOX): box_box,
}


def is_canonical(type_a: int, type_b: int) -> bool:
    """True when (type_a, type_b) is already in canonical order."""
    return TYPE_ORDER[int(type_a)] <= TYPE_ORDER[int(type_b)]


def pair_function(type_a: int, type_b: int):
    """(function, swapped): the canonical pair function for these shape types,
    and whether the arguments must be swapped (and the normal flipped)."""
    ta, tb = int(type_a), int(type_b)
    for t in (ta, tb):
        if t not in TYPE_ORDER:
            raise ValueError(f"no collision for shape type {SHAPE_NAMES.get(t, t)!r}")
    swapped = not is_canonical(ta, tb)
    key = (tb, ta) if swapped else (ta, tb)
    if key not in PAIR_FUNCTIONS:
        raise ValueError(f"no collision between {SHAPE_NAMES[ta]} and {SHAPE_NAMES[tb]}")
    return PAIR_FUNCTIONS[key], swapped


def collide(type_a, type_b, pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Contact manifold of P pairs whose a shapes are all ``type_a`` and b shapes ``type_b``.

    pos (W, P, 3) m, quat (W, P, 4), params (P, 3); margin in m. The normal
    of the result always points from a to b, whichever order the types come in.
    """
    fn, swapped = pair_function(type_a, type_b)
    if swapped:
        return fn(pos_b, quat_b, params_b, pos_a, quat_a, params_a, margin).flipped()
    return fn(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


__all__ = [
    "Manifold", "MAX_POINTS", "INVALID_SEPARATION", "PAIR_FUNCTIONS", "TYPE_ORDER", "collide",
    "pair_function", "is_canonical", "plane_sphere", "plane_capsule", "plane_box", "sphere_sphere",
    "sphere_capsule", "sphere_box", "capsule_capsule", "capsule_box", "box_box",
]
