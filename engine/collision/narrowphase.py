"""Narrow phase: contact manifolds for every pair kind, and a dispatcher.

Every pair function has the signature

    f(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold

with positions (W, P, 3) in metres, unit quaternions (W, P, 4) in (w, x, y, z)
order, shape parameters (P, 3) as in :mod:`engine.shapes`, and ``margin``
the speculative distance in metres, a number or one per pair (W, P) (points
with separation < margin are valid; the box pair keeps its four points among
them). Any leading shape that broadcasts works in place of (W, P). The
normal points from shape a to shape b. The canonical order of shape types
is plane, sphere, capsule, box; :func:`collide` swaps arguments (and flips
the normal) for the other order.

These are numpy-facing wrappers: the geometry is in the compiled kernels of
:mod:`engine.core.collide` (one kernel per pair kind, derivations there),
run over every (world, pair) in one kernel call. Each pair is computed on
its own, so a batch of W worlds gives bit for bit what W separate calls give.
"""

from __future__ import annotations

import numpy as np

from ..core.collide import KIND_CODES
from ..core.collide import narrow_rows as _narrow_rows
from ..shapes import BOX, CAPSULE, PLANE, SHAPE_NAMES, SPHERE
from .manifold import INVALID_SEPARATION, MAX_POINTS, Manifold

#: Rank of each shape type in the canonical pair order (lower rank is shape a).
TYPE_ORDER = {PLANE: 0, SPHERE: 1, CAPSULE: 2, BOX: 3}


def _rows(a, lead, width):
    return np.broadcast_to(np.asarray(a, dtype=float), lead + (width,)).reshape(-1, width)


def collide_rows(kind, pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin, swapped=False) -> Manifold:
    """Manifolds of pairs of mixed kinds: ``kind`` (...) int the kind code of
    each pair (:data:`engine.core.collide.KIND_CODES` of its canonical shape
    types), the other arguments as the pair functions', broadcast to the
    shape of ``kind`` (m). ``swapped``: a and b hold each pair's b and a
    shapes, and the normals are reversed to point from the given a to b."""
    kind = np.asarray(kind, dtype=np.int64)
    lead = kind.shape
    R = kind.size
    normal = np.empty((R, 3))
    point = np.empty((R, MAX_POINTS, 3))
    separation = np.empty((R, MAX_POINTS))
    valid = np.empty((R, MAX_POINTS), dtype=bool)
    if R:
        # The R pairs as one world of 2 R bodies: pair r joins bodies 2 r (a) and 2 r + 1 (b).
        body_a = 2 * np.arange(R, dtype=np.int64)
        position = np.empty((1, 2 * R, 3))
        orientation = np.empty((1, 2 * R, 4))
        params = np.empty((2 * R, 3))
        position[0, 0::2], position[0, 1::2] = _rows(pos_a, lead, 3), _rows(pos_b, lead, 3)
        orientation[0, 0::2], orientation[0, 1::2] = _rows(quat_a, lead, 4), _rows(quat_b, lead, 4)
        params[0::2], params[1::2] = _rows(params_a, lead, 3), _rows(params_b, lead, 3)
        margin = np.ascontiguousarray(np.broadcast_to(np.asarray(margin, dtype=float), lead)).reshape(1, R)
        _narrow_rows(kind.reshape(-1), body_a, body_a + 1, position, orientation, params, margin,
                     np.ones((1, R), dtype=bool), normal, point, separation, valid, np.empty((1, R)),
                     np.empty((1, 2, 8, 3)))
        if swapped:
            normal = -normal
    return Manifold(normal.reshape(lead + (3,)), point.reshape(lead + (MAX_POINTS, 3)),
                    separation.reshape(lead + (MAX_POINTS,)), valid.reshape(lead + (MAX_POINTS,)))


def _pair(code, pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin, swapped=False) -> Manifold:
    """The manifolds of pairs of one kind, over the broadcast leading shape of the arguments."""
    pos_a, quat_a, params_a = np.asarray(pos_a), np.asarray(quat_a), np.asarray(params_a)
    pos_b, quat_b, params_b = np.asarray(pos_b), np.asarray(quat_b), np.asarray(params_b)
    lead = np.broadcast_shapes(pos_a.shape[:-1], quat_a.shape[:-1], params_a.shape[:-1], pos_b.shape[:-1],
                               quat_b.shape[:-1], params_b.shape[:-1], np.shape(margin))
    return collide_rows(np.full(lead, code, dtype=np.int64), pos_a, quat_a, params_a, pos_b, quat_b, params_b,
                        margin, swapped)


