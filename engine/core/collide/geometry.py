"""Scalar geometric helpers shared by the pair kernels (one pair at a time).

Vectors are tuples (:mod:`engine.core.vec`). Sums are written out in a
fixed order (a dot product is (x0 y0 + x1 y1) + x2 y2), which the kernels'
IEEE semantics keep, so each pair's result is one fixed function of its
inputs; the guards against zero lengths pick a fixed fallback instead of
dividing by zero. Units: metres.
"""

from __future__ import annotations

import math

from ..jit import kernel
from ..vec import dot, rotate

#: Distances (m) below which a direction is treated as undefined and a
#: fallback direction is used instead.
TINY_LENGTH = 1e-9

#: Squared segment lengths (m²) below this make a segment a point.
DEGENERATE_SEGMENT = 1e-18

#: Segments whose a e - b² (Ericson's denominator) is below this fraction of
#: a e are parallel.
PARALLEL_DENOM = 1e-12


@kernel
def clip(x, lo, hi):
    """min(max(x, lo), hi), as ``np.clip`` (a NaN stays NaN)."""
    y = lo if x < lo else x
    return hi if y > hi else y


@kernel
def clip3(p, h):
    """The point of the box |x_i| <= h_i nearest to p (component-wise clamp)."""
    return (clip(p[0], -h[0], h[0]), clip(p[1], -h[1], h[1]), clip(p[2], -h[2], h[2]))


@kernel
def sign_nonneg(x):
    """+1 where ``x >= 0``, -1 elsewhere (never 0, so it is safe as an orientation)."""
    return 1.0 if x >= 0.0 else -1.0


@kernel
def local_z(q):
    """World direction of a body's local +z axis (capsule axis, plane normal)."""
    return rotate(q, (0.0, 0.0, 1.0))


@kernel
def normalize_or(v, fallback):
    """(unit vector along v, |v|); ``fallback`` as the direction when |v| <= TINY_LENGTH."""
    length = math.sqrt(dot(v, v))
    if length > TINY_LENGTH:
        return (v[0] / length, v[1] / length, v[2] / length), length
    return fallback, length


@kernel
def perpendicular_fallback(axis):
    """A fixed unit vector perpendicular to the unit vector ``axis``.

    The world +z axis with its component along ``axis`` removed; if ``axis``
    is (nearly) vertical, the world +x axis likewise. Used as the contact
    normal when two capsule axes meet, where any perpendicular is as good.
    """
    vz = (0.0 - axis[0] * axis[2], 0.0 - axis[1] * axis[2], 1.0 - axis[2] * axis[2])
    if dot(vz, vz) > 1e-6:
        v = vz
    else:
        v = (1.0 - axis[0] * axis[0], 0.0 - axis[1] * axis[0], 0.0 - axis[2] * axis[0])
    n = math.sqrt(dot(v, v))
    return (v[0] / n, v[1] / n, v[2] / n)


@kernel
def closest_points_segments(p1, d1, p2, d2):
    """Parameters ``(s, t)`` in [0, 1] of the closest points ``p1 + s d1`` and
    ``p2 + t d2`` of two segments.

    Ericson, *Real-Time Collision Detection* (2005), section 5.1.9
    (ClosestPtSegmentSegment). Degenerate segments (zero length) and
    parallel segments are handled: for parallel segments ``s`` starts at 0
    and both are then clamped, which gives a pair inside the overlap when
    the segments overlap.
    """
    r = (p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2])
    a = dot(d1, d1)
    e = dot(d2, d2)
    f = dot(d2, r)
    a_ok = a > DEGENERATE_SEGMENT
    e_ok = e > DEGENERATE_SEGMENT
    if not a_ok and not e_ok:  # two points
        return 0.0, 0.0
    if not a_ok:  # a point against segment 2
        return 0.0, clip(f / e, 0.0, 1.0)
    c = dot(d1, r)
    if not e_ok:  # segment 1 against a point
        return clip(-c / a, 0.0, 1.0), 0.0
    b = dot(d1, d2)
    denom = a * e - b * b
    s = 0.0
    if denom > PARALLEL_DENOM * a * e:
        s = clip((b * f - c * e) / denom, 0.0, 1.0)
    t = (b * s + f) / e
    if t < 0.0:
        s = clip(-c / a, 0.0, 1.0)
    elif t > 1.0:
        s = clip((b - c) / a, 0.0, 1.0)
    return s, clip(t, 0.0, 1.0)


