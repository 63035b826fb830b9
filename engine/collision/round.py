"""Pairs of round shapes: sphere-sphere, sphere-capsule, capsule-capsule.

A capsule is the set of points within ``radius`` of its core segment, so each
pair reduces to the closest points of two core features (points or segments):
the normal is the unit vector between them and the separation is their
distance minus both radii. Units: metres.
"""

from __future__ import annotations

import numpy as np

from ..math3d import cross, dot, norm
from .geometry import EZ, closest_points_segments, local_z, normalize_or, perpendicular_fallback
from .manifold import Manifold, assemble

#: Nearly parallel capsules get two points (the ends of their overlap) when
#: the sideways drift of one axis along the overlap, sin(angle) * overlap,
#: is below this fraction of the summed radii; otherwise they cross and get
#: one point.
PARALLEL_DRIFT = 0.1

#: Overlaps shorter than this (m) give one point, not two coincident ones.
MIN_OVERLAP = 1e-6


def _round_contact(ca, ra, cb, rb, fallback):
    """Normal, point (midway between surfaces) and separation of the spheres
    (ca, ra) and (cb, rb); ``fallback`` is the normal when the centres meet."""
    n, dist = normalize_or(cb - ca, fallback)
    sep = dist - ra - rb
    surface_a = ca + n * ra[..., None]
    surface_b = cb - n * rb[..., None]
    return n, 0.5 * (surface_a + surface_b), sep


def sphere_sphere(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Sphere a, sphere b: one point; coincident centres use the normal +z."""
    ra = np.broadcast_to(params_a[..., 0], pos_a.shape[:-1])
    rb = np.broadcast_to(params_b[..., 0], pos_b.shape[:-1])
    n, point, sep = _round_contact(pos_a, ra, pos_b, rb, EZ)
    return assemble(n, point[..., None, :], sep[..., None], None, margin)


def sphere_capsule(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Sphere a, capsule b: one point, from the sphere centre's closest point on
    the capsule segment. A centre on the axis uses a normal perpendicular to it."""
    ra = params_a[..., 0]
    rb = params_b[..., 0]
    hl = params_b[..., 1]
    u = local_z(quat_b)
    tau = np.clip(dot(pos_a - pos_b, u), -hl, hl)
    core = pos_b + u * tau[..., None]
    n, point, sep = _round_contact(pos_a, ra, core, rb, perpendicular_fallback(u))
    return assemble(n, point[..., None, :], sep[..., None], None, margin)


def capsule_capsule(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Capsule a, capsule b: one point, or two for (nearly) parallel capsules.

    Closest points of the two segments (Ericson 5.1.9) give the normal. When
    the axes are parallel within ``PARALLEL_DRIFT`` and their projections
    overlap, the ends of the overlap on a's axis give two points (slot 0 at
    the end towards a's -z end), each with its own separation: the distance
    from a's axis point to b's segment minus the radii. Crossing or
    end-to-end capsules give one point in slot 0. Segments that meet use a
    normal perpendicular to both axes (or to a's axis, if parallel).
    """
    ra = params_a[..., 0]
    hla = params_a[..., 1]
    rb = params_b[..., 0]
    hlb = params_b[..., 1]
    ua = local_z(quat_a)
    ub = local_z(quat_b)
    a0 = pos_a - ua * hla[..., None]
    b0 = pos_b - ub * hlb[..., None]
    da = ua * (2.0 * hla)[..., None]
    db = ub * (2.0 * hlb)[..., None]
    s, t = closest_points_segments(a0, da, b0, db)
    ca = a0 + da * s[..., None]
    cb = b0 + db * t[..., None]

    axis_cross = cross(ua, ub)
    sin_angle = norm(axis_cross)
    fallback = np.where((sin_angle > 1e-6)[..., None], axis_cross / np.maximum(sin_angle, 1e-6)[..., None],
                        perpendicular_fallback(ua))
    rsum = ra + rb
    n, point, sep = _round_contact(ca, ra, cb, rb, fallback)

    # Overlap of b's segment projected on a's axis (coordinates from a's centre).
    tb0 = dot(b0 - pos_a, ua)
    tb1 = tb0 + 2.0 * hlb * dot(ub, ua)
    lo = np.maximum(np.minimum(tb0, tb1), -hla)
    hi = np.minimum(np.maximum(tb0, tb1), hla)
    overlap = hi - lo
    two = (overlap > MIN_OVERLAP) & (sin_angle * overlap <= PARALLEL_DRIFT * rsum)

    pts, seps = [], []
    for tk in (lo, hi):
        pa = pos_a + ua * tk[..., None]
        tau = np.clip(dot(pa - pos_b, ub), -hlb, hlb)
        pb = pos_b + ub * tau[..., None]
        dist = norm(pb - pa)
        sep_k = dist - rsum
        # midway between a's surface and b's surface along the pair normal
        pts.append(0.5 * (pa + n * ra[..., None] + pb - n * rb[..., None]))
        seps.append(sep_k)

    two3 = two[..., None]
    p0 = np.where(two3, pts[0], point)
    p1 = np.where(two3, pts[1], point)
    s0 = np.where(two, seps[0], sep)
    s1 = np.where(two, seps[1], np.inf)
    return assemble(n, np.stack((p0, p1), axis=-2), np.stack((s0, s1), axis=-1),
                    np.stack((np.ones_like(two), two), axis=-1), margin)
