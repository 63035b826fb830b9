"""Round shapes against boxes: sphere-box and capsule-box (the box is shape b).

Work happens in the box's local frame, where the box is the axis-aligned
set |x_i| <= h_i. Separated shapes use exact closest points (so speculative
contacts carry true gaps); a core point or segment touching or inside the
box uses the axis of least penetration. Units: metres.
"""

from __future__ import annotations

import numpy as np

from ..math3d import dot, norm, quat_rotate, quat_rotate_inv
from .geometry import closest_points_segments, local_z, one_hot, pick, sign_nonneg
from .manifold import Manifold, assemble, select

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


def _box_dist2(p, h):
    """Squared distance (m²) from local points p (..., 3) to the box |x| <= h."""
    d = p - np.clip(p, -h, h)
    return dot(d, d)


def sphere_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Sphere a, box b: one point.

    Outside: closest point on the box (clamp, Ericson 5.1.4). Centre inside:
    the nearest face, whose outward normal points at the sphere.
    """
    r = params_a[..., 0]
    h = np.broadcast_to(params_b, pos_b.shape)
    c = quat_rotate_inv(quat_b, pos_a - pos_b)
    q = np.clip(c, -h, h)
    gap = c - q
    dist = norm(gap)
    outside = dist > TOUCH
    n_out = gap / np.where(outside, dist, 1.0)[..., None]
    # Inside: nearest face (first axis on ties), outward towards the centre.
    depth = h - np.abs(c)  # >= 0 inside
    face = np.argmin(depth, axis=-1)
    sgn = sign_nonneg(pick(c, face))
    n_in = one_hot(face) * sgn[..., None]
    q_in = np.where(one_hot(face) > 0, (sgn * pick(h, face))[..., None], c)
    n_local = np.where(outside[..., None], n_out, n_in)  # box -> sphere
    surface_box = np.where(outside[..., None], q, q_in)
    sep = np.where(outside, dist, -pick(depth, face)) - r
    surface_sphere = c - n_local * r[..., None]
    mid = 0.5 * (surface_box + surface_sphere)
    normal = -quat_rotate(quat_b, n_local)  # sphere -> box
    point = pos_b + quat_rotate(quat_b, mid)
    return assemble(normal, point[..., None, :], sep[..., None], None, margin)


def _segment_box_closest(p0, d, h):
    """Parameter t in [0, 1] of the point of segment ``p0 + t d`` closest to the
    box |x| <= h, and the squared distance there.

    The squared distance is a convex piecewise quadratic in t whose pieces
    change where the segment crosses a face plane x_i = ±h_i; minimising each
    of the (at most 7) pieces in closed form and keeping the best is exact.
    """
    zeros = np.zeros(d.shape[:-1])
    knots = [zeros, zeros + 1.0]
    for i in range(3):
        di = d[..., i]
        moving = di != 0.0
        safe = np.where(moving, di, 1.0)
        for side in (-1.0, 1.0):
            knots.append(np.where(moving, np.clip((side * h[..., i] - p0[..., i]) / safe, 0.0, 1.0), 0.0))
    knots = np.sort(np.stack(knots, axis=-1), axis=-1)
    best_t = zeros
    best_d2 = np.full(zeros.shape, np.inf)
    for k in range(knots.shape[-1] - 1):
        lo, hi = knots[..., k], knots[..., k + 1]
        mid = 0.5 * (lo + hi)
        num = zeros
        den = zeros
        for i in range(3):
            x = p0[..., i] + mid * d[..., i]
            target = np.clip(x, -h[..., i], h[..., i])
            active = x != target  # this coordinate is clamped on this piece
            num = num + np.where(active, d[..., i] * (p0[..., i] - target), 0.0)
            den = den + np.where(active, d[..., i] * d[..., i], 0.0)
        ok = den > 0.0
        t = np.where(ok, -num / np.where(ok, den, 1.0), mid)
        t = np.minimum(np.maximum(t, lo), hi)
        d2 = _box_dist2(p0 + d * t[..., None], h)
        better = d2 < best_d2
        best_t = np.where(better, t, best_t)
        best_d2 = np.where(better, d2, best_d2)
    return best_t, best_d2


def capsule_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Capsule a, box b: one point, or two when the capsule lies along a face.

    1. Closest points of the capsule segment and the box (exact, see
       ``_segment_box_closest``). If apart and the closest box point is inside
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
    r = params_a[..., 0]
    hl = params_a[..., 1]
    h = np.broadcast_to(params_b, pos_b.shape)
    c = quat_rotate_inv(quat_b, pos_a - pos_b)
    u = quat_rotate_inv(quat_b, local_z(quat_a))
    p0 = c - u * hl[..., None]
    d = u * (2.0 * hl)[..., None]

    # 1. Closest points.
    t_star, d2 = _segment_box_closest(p0, d, h)
    s_star = p0 + d * t_star[..., None]
    b_star = np.clip(s_star, -h, h)
    dist = np.sqrt(d2)
    apart = dist > TOUCH
    n_gap = (s_star - b_star) / np.where(apart, dist, 1.0)[..., None]
    clamped = np.abs(s_star) > h
    gap_face = apart & (clamped.sum(axis=-1) == 1)
    gap_face_idx = np.argmax(clamped, axis=-1)

    # 2. SAT for touching / penetrating segments.
    face_sep = np.abs(c) - h - np.abs(u) * hl[..., None]  # (W, P, 3)
    sat_face_idx = np.argmax(face_sep, axis=-1)
    best_face_sep = pick(face_sep, sat_face_idx)
    edge_axes = []
    edge_sep = []
    for i in range(3):
        ax = np.zeros(u.shape)
        j, k = (i + 1) % 3, (i + 2) % 3
        # u x e_i
        ax[..., j] = u[..., k]
        ax[..., k] = -u[..., j]
        length = norm(ax)
        ok = length > 1e-6
        ax = ax / np.where(ok, length, 1.0)[..., None]
        proj = dot(c, ax)
        ax = ax * sign_nonneg(proj)[..., None]  # box -> capsule
        radius = h[..., 0] * np.abs(ax[..., 0]) + h[..., 1] * np.abs(ax[..., 1]) + h[..., 2] * np.abs(ax[..., 2])
        edge_axes.append(ax)
        edge_sep.append(np.where(ok, np.abs(proj) - radius, -np.inf))
    edge_sep = np.stack(edge_sep, axis=-1)
    edge_axes = np.stack(edge_axes, axis=-2)  # (W, P, 3 edges, 3)
    edge_idx = np.argmax(edge_sep, axis=-1)
    best_edge_sep = pick(edge_sep, edge_idx)
    use_edge = ~apart & (best_edge_sep > best_face_sep + EDGE_REL * np.abs(best_face_sep) + EDGE_ABS)

    # Single point from the segment-edge closest points (SAT edge axis).
    n_edge = np.take_along_axis(edge_axes, edge_idx[..., None, None], axis=-2)[..., 0, :]
    along = one_hot(edge_idx)
    corner = np.where(along > 0, -h, sign_nonneg(n_edge) * h)
    edge_dir = along * (2.0 * h)
    se, te = closest_points_segments(p0, d, corner, edge_dir)
    s_edge = p0 + d * se[..., None]
    b_edge = corner + edge_dir * te[..., None]
    sep_edge = dot(s_edge - b_edge, n_edge) - r

    # Single point from the gap (apart, closest box point on an edge or corner).
    single_n = np.where(use_edge[..., None], n_edge, n_gap)
    single_s = np.where(use_edge[..., None], s_edge, s_star)
    single_b = np.where(use_edge[..., None], b_edge, b_star)
    single_sep = np.where(use_edge, sep_edge, dist - r)
    single_mid = 0.5 * (single_b + single_s - single_n * r[..., None])
    single = assemble(-quat_rotate(quat_b, single_n), (pos_b + quat_rotate(quat_b, single_mid))[..., None, :],
                      single_sep[..., None], None, margin)

    # 3. Face feature: clip the segment to the face's side planes.
    face = np.where(apart, gap_face_idx, sat_face_idx)
    sgn = sign_nonneg(pick(np.where(apart[..., None], s_star, c), face))
    lo = np.zeros(dist.shape)
    hi = np.ones(dist.shape)
    for j in range(3):
        side = face != j
        dj = d[..., j]
        moving = dj != 0.0
        safe = np.where(moving, dj, 1.0)
        t1 = (-h[..., j] - p0[..., j]) / safe
        t2 = (h[..., j] - p0[..., j]) / safe
        inside = np.abs(p0[..., j]) <= h[..., j]
        j_lo = np.where(moving, np.minimum(t1, t2), np.where(inside, 0.0, np.inf))
        j_hi = np.where(moving, np.maximum(t1, t2), np.where(inside, 1.0, -np.inf))
        lo = np.where(side, np.maximum(lo, j_lo), lo)
        hi = np.where(side, np.minimum(hi, j_hi), hi)
    clipped = lo <= hi
    lo = np.where(clipped, lo, t_star)
    hi = np.where(clipped, hi, t_star)
    n_face = one_hot(face) * sgn[..., None]  # box -> capsule, local
    pts, seps = [], []
    for tk in (lo, hi):
        s_k = p0 + d * tk[..., None]
        height = sgn * pick(s_k, face) - pick(h, face)
        on_face = s_k - n_face * height[..., None]
        pts.append(pos_b + quat_rotate(quat_b, 0.5 * (on_face + s_k - n_face * r[..., None])))
        seps.append(height - r)
    second = (hi - lo) * (2.0 * hl) > MIN_CLIP
    face_m = assemble(-quat_rotate(quat_b, n_face), np.stack(pts, axis=-2), np.stack(seps, axis=-1),
                      np.stack((np.ones_like(second), second), axis=-1), margin)

    is_face = np.where(apart, gap_face, ~use_edge)
    return select(is_face, face_m, single)