def plane_sphere(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Plane a, sphere b: one point (slot 0) below the sphere centre."""
    return _pair(KIND_CODES[PLANE, SPHERE], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def plane_capsule(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Plane a, capsule b: the two segment ends (slot 0: local -z end, slot 1: +z end)."""
    return _pair(KIND_CODES[PLANE, CAPSULE], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def plane_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Plane a, box b: the 4 deepest of the 8 corners, in the slots in
    increasing corner index (a box resting on a face keeps each corner in
    the same slot). A box lying flat gives 4 valid points, on an edge 2, on
    a corner 1."""
    return _pair(KIND_CODES[PLANE, BOX], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def sphere_sphere(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Sphere a, sphere b: one point; coincident centres use the normal +z."""
    return _pair(KIND_CODES[SPHERE, SPHERE], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def sphere_capsule(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Sphere a, capsule b: one point, from the sphere centre's closest point on
    the capsule segment. A centre on the axis uses a normal perpendicular to it."""
    return _pair(KIND_CODES[SPHERE, CAPSULE], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def sphere_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Sphere a, box b: one point (the closest box point; a centre inside
    the box is pushed out through the nearest face)."""
    return _pair(KIND_CODES[SPHERE, BOX], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def capsule_capsule(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Capsule a, capsule b: one point, or two for (nearly) parallel capsules
    (the ends of their overlap, slot 0 towards a's -z end)."""
    return _pair(KIND_CODES[CAPSULE, CAPSULE], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def capsule_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Capsule a, box b: one point, or two when the capsule lies along a
    face (slot 0 nearer the capsule's -z end)."""
    return _pair(KIND_CODES[CAPSULE, BOX], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


def box_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Box a, box b: up to 4 points for face contact, 1 for edge-edge contact.

    Face contacts keep the incident face's vertex order in the slots (a box
    resting inside a larger face gives its 4 bottom corners in fixed slots).
    """
    return _pair(KIND_CODES[BOX, BOX], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


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


def _canonical(type_a, type_b):
    """(canonical (type_a, type_b), swapped), or ValueError for a pair that cannot collide."""
    ta, tb = int(type_a), int(type_b)
    for t in (ta, tb):
        if t not in TYPE_ORDER:
            raise ValueError(f"no collision for shape type {SHAPE_NAMES.get(t, t)!r}")
    swapped = not is_canonical(ta, tb)
    key = (tb, ta) if swapped else (ta, tb)
    if key not in PAIR_FUNCTIONS:
        raise ValueError(f"no collision between {SHAPE_NAMES[ta]} and {SHAPE_NAMES[tb]}")
    return key, swapped


def pair_function(type_a: int, type_b: int):
    """(function, swapped): the canonical pair function for these shape types,
    and whether the arguments must be swapped (and the normal flipped)."""
    key, swapped = _canonical(type_a, type_b)
    return PAIR_FUNCTIONS[key], swapped


def kind_code(type_a: int, type_b: int) -> int:
    """The kernels' code of the canonical pair kind of these shape types
    (:data:`engine.core.collide.KIND_CODES`), in either order."""
    return KIND_CODES[_canonical(type_a, type_b)[0]]


def collide(type_a, type_b, pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Contact manifold of P pairs whose a shapes are all ``type_a`` and b shapes ``type_b``.

    pos (W, P, 3) m, quat (W, P, 4), params (P, 3); margin in m. The normal
    of the result always points from a to b, whichever order the types come in.
    """
    key, swapped = _canonical(type_a, type_b)
    if swapped:
        return _pair(KIND_CODES[key], pos_b, quat_b, params_b, pos_a, quat_a, params_a, margin, swapped=True)
    return _pair(KIND_CODES[key], pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin)


__all__ = [
    "Manifold", "MAX_POINTS", "INVALID_SEPARATION", "PAIR_FUNCTIONS", "TYPE_ORDER", "collide", "collide_rows",
    "kind_code", "pair_function", "is_canonical", "plane_sphere", "plane_capsule", "plane_box", "sphere_sphere",
    "sphere_capsule", "sphere_box", "capsule_capsule", "capsule_box", "box_box",
]
