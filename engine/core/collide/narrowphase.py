"""Narrow phase: the pair kind codes, and the narrow phase of a world by those codes.

Each candidate pair gets, when the model is compiled, the code of its
canonical shape pair (shape a comes first in the order plane, sphere,
capsule, box); the narrow phase of a world then calls each pair's kernel
by a branch on its code, with no Python in the loop.
"""

from __future__ import annotations

from ...shapes import BOX, CAPSULE, PLANE, SPHERE
from ..jit import kernel
from .box_round import capsule_box, sphere_box
from .boxes import box_box
from .manifold import INVALID_SEPARATION, empty, least_separation, manifold, store
from .plane import plane_box, plane_capsule, plane_sphere
from .round import capsule_capsule, sphere_capsule, sphere_sphere

PLANE_SPHERE = 0
PLANE_CAPSULE = 1
PLANE_BOX = 2
SPHERE_SPHERE = 3
SPHERE_CAPSULE = 4
SPHERE_BOX = 5
CAPSULE_CAPSULE = 6
CAPSULE_BOX = 7
BOX_BOX = 8

#: Code of each canonical (type_a, type_b).
KIND_CODES = {
    (PLANE, SPHERE): PLANE_SPHERE,
    (PLANE, CAPSULE): PLANE_CAPSULE,
    (PLANE, BOX): PLANE_BOX,
    (SPHERE, SPHERE): SPHERE_SPHERE,
    (SPHERE, CAPSULE): SPHERE_CAPSULE,
    (SPHERE, BOX): SPHERE_BOX,
    (CAPSULE, CAPSULE): CAPSULE_CAPSULE,
    (CAPSULE, BOX): CAPSULE_BOX,
    (BOX, BOX): BOX_BOX,
}


@kernel
def narrow_world(w, pair_kind, pair_a, pair_b, position, orientation, shape_params, margin, keep, normal, point,
                 separation, valid, contact_separation, poly):
    """The narrow phase of world ``w``: the manifold of every pair p with
    ``keep[w, p]`` set on entry (its AABBs overlap) into row w P + p.

    pair_kind, pair_a, pair_b (P,): kind codes and bodies (shape a, shape b in
    canonical order) of the pairs; position (W, N, 3) m, orientation
    (W, N, 4), shape_params (N, 3): the bodies; margin (W, P) m: each pair's
    margin. Writes normal (W P, 3), point (W P, 4, 3), separation (W P, 4),
    valid (W P, 4); rows of pairs not looked at hold the normal 0 and empty
    slots. On return keep[w, p] tells whether the pair has a valid point and
    contact_separation[w, p] (W, P) is its least valid separation (+inf
    without one). ``poly[w]`` is the box pair's (2, 8, 3) scratch.
    """
    P = pair_a.shape[0]
    for p in range(P):
        r = w * P + p
        if not keep[w, p]:
            store(normal, point, separation, valid, r, manifold((0.0, 0.0, 0.0), empty(), empty(), empty(), empty()))
            contact_separation[w, p] = INVALID_SEPARATION
            continue
        a, b = pair_a[p], pair_b[p]
        pa = (position[w, a, 0], position[w, a, 1], position[w, a, 2])
        qa = (orientation[w, a, 0], orientation[w, a, 1], orientation[w, a, 2], orientation[w, a, 3])
        ha = (shape_params[a, 0], shape_params[a, 1], shape_params[a, 2])
        pb = (position[w, b, 0], position[w, b, 1], position[w, b, 2])
        qb = (orientation[w, b, 0], orientation[w, b, 1], orientation[w, b, 2], orientation[w, b, 3])
        hb = (shape_params[b, 0], shape_params[b, 1], shape_params[b, 2])
        mg = margin[w, p]
        # The dispatch by kind code sits in this loop (not in a function of its
        # own) so that the small pair kernels are inlined here.
        kind = pair_kind[p]
        if kind == PLANE_SPHERE:
            m = plane_sphere(pa, qa, ha, pb, qb, hb, mg)
        elif kind == PLANE_CAPSULE:
            m = plane_capsule(pa, qa, ha, pb, qb, hb, mg)
        elif kind == PLANE_BOX:
            m = plane_box(pa, qa, ha, pb, qb, hb, mg)
        elif kind == SPHERE_SPHERE:
            m = sphere_sphere(pa, qa, ha, pb, qb, hb, mg)
        elif kind == SPHERE_CAPSULE:
            m = sphere_capsule(pa, qa, ha, pb, qb, hb, mg)
        elif kind == SPHERE_BOX:
            m = sphere_box(pa, qa, ha, pb, qb, hb, mg)
        elif kind == CAPSULE_CAPSULE:
            m = capsule_capsule(pa, qa, ha, pb, qb, hb, mg)
        elif kind == CAPSULE_BOX:
            m = capsule_box(pa, qa, ha, pb, qb, hb, mg)
        else:
            m = box_box(pa, qa, ha, pb, qb, hb, mg, poly, w)
        store(normal, point, separation, valid, r, m)
        least = least_separation(m)
        keep[w, p] = least < INVALID_SEPARATION
        contact_separation[w, p] = least


@kernel
def narrow_rows(pair_kind, pair_a, pair_b, position, orientation, shape_params, margin, keep, normal, point,
                separation, valid, contact_separation, poly):
    """``narrow_world`` for every world, on the calling thread."""
    for w in range(position.shape[0]):
        narrow_world(w, pair_kind, pair_a, pair_b, position, orientation, shape_params, margin, keep, normal, point,
                     separation, valid, contact_separation, poly)
