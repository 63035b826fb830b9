"""Round shapes against boxes: sphere-box and capsule-box (the box is shape b).

Work happens in the box's local frame, where the box is the axis-aligned
set |x_i| <= h_i. Separated shapes use exact closest points (so speculative
contacts carry true gaps); a core point or segment touching or inside the
box uses the axis of least penetration. Arguments and result as in
:mod:`.plane`. Units: metres.
"""

from __future__ import annotations

import math

from ..jit import kernel
from ..vec import abs3, add, dot, neg, pick3, rotate, rotate_inv, sub
from .geometry import box_dist2, clip, clip3, closest_points_segments, local_z, sign_nonneg, sort6
from .manifold import candidate, empty, manifold, single

#: Core features closer to the box than this (m) count as touching it; the
#: normal then comes from the least-penetration axis, not from the gap.
TOUCH = 1e-7

#: SAT bias: an edge axis replaces the best face axis only when its
#: separation is larger by this fraction of |face separation| plus EDGE_ABS (m)
#: (faces give more stable normals and two-point contacts).
EDGE_REL = 0.05
EDGE_ABS = 5e-4

#: Clipped segment parts shorter than this (m) give one point, not two coincident ones.
MIN_CLIP = 1e-6

#: Edge axes u x e_i shorter than this (the sine of the angle between the
#: segment and the box edge) are parallel to the edge and not tested.
PARALLEL_SIN = 1e-6


@kernel
def _axis(i, value):
    """value e_i: the coordinate vector i (0, 1 or 2) scaled, as (1 or 0) * value."""
    return ((1.0 if i == 0 else 0.0) * value, (1.0 if i == 1 else 0.0) * value, (1.0 if i == 2 else 0.0) * value)


@kernel
def sphere_box(pa, qa, ha, pb, qb, hb, margin):
    """Sphere a, box b: one point.

    Outside: closest point on the box (clamp, Ericson 5.1.4). Centre inside:
    the nearest face (the first axis on ties), whose outward normal points
    at the sphere.
    """
    radius = ha[0]
    c = rotate_inv(qb, sub(pa, pb))
    q = clip3(c, hb)
    gap = sub(c, q)
    dist = math.sqrt(dot(gap, gap))
    if dist > TOUCH:
        n_local = (gap[0] / dist, gap[1] / dist, gap[2] / dist)  # box -> sphere
        surface_box = q
        sep = dist - radius
    else:
        depth = (hb[0] - abs(c[0]), hb[1] - abs(c[1]), hb[2] - abs(c[2]))  # >= 0 inside
        face = 0
        if depth[1] < depth[face]:
            face = 1
        if depth[2] < pick3(depth, face):
            face = 2
        sgn = sign_nonneg(pick3(c, face))
        n_local = _axis(face, sgn)
        hf = sgn * pick3(hb, face)
        surface_box = (hf if face == 0 else c[0], hf if face == 1 else c[1], hf if face == 2 else c[2])
        sep = -pick3(depth, face) - radius
    surface_sphere = (c[0] - n_local[0] * radius, c[1] - n_local[1] * radius, c[2] - n_local[2] * radius)
    mid = (0.5 * (surface_box[0] + surface_sphere[0]), 0.5 * (surface_box[1] + surface_sphere[1]),
           0.5 * (surface_box[2] + surface_sphere[2]))
    return single(neg(rotate(qb, n_local)), add(pb, rotate(qb, mid)), sep, margin)


@kernel
def _knot(h, p, d):
    """Where the segment coordinate p + t d crosses the face plane ±h, clamped to [0, 1]."""
    return clip((h - p) / d, 0.0, 1.0) if d != 0.0 else 0.0


