"""Pairs of round shapes: sphere-sphere, sphere-capsule, capsule-capsule.

A capsule is the set of points within ``radius`` of its core segment, so each
pair reduces to the closest points of two core features (points or segments):
the normal is the unit vector between them and the separation is their
distance minus both radii. Arguments and result as in :mod:`.plane`.
Units: metres.
"""

from __future__ import annotations

import math

from ..jit import kernel
from ..vec import cross, dot, sub
from .geometry import clip, closest_points_segments, local_z, normalize_or, perpendicular_fallback
from .manifold import candidate, empty, manifold, single

#: Nearly parallel capsules get two points (the ends of their overlap) when
#: the sideways drift of one axis along the overlap, sin(angle) * overlap,
#: is below this fraction of the summed radii; otherwise they cross and get
#: one point.
PARALLEL_DRIFT = 0.1

#: Overlaps shorter than this (m) give one point, not two coincident ones.
MIN_OVERLAP = 1e-6

#: Axes whose cross product is shorter than this (the sine of their angle)
#: are parallel: the fallback normal is then perpendicular to a's axis only.
PARALLEL_SIN = 1e-6


@kernel
def round_contact(ca, ra, cb, rb, fallback):
    """Normal, point (midway between surfaces) and separation of the spheres
    (ca, ra) and (cb, rb); ``fallback`` is the normal when the centres meet."""
    n, dist = normalize_or(sub(cb, ca), fallback)
    sep = dist - ra - rb
    p = (0.5 * ((ca[0] + n[0] * ra) + (cb[0] - n[0] * rb)),
         0.5 * ((ca[1] + n[1] * ra) + (cb[1] - n[1] * rb)),
         0.5 * ((ca[2] + n[2] * ra) + (cb[2] - n[2] * rb)))
    return n, p, sep


@kernel
def sphere_sphere(pa, qa, ha, pb, qb, hb, margin):
    """Sphere a, sphere b: one point; coincident centres use the normal +z."""
    n, p, sep = round_contact(pa, ha[0], pb, hb[0], (0.0, 0.0, 1.0))
    return single(n, p, sep, margin)


@kernel
def sphere_capsule(pa, qa, ha, pb, qb, hb, margin):
    """Sphere a, capsule b: one point, from the sphere centre's closest point on
    the capsule segment. A centre on the axis uses a normal perpendicular to it."""
    hl = hb[1]
    u = local_z(qb)
    tau = clip(dot(sub(pa, pb), u), -hl, hl)
    core = (pb[0] + u[0] * tau, pb[1] + u[1] * tau, pb[2] + u[2] * tau)
    n, p, sep = round_contact(pa, ha[0], core, hb[0], perpendicular_fallback(u))
    return single(n, p, sep, margin)


@kernel
def _overlap_end(pa, ua, pb, ub, hlb, ra, rb, n, tk, margin):
    """The slot of a's axis point at ``tk`` (m from a's centre) against b's
    segment: its distance to the segment minus the radii, the point midway
    between a's and b's surfaces along the pair normal ``n``."""
    pk = (pa[0] + ua[0] * tk, pa[1] + ua[1] * tk, pa[2] + ua[2] * tk)
    tau = clip(dot(sub(pk, pb), ub), -hlb, hlb)
    qk = (pb[0] + ub[0] * tau, pb[1] + ub[1] * tau, pb[2] + ub[2] * tau)
    d = sub(qk, pk)
    sep_k = math.sqrt(dot(d, d)) - (ra + rb)
    mid = (0.5 * (pk[0] + n[0] * ra + qk[0] - n[0] * rb),
           0.5 * (pk[1] + n[1] * ra + qk[1] - n[1] * rb),
           0.5 * (pk[2] + n[2] * ra + qk[2] - n[2] * rb))
    return candidate(mid, sep_k, True, margin)


@kernel
def capsule_capsule(pa, qa, ha, pb, qb, hb, margin):
    """Capsule a, capsule b: one point, or two for (nearly) parallel capsules.

    Closest points of the two segments (Ericson 5.1.9) give the normal. When
    the axes are parallel within ``PARALLEL_DRIFT`` and their projections
    overlap, the ends of the overlap on a's axis give two points (slot 0 at
    the end towards a's -z end), each with its own separation: the distance
    from a's axis point to b's segment minus the radii. Crossing or
    end-to-end capsules give one point in slot 0 (slot 1 then holds the same
    point, not valid). Segments that meet use a normal perpendicular to both
    axes (or to a's axis, if parallel).
    """
    ra, hla = ha[0], ha[1]
    rb, hlb = hb[0], hb[1]
    ua = local_z(qa)
    ub = local_z(qb)
    a0 = (pa[0] - ua[0] * hla, pa[1] - ua[1] * hla, pa[2] - ua[2] * hla)
    b0 = (pb[0] - ub[0] * hlb, pb[1] - ub[1] * hlb, pb[2] - ub[2] * hlb)
    la, lb = 2.0 * hla, 2.0 * hlb
    da = (ua[0] * la, ua[1] * la, ua[2] * la)
    db = (ub[0] * lb, ub[1] * lb, ub[2] * lb)
    s, t = closest_points_segments(a0, da, b0, db)
    ca = (a0[0] + da[0] * s, a0[1] + da[1] * s, a0[2] + da[2] * s)
    cb = (b0[0] + db[0] * t, b0[1] + db[1] * t, b0[2] + db[2] * t)

    axis_cross = cross(ua, ub)
    sin_angle = math.sqrt(dot(axis_cross, axis_cross))
    if sin_angle > PARALLEL_SIN:
        fallback = (axis_cross[0] / sin_angle, axis_cross[1] / sin_angle, axis_cross[2] / sin_angle)
    else:
        fallback = perpendicular_fallback(ua)
    rsum = ra + rb
    n, p, sep = round_contact(ca, ra, cb, rb, fallback)

    # Overlap of b's segment projected on a's axis (coordinates from a's centre).
    tb0 = dot(sub(b0, pa), ua)
    tb1 = tb0 + lb * dot(ub, ua)
    lo = max(min(tb0, tb1), -hla)
    hi = min(max(tb0, tb1), hla)
    overlap = hi - lo
    if overlap > MIN_OVERLAP and sin_angle * overlap <= PARALLEL_DRIFT * rsum:
        return manifold(n, _overlap_end(pa, ua, pb, ub, hlb, ra, rb, n, lo, margin),
                        _overlap_end(pa, ua, pb, ub, hlb, ra, rb, n, hi, margin), empty(), empty())
    return manifold(n, candidate(p, sep, True, margin), candidate(p, math.inf, False, margin), empty(), empty())
