"""Broad phase: world axis-aligned bounding boxes and their overlap test.

``candidate_pairs`` (:mod:`engine.collision.broadphase`) lists at build time
every body pair that may ever collide; each step culls that fixed list with
these boxes. Units: metres.
"""

from __future__ import annotations

import math

from ...shapes import BOX, CAPSULE, NONE, PLANE, SPHERE
from ..jit import kernel
from ..vec import load3, load4, quat_to_matrix


@kernel
def body_bounds(kind, params, pos, quat):
    """World AABB (lo, hi) of one body of shape type ``kind`` with shape
    parameters ``params`` (tuple), position ``pos`` (m) and orientation ``quat``.

    Spheres: centre ± r; capsules: ± (r + half_length |axis|) per world axis;
    boxes: ± sum_j h_j |axis_j| per world axis (the rotated box's extent);
    planes are unbounded (±inf); bodies without a shape get an empty box
    (lo = +inf, hi = -inf) that overlaps nothing.
    """
    inf = math.inf
    if kind == PLANE:
        return (-inf, -inf, -inf), (inf, inf, inf)
    if kind == NONE:
        return (inf, inf, inf), (-inf, -inf, -inf)
    if kind == SPHERE:
        half = (params[0], params[0], params[0])
    elif kind == CAPSULE:
        z = quat_to_matrix(quat)[2]  # the capsule axis
        half = (params[0] + params[1] * abs(z[0]), params[0] + params[1] * abs(z[1]),
                params[0] + params[1] * abs(z[2]))
    elif kind == BOX:
        m = quat_to_matrix(quat)  # columns: the box axes
        half = (params[0] * abs(m[0][0]) + params[1] * abs(m[1][0]) + params[2] * abs(m[2][0]),
                params[0] * abs(m[0][1]) + params[1] * abs(m[1][1]) + params[2] * abs(m[2][1]),
                params[0] * abs(m[0][2]) + params[1] * abs(m[1][2]) + params[2] * abs(m[2][2]))
    else:
        half = (0.0, 0.0, 0.0)
    return ((pos[0] - half[0], pos[1] - half[1], pos[2] - half[2]),
            (pos[0] + half[0], pos[1] + half[1], pos[2] + half[2]))


@kernel
def boxes_overlap(lo_a, hi_a, lo_b, hi_b, grow):
    """The boxes (lo_a, hi_a) and (lo_b, hi_b), each grown by ``grow / 2``
    metres on every side, overlap (``grow`` m added to each comparison)."""
    return (lo_a[0] <= hi_b[0] + grow and lo_b[0] <= hi_a[0] + grow
            and lo_a[1] <= hi_b[1] + grow and lo_b[1] <= hi_a[1] + grow
            and lo_a[2] <= hi_b[2] + grow and lo_b[2] <= hi_a[2] + grow)


@kernel
def bounds_rows(kind, params, pos, quat, lo, hi):
    """AABBs of R bodies: kind (R,) shape types, params (R, 3), pos (R, 3) m,
    quat (R, 4) -> lo, hi (R, 3) m."""
    for i in range(kind.shape[0]):
        l, h = body_bounds(kind[i], load3(params, i), load3(pos, i), load4(quat, i))
        for c in range(3):
            lo[i, c] = l[c]
            hi[i, c] = h[c]


@kernel
def overlap_rows(lo, hi, pairs_a, pairs_b, grow, out):
    """out[w, p]: the AABBs lo, hi (W, N, 3) of bodies pairs_a[p] and
    pairs_b[p] in world w overlap with ``grow[w, p]`` m added to each comparison."""
    for w in range(out.shape[0]):
        for p in range(out.shape[1]):
            a, b = pairs_a[p], pairs_b[p]
            out[w, p] = boxes_overlap((lo[w, a, 0], lo[w, a, 1], lo[w, a, 2]), (hi[w, a, 0], hi[w, a, 1], hi[w, a, 2]),
                                      (lo[w, b, 0], lo[w, b, 1], lo[w, b, 2]), (hi[w, b, 0], hi[w, b, 1], hi[w, b, 2]),
                                      grow[w, p])