@kernel
def segment_box_closest(p0, d, h):
    """Parameter t in [0, 1] of the point of segment ``p0 + t d`` closest to the
    box |x| <= h, and the squared distance (m²) there.

    The squared distance is a convex piecewise quadratic in t whose pieces
    change where the segment crosses a face plane x_i = ±h_i; minimising each
    of the (at most 7) pieces in closed form and keeping the best (the first
    on a tie) is exact.
    """
    k1, k2, k3, k4, k5, k6 = sort6(_knot(-h[0], p0[0], d[0]), _knot(h[0], p0[0], d[0]),
                                   _knot(-h[1], p0[1], d[1]), _knot(h[1], p0[1], d[1]),
                                   _knot(-h[2], p0[2], d[2]), _knot(h[2], p0[2], d[2]))
    knots = (0.0, k1, k2, k3, k4, k5, k6, 1.0)  # every knot is in [0, 1]
    best_t = 0.0
    best_d2 = math.inf
    for k in range(7):
        lo, hi = knots[k], knots[k + 1]
        mid = 0.5 * (lo + hi)
        num = 0.0
        den = 0.0
        for i in range(3):
            x = p0[i] + mid * d[i]
            target = clip(x, -h[i], h[i])
            if x != target:  # this coordinate is clamped on this piece
                num = num + d[i] * (p0[i] - target)
                den = den + d[i] * d[i]
            else:
                num = num + 0.0
                den = den + 0.0
        t = -num / den if den > 0.0 else mid
        t = min(max(t, lo), hi)
        d2 = box_dist2((p0[0] + d[0] * t, p0[1] + d[1] * t, p0[2] + d[2] * t), h)
        if d2 < best_d2:
            best_t = t
            best_d2 = d2
    return best_t, best_d2


@kernel
def capsule_box(pa, qa, ha, pb, qb, hb, margin):
    """Capsule a, box b: one point, or two when the capsule lies along a face.

    1. Closest points of the capsule segment and the box (exact, see
       ``segment_box_closest``). If apart and the closest box point is inside
       a face, that face is the contact feature; if on an edge or corner, one
       point.
    2. If the segment touches or enters the box: SAT over the 3 face normals
       and the 3 segment x box-edge axes (Ericson 5.2.1 style, with a bias
       to faces); a face axis makes that face the feature, an edge axis gives
       one point between the segment and that box edge.
    3. Face feature: the segment is clipped to the face's side planes
       (Liang-Barsky) and both ends of the clipped part are contact points
       (slot 0 nearer the capsule's -z end), each with its own depth below or
       height above the face.
    """
    radius, hl = ha[0], ha[1]
    h = hb
    c = rotate_inv(qb, sub(pa, pb))
    u = rotate_inv(qb, local_z(qa))
    p0 = (c[0] - u[0] * hl, c[1] - u[1] * hl, c[2] - u[2] * hl)
    length = 2.0 * hl
    d = (u[0] * length, u[1] * length, u[2] * length)

    # 1. Closest points.
    t_star, d2 = segment_box_closest(p0, d, h)
    s_star = (p0[0] + d[0] * t_star, p0[1] + d[1] * t_star, p0[2] + d[2] * t_star)
    b_star = clip3(s_star, h)
    dist = math.sqrt(d2)
    apart = dist > TOUCH
    gap_face = False
    gap_face_idx = 0
    if apart:
        n_clamped = 0
        for i in range(3):
            if abs(s_star[i]) > h[i]:
                if n_clamped == 0:
                    gap_face_idx = i
                n_clamped += 1
        gap_face = n_clamped == 1

    # 2. SAT for touching / penetrating segments.
    use_edge = False
    sat_face_idx = 0
    if not apart:
        au = abs3(u)
        face_sep = (abs(c[0]) - h[0] - au[0] * hl, abs(c[1]) - h[1] - au[1] * hl, abs(c[2]) - h[2] - au[2] * hl)
        if face_sep[1] > face_sep[sat_face_idx]:
            sat_face_idx = 1
        if face_sep[2] > pick3(face_sep, sat_face_idx):
            sat_face_idx = 2
        best_face_sep = pick3(face_sep, sat_face_idx)
        best_edge_sep = -math.inf
        edge_idx = 0
        n_edge = (0.0, 0.0, 0.0)
        for i in range(3):
            # u x e_i
            if i == 0:
                ax = (0.0, u[2], -u[1])
            elif i == 1:
                ax = (-u[2], 0.0, u[0])
            else:
                ax = (u[1], -u[0], 0.0)
            ax_len = math.sqrt(dot(ax, ax))
            if ax_len > PARALLEL_SIN:
                ax = (ax[0] / ax_len, ax[1] / ax_len, ax[2] / ax_len)
                proj = dot(c, ax)
                sp = sign_nonneg(proj)
                ax = (ax[0] * sp, ax[1] * sp, ax[2] * sp)  # box -> capsule
                extent = h[0] * abs(ax[0]) + h[1] * abs(ax[1]) + h[2] * abs(ax[2])
                sep_i = abs(proj) - extent
            else:
                sep_i = -math.inf
            if i == 0 or sep_i > best_edge_sep:
                best_edge_sep = sep_i
                edge_idx = i
                n_edge = ax
        use_edge = best_edge_sep > best_face_sep + EDGE_REL * abs(best_face_sep) + EDGE_ABS
        if use_edge:
            # One point from the closest points of the segment and that box edge.
            corner = (-h[0] if edge_idx == 0 else sign_nonneg(n_edge[0]) * h[0],
                      -h[1] if edge_idx == 1 else sign_nonneg(n_edge[1]) * h[1],
                      -h[2] if edge_idx == 2 else sign_nonneg(n_edge[2]) * h[2])
            edge_dir = _axis(edge_idx, 2.0 * pick3(h, edge_idx))
            se, te = closest_points_segments(p0, d, corner, edge_dir)
            s_edge = (p0[0] + d[0] * se, p0[1] + d[1] * se, p0[2] + d[2] * se)
            b_edge = (corner[0] + edge_dir[0] * te, corner[1] + edge_dir[1] * te, corner[2] + edge_dir[2] * te)
            sep_edge = dot(sub(s_edge, b_edge), n_edge) - radius
            return _single(pb, qb, n_edge, s_edge, b_edge, sep_edge, radius, margin)

    if apart and not gap_face:
        # One point from the gap: the closest box point is on an edge or corner.
        n_gap = ((s_star[0] - b_star[0]) / dist, (s_star[1] - b_star[1]) / dist, (s_star[2] - b_star[2]) / dist)
        return _single(pb, qb, n_gap, s_star, b_star, dist - radius, radius, margin)

    # 3. Face feature: clip the segment to the face's side planes.
    if apart:
        face = gap_face_idx
        sgn = sign_nonneg(pick3(s_star, face))
    else:
        face = sat_face_idx
        sgn = sign_nonneg(pick3(c, face))
    lo = 0.0
    hi = 1.0
    for j in range(3):
        if j == face:
            continue
        if d[j] != 0.0:
            t1 = (-h[j] - p0[j]) / d[j]
            t2 = (h[j] - p0[j]) / d[j]
            lo = max(lo, min(t1, t2))
            hi = min(hi, max(t1, t2))
        elif not abs(p0[j]) <= h[j]:
            lo = math.inf
            hi = -math.inf
    if not lo <= hi:
        lo = t_star
        hi = t_star
    n_face = _axis(face, sgn)  # box -> capsule, local
    second = (hi - lo) * length > MIN_CLIP
    return manifold(neg(rotate(qb, n_face)), _face_slot(pb, qb, p0, d, lo, face, sgn, h, n_face, radius, True, margin),
                    _face_slot(pb, qb, p0, d, hi, face, sgn, h, n_face, radius, second, margin), empty(), empty())


