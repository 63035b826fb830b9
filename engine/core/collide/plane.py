"""Plane against sphere, capsule and box (the plane is always shape a).

A plane's surface passes through its body's position with outward normal
along the body's local +z axis; it is solid below. The contact normal is the
plane normal (from the plane to the other shape). Each candidate point's
separation is its signed height above the plane minus the shape's radius,
and the point lies midway between the plane and the shape's surface.

Arguments of every pair kernel: positions (m) and unit orientations
(w, x, y, z) of a and b as tuples, shape parameters ha, hb as tuples (see
:mod:`engine.shapes`) and the margin (m); each returns the manifold tuple
of :mod:`.manifold`. Units: metres.
"""

from __future__ import annotations

from ..jit import kernel
from ..vec import dot, quat_to_matrix, sub
from .geometry import local_z, lowest4_of8
from .manifold import candidate, empty, manifold


@kernel
def _lowered(p, n, c):
    """p - c n."""
    return (p[0] - n[0] * c, p[1] - n[1] * c, p[2] - n[2] * c)


@kernel
def plane_sphere(pa, qa, ha, pb, qb, hb, margin):
    """Plane a, sphere b: one point (slot 0) below the sphere centre."""
    n = local_z(qa)
    radius = hb[0]
    sep = dot(sub(pb, pa), n) - radius
    p = _lowered(pb, n, radius + 0.5 * sep)
    return manifold(n, candidate(p, sep, True, margin), empty(), empty(), empty())


@kernel
def _end_slot(pa, n, end, radius, margin):
    sep = dot(sub(end, pa), n) - radius
    return candidate(_lowered(end, n, radius + 0.5 * sep), sep, True, margin)


@kernel
def plane_capsule(pa, qa, ha, pb, qb, hb, margin):
    """Plane a, capsule b: the two segment ends (slot 0: local -z end, slot 1: +z end)."""
    n = local_z(qa)
    radius = hb[0]
    hl = hb[1]
    u = local_z(qb)
    end0 = (pb[0] - u[0] * hl, pb[1] - u[1] * hl, pb[2] - u[2] * hl)
    end1 = (pb[0] + u[0] * hl, pb[1] + u[1] * hl, pb[2] + u[2] * hl)
    return manifold(n, _end_slot(pa, n, end0, radius, margin), _end_slot(pa, n, end1, radius, margin), empty(),
                    empty())


@kernel
def _sign(k, bit):
    """Sign along local axis ``bit`` (4: x, 2: y, 1: z) of box corner ``k``."""
    return 1.0 if k & bit else -1.0


@kernel
def _corner_slot(pb, m, hb, n, heights, k, margin):
    """Slot of box corner k: the corner (its signs from the bits of k) lowered
    by half its height, towards the plane."""
    sx, sy, sz = _sign(k, 4), _sign(k, 2), _sign(k, 1)
    o0 = (m[0][0] * hb[0], m[0][1] * hb[0], m[0][2] * hb[0])
    o1 = (m[1][0] * hb[1], m[1][1] * hb[1], m[1][2] * hb[1])
    o2 = (m[2][0] * hb[2], m[2][1] * hb[2], m[2][2] * hb[2])
    corner = (pb[0] + sx * o0[0] + sy * o1[0] + sz * o2[0],
              pb[1] + sx * o0[1] + sy * o1[1] + sz * o2[1],
              pb[2] + sx * o0[2] + sy * o1[2] + sz * o2[2])
    hk = heights[k]
    return candidate(_lowered(corner, n, 0.5 * hk), hk, True, margin)


@kernel
def plane_box(pa, qa, ha, pb, qb, hb, margin):
    """Plane a, box b: the 4 deepest of the 8 corners.

    Corner k has signs (bit 2, bit 1, bit 0 of k set = +) along the box's
    local (x, y, z) axes. The 4 lowest corners (the lower index on a tie)
    sit in the slots in increasing corner index, so a box resting on a face
    keeps each corner in the same slot. A box lying flat gives 4 valid
    points, on an edge 2, on a corner 1.
    """
    n = local_z(qa)
    m = quat_to_matrix(qb)  # columns: the box axes in the world
    centre = dot(sub(pb, pa), n)
    share0 = hb[0] * dot(m[0], n)
    share1 = hb[1] * dot(m[1], n)
    share2 = hb[2] * dot(m[2], n)
    # Height of corner k above the plane.
    heights = (centre - share0 - share1 - share2, centre - share0 - share1 + share2,
               centre - share0 + share1 - share2, centre - share0 + share1 + share2,
               centre + share0 - share1 - share2, centre + share0 - share1 + share2,
               centre + share0 + share1 - share2, centre + share0 + share1 + share2)
    c0, c1, c2, c3 = lowest4_of8(heights)
    return manifold(n, _corner_slot(pb, m, hb, n, heights, c0, margin),
                    _corner_slot(pb, m, hb, n, heights, c1, margin),
                    _corner_slot(pb, m, hb, n, heights, c2, margin),
                    _corner_slot(pb, m, hb, n, heights, c3, margin))