@kernel
def box_dist2(p, h):
    """Squared distance (m²) from the local point p to the box |x_i| <= h_i."""
    q = clip3(p, h)
    d = (p[0] - q[0], p[1] - q[1], p[2] - q[2])
    return dot(d, d)


@kernel
def _order(x, y):
    return (x, y) if x <= y else (y, x)


@kernel
def sort6(x0, x1, x2, x3, x4, x5):
    """The six numbers in ascending order (a 12-comparator sorting network)."""
    x0, x5 = _order(x0, x5)
    x1, x3 = _order(x1, x3)
    x2, x4 = _order(x2, x4)
    x1, x2 = _order(x1, x2)
    x3, x4 = _order(x3, x4)
    x0, x3 = _order(x0, x3)
    x2, x5 = _order(x2, x5)
    x0, x1 = _order(x0, x1)
    x2, x3 = _order(x2, x3)
    x4, x5 = _order(x4, x5)
    x1, x2 = _order(x1, x2)
    x3, x4 = _order(x3, x4)
    return x0, x1, x2, x3, x4, x5


@kernel
def sort4i(x0, x1, x2, x3):
    """Four integers in ascending order (a 5-comparator sorting network)."""
    x0, x1 = _order(x0, x1)
    x2, x3 = _order(x2, x3)
    x0, x2 = _order(x0, x2)
    x1, x3 = _order(x1, x3)
    x1, x2 = _order(x1, x2)
    return x0, x1, x2, x3


@kernel
def _order_keyed(x, i, y, j):
    """The keyed values (x, i) and (y, j) in (value, key) order."""
    if y < x or (y == x and j < i):
        return y, j, x, i
    return x, i, y, j


@kernel
def lowest4_of8(h):
    """Indices of the 4 smallest of the 8 numbers ``h`` (the lower index on a
    tie, as a stable argsort), in increasing index order.

    A 19-comparator sorting network on (value, index) keys, then the first
    4 indices sorted.
    """
    x0, i0, x1, i1 = h[0], 0, h[1], 1
    x2, i2, x3, i3 = h[2], 2, h[3], 3
    x4, i4, x5, i5 = h[4], 4, h[5], 5
    x6, i6, x7, i7 = h[6], 6, h[7], 7
    x0, i0, x2, i2 = _order_keyed(x0, i0, x2, i2)
    x1, i1, x3, i3 = _order_keyed(x1, i1, x3, i3)
    x4, i4, x6, i6 = _order_keyed(x4, i4, x6, i6)
    x5, i5, x7, i7 = _order_keyed(x5, i5, x7, i7)
    x0, i0, x4, i4 = _order_keyed(x0, i0, x4, i4)
    x1, i1, x5, i5 = _order_keyed(x1, i1, x5, i5)
    x2, i2, x6, i6 = _order_keyed(x2, i2, x6, i6)
    x3, i3, x7, i7 = _order_keyed(x3, i3, x7, i7)
    x0, i0, x1, i1 = _order_keyed(x0, i0, x1, i1)
    x2, i2, x3, i3 = _order_keyed(x2, i2, x3, i3)
    x4, i4, x5, i5 = _order_keyed(x4, i4, x5, i5)
    x6, i6, x7, i7 = _order_keyed(x6, i6, x7, i7)
    x2, i2, x4, i4 = _order_keyed(x2, i2, x4, i4)
    x3, i3, x5, i5 = _order_keyed(x3, i3, x5, i5)
    x1, i1, x4, i4 = _order_keyed(x1, i1, x4, i4)
    x3, i3, x6, i6 = _order_keyed(x3, i3, x6, i6)
    x1, i1, x2, i2 = _order_keyed(x1, i1, x2, i2)
    x3, i3, x4, i4 = _order_keyed(x3, i3, x4, i4)
    return sort4i(i0, i1, i2, i3)