@kernel
def _face_slot(pb, qb, p0, d, tk, face, sgn, h, n_face, radius, exists, margin):
    """The slot of the segment point at ``tk`` against box face ``face`` (outward
    normal ``n_face`` = sgn e_face, box frame): its height above the face minus
    the radius, the point midway between the face and the capsule surface."""
    s_k = (p0[0] + d[0] * tk, p0[1] + d[1] * tk, p0[2] + d[2] * tk)
    height = sgn * pick3(s_k, face) - pick3(h, face)
    on_face = (s_k[0] - n_face[0] * height, s_k[1] - n_face[1] * height, s_k[2] - n_face[2] * height)
    mid = (0.5 * (on_face[0] + s_k[0] - n_face[0] * radius), 0.5 * (on_face[1] + s_k[1] - n_face[1] * radius),
           0.5 * (on_face[2] + s_k[2] - n_face[2] * radius))
    return candidate(add(pb, rotate(qb, mid)), height - radius, exists, margin)


@kernel
def _single(pb, qb, n_local, s, b, sep, radius, margin):
    """One point midway between the box point ``b`` and the capsule surface
    below the segment point ``s`` along ``n_local`` (box frame, box -> capsule)."""
    mid = (0.5 * (b[0] + s[0] - n_local[0] * radius), 0.5 * (b[1] + s[1] - n_local[1] * radius),
           0.5 * (b[2] + s[2] - n_local[2] * radius))
    return single(neg(rotate(qb, n_local)), add(pb, rotate(qb, mid)), sep, margin)
