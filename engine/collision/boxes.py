"""Box against box: separating axes, then face clipping or edge-edge.

1. SAT over 15 axes: the 3 face normals of each box and the 9 cross products
   of their edge directions (Gottschalk, Lin, Manocha 1996, "OBBTree";
   Ericson, *Real-Time Collision Detection* 4.4.1). Each axis' separation is
   in metres (edge axes normalised). Faces are favoured: a's faces over b's
   unless b's are clearly better, and faces over edges unless an edge axis
   is clearly better (Box2D's b2CollidePolygons tolerance, ODE's dBoxBox
   fudge factor), so a resting contact keeps its normal.
2. Face axis: the face of the other (incident) box most anti-parallel to the
   reference face normal is clipped against the reference face's 4 side
   planes (Sutherland-Hodgman, written with fixed-size vertex arrays and
   masks); clipped vertices below the reference face plane plus the margin
   are contacts, reduced to 4 (deepest, farthest from it, then the largest
   triangles on either side).
3. Edge axis: one point midway between the closest points of the two edges.

Units: metres.
"""

from __future__ import annotations

import numpy as np

from ..math3d import cross, dot, norm, quat_to_matrix
from .geometry import closest_points_segments, column, pick, sign_nonneg
from .manifold import MAX_POINTS, Manifold, assemble, select

#: b's face replaces a's as reference when its separation is larger by this (m).
FACE_ABS = 5e-4
#: An edge axis replaces the best face axis when its separation is larger by
#: EDGE_REL * |face separation| + EDGE_ABS (m).
EDGE_REL = 0.05
EDGE_ABS = 5e-4
#: An edge-edge axis within this cosine of the chosen face normal is treated
#: as that face: a box lying almost flat across another's edge then gets the
#: clipped face manifold (2-4 points) instead of one point it can rock about.
EDGE_FACE_COS = 0.95
#: Edge pairs closer to parallel than this (sine of the angle) have no axis of their own.
PARALLEL_SIN = 1e-5
#: Points within this depth (m) of the deepest count as deepest when reducing,
#: the first of them in polygon order winning (keeps the choice stable).
DEEP_TOL = 1e-3
#: Squared lengths / areas (m²) below this count as degenerate when reducing.
AREA_EPS = 1e-12

# Incident face vertices as signs along the face's two tangent axes, in cyclic order.
_QUAD = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))


def _clip(poly, count, coord, sign, limit):
    """Sutherland-Hodgman against one plane: keep ``sign * poly[..., coord] <= limit``.

    poly (..., C, 3) with the first ``count`` (...) vertices in cyclic order.
    Each edge (v_k, v_k+1) emits v_k if inside and the crossing point if the
    edge crosses the plane; emitted vertices are compacted to the front.
    Returns (..., C + 1, 3) and the new count.
    """
    cap = poly.shape[-2]
    k = np.arange(cap)
    exists = k < count[..., None]
    nxt = np.where(k + 1 < count[..., None], k + 1, 0)
    q = np.take_along_axis(poly, nxt[..., None], axis=-2)
    gp = sign * poly[..., coord] - limit[..., None]
    gq = sign * q[..., coord] - limit[..., None]
    in_p = gp <= 0.0
    in_q = gq <= 0.0
    emit_p = exists & in_p
    emit_x = exists & (in_p != in_q)
    alpha = gp / np.where(emit_x, gp - gq, 1.0)
    x = poly + (q - poly) * alpha[..., None]
    out = np.stack((poly, x), axis=-2).reshape(poly.shape[:-2] + (2 * cap, 3))
    mask = np.stack((emit_p, emit_x), axis=-1).reshape(poly.shape[:-2] + (2 * cap,))
    order = np.argsort(~mask, axis=-1, kind="stable")[..., : cap + 1]
    return np.take_along_axis(out, order[..., None], axis=-2), mask.sum(axis=-1)


def _reduce(u, v, depth, mask):
    """Choose at most 4 of C candidate points (in-plane coordinates u, v,
    depth, validity mask, each (..., C)).

    Four or fewer: all, in polygon order. More: the deepest (first within
    DEEP_TOL), the farthest from it, and the points making the largest
    triangle with those two on each side; then put back in polygon order so
    that slots follow the polygon. Returns indices (..., 4) and validity.
    """
    cap = mask.shape[-1]
    count = mask.sum(axis=-1)
    compact = np.argsort(~mask, axis=-1, kind="stable")[..., :MAX_POINTS]
    compact_ok = np.arange(MAX_POINTS) < count[..., None]

    dmin = np.where(mask, depth, np.inf).min(axis=-1)
    i1 = np.argmax(mask & (depth <= dmin[..., None] + DEEP_TOL), axis=-1)
    u1, v1 = pick(u, i1), pick(v, i1)
    dist2 = np.where(mask, (u - u1[..., None]) ** 2 + (v - v1[..., None]) ** 2, -1.0)
    i2 = np.argmax(dist2, axis=-1)
    ok2 = pick(dist2, i2) > AREA_EPS
    u2, v2 = pick(u, i2), pick(v, i2)
    area = (u2 - u1)[..., None] * (v - v1[..., None]) - (v2 - v1)[..., None] * (u - u1[..., None])
    a3 = np.where(mask, area, -np.inf)
    a4 = np.where(mask, area, np.inf)
    i3 = np.argmax(a3, axis=-1)
    i4 = np.argmin(a4, axis=-1)
    ok3 = pick(a3, i3) > AREA_EPS
    ok4 = pick(a4, i4) < -AREA_EPS
    chosen = np.stack((i1, i2, i3, i4), axis=-1)
    ok = np.stack((count > 0, ok2, ok3, ok4), axis=-1)
    key = np.sort(np.where(ok, chosen, cap), axis=-1)
    chosen_ok = key < cap
    chosen = np.where(chosen_ok, key, 0)

    many = (count > MAX_POINTS)[..., None]
    return np.where(many, chosen, compact), np.where(many, chosen_ok, compact_ok)


def box_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Box a, box b: up to 4 points for face contact, 1 for edge-edge contact.

    Face contacts keep the incident face's vertex order in the slots (a box
    resting inside a larger face gives its 4 bottom corners in fixed slots).
    """
    lead = np.broadcast_shapes(pos_a.shape[:-1], pos_b.shape[:-1])
    ha = np.broadcast_to(params_a, lead + (3,))
    hb = np.broadcast_to(params_b, lead + (3,))
    ma = np.broadcast_to(quat_to_matrix(quat_a), lead + (3, 3))  # columns: a's axes in world
    mb = np.broadcast_to(quat_to_matrix(quat_b), lead + (3, 3))
    A = [ma[..., :, i] for i in range(3)]
    B = [mb[..., :, j] for j in range(3)]
    t = pos_b - pos_a
    R = [[dot(A[i], B[j]) for j in range(3)] for i in range(3)]
    absR = [[np.abs(R[i][j]) for j in range(3)] for i in range(3)]
    ta = [dot(t, A[i]) for i in range(3)]
    tb = [dot(t, B[j]) for j in range(3)]

    # 1. Separation along the 15 axes.
    sep_a = np.stack([np.abs(ta[i]) - (ha[..., i] + hb[..., 0] * absR[i][0] + hb[..., 1] * absR[i][1]
                                       + hb[..., 2] * absR[i][2]) for i in range(3)], axis=-1)
    sep_b = np.stack([np.abs(tb[j]) - (ha[..., 0] * absR[0][j] + ha[..., 1] * absR[1][j]
                                       + ha[..., 2] * absR[2][j] + hb[..., j]) for j in range(3)], axis=-1)
    sep_e = []
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            axis = cross(A[i], B[j])
            length = norm(axis)
            ok = length > PARALLEL_SIN
            ra = ha[..., i1] * absR[i2][j] + ha[..., i2] * absR[i1][j]
            rb = hb[..., j1] * absR[i][j2] + hb[..., j2] * absR[i][j1]
            s = (np.abs(dot(t, axis)) - ra - rb) / np.where(ok, length, 1.0)
            sep_e.append(np.where(ok, s, -np.inf))
    sep_e = np.stack(sep_e, axis=-1)

    ia = np.argmax(sep_a, axis=-1)
    ib = np.argmax(sep_b, axis=-1)
    ie = np.argmax(sep_e, axis=-1)
    sa, sb, se = pick(sep_a, ia), pick(sep_b, ib), pick(sep_e, ie)
    use_b = sb > sa + FACE_ABS
    sf = np.where(use_b, sb, sa)
    use_edge = se > sf + EDGE_REL * np.abs(sf) + EDGE_ABS
    apart = np.maximum(np.maximum(sa, sb), se) >= margin

    face = _face_contact(pos_a, ma, ha, pos_b, mb, hb, use_b, np.where(use_b, ib, ia), margin)
    edge = _edge_contact(pos_a, ma, ha, pos_b, mb, hb, t, ie, se, margin)
    use_edge = use_edge & (np.abs(dot(edge.normal, face.normal)) < EDGE_FACE_COS)
    out = select(use_edge, edge, face)
    return out._replace(valid=out.valid & ~apart[..., None],
                        separation=np.where(apart[..., None], np.inf, out.separation))


def _face_contact(pos_a, ma, ha, pos_b, mb, hb, use_b, f, margin):
    """Clip the incident face against reference face ``f`` (of b where ``use_b``, else of a)."""
    ub3 = use_b[..., None]
    ref_pos = np.where(ub3, pos_b, pos_a)
    inc_pos = np.where(ub3, pos_a, pos_b)
    ref_m = np.where(ub3[..., None], mb, ma)
    inc_m = np.where(ub3[..., None], ma, mb)
    ref_h = np.where(ub3, hb, ha)
    inc_h = np.where(ub3, ha, hb)

    f1, f2 = (f + 1) % 3, (f + 2) % 3
    axis_n, axis_u, axis_v = column(ref_m, f), column(ref_m, f1), column(ref_m, f2)
    hn, hu, hv = pick(ref_h, f), pick(ref_h, f1), pick(ref_h, f2)
    sgn = sign_nonneg(dot(inc_pos - ref_pos, axis_n))
    n_ref = axis_n * sgn[..., None]  # reference -> incident

    # Incident face: the one whose outward normal is most anti-parallel to n_ref.
    align = np.stack([dot(inc_m[..., :, k], n_ref) for k in range(3)], axis=-1)
    g = np.argmax(np.abs(align), axis=-1)
    g1, g2 = (g + 1) % 3, (g + 2) % 3
    centre = inc_pos - column(inc_m, g) * (sign_nonneg(pick(align, g)) * pick(inc_h, g))[..., None]
    ta = column(inc_m, g1) * pick(inc_h, g1)[..., None]
    tb = column(inc_m, g2) * pick(inc_h, g2)[..., None]
    verts = np.stack([centre + su * ta + sv * tb for su, sv in _QUAD], axis=-2)  # (W, P, 4, 3)

    # Reference-face coordinates (normal, u, v) of the incident vertices.
    rel = verts - ref_pos[..., None, :]
    poly = np.stack((dot(rel, axis_n[..., None, :]), dot(rel, axis_u[..., None, :]),
                     dot(rel, axis_v[..., None, :])), axis=-1)
    count = np.full(poly.shape[:-2], 4)
    for coord, limit in ((1, hu), (2, hv)):
        for side in (1.0, -1.0):
            poly, count = _clip(poly, count, coord, side, limit)

    depth = sgn[..., None] * poly[..., 0] - hn[..., None]
    mask = (np.arange(poly.shape[-2]) < count[..., None]) & (depth < np.asarray(margin)[..., None])
    idx, ok = _reduce(poly[..., 1], poly[..., 2], depth, mask)
    chosen = np.take_along_axis(poly, idx[..., None], axis=-2)
    sep = np.take_along_axis(depth, idx, axis=-1)
    # Midway between the incident point and its projection on the reference face.
    x_n = chosen[..., 0] - 0.5 * sgn[..., None] * sep
    point = (ref_pos[..., None, :] + axis_n[..., None, :] * x_n[..., None]
             + axis_u[..., None, :] * chosen[..., 1:2] + axis_v[..., None, :] * chosen[..., 2:3])
    normal = np.where(ub3, -n_ref, n_ref)  # a -> b
    return assemble(normal, point, sep, ok, margin)


def _edge_contact(pos_a, ma, ha, pos_b, mb, hb, t, ie, se, margin):
    """One point between a's edge along axis ie // 3 and b's edge along axis ie % 3."""
    i, j = ie // 3, ie % 3
    ai, bj = column(ma, i), column(mb, j)
    axis = cross(ai, bj)
    length = norm(axis)
    n = axis / np.maximum(length, PARALLEL_SIN)[..., None]
    n = n * sign_nonneg(dot(t, n))[..., None]  # a -> b
    # Support edges: a's edge furthest along n, b's edge furthest along -n.
    ca = pos_a.copy()
    cb = pos_b.copy()
    for k in range(3):
        axk, bxk = ma[..., :, k], mb[..., :, k]
        ca = ca + axk * np.where(i == k, 0.0, sign_nonneg(dot(axk, n)) * ha[..., k])[..., None]
        cb = cb - bxk * np.where(j == k, 0.0, sign_nonneg(dot(bxk, n)) * hb[..., k])[..., None]
    ea = ai * pick(ha, i)[..., None]
    eb = bj * pick(hb, j)[..., None]
    s, u = closest_points_segments(ca - ea, 2.0 * ea, cb - eb, 2.0 * eb)
    pa = ca - ea + 2.0 * ea * s[..., None]
    pb = cb - eb + 2.0 * eb * u[..., None]
    point = 0.5 * (pa + pb)
    return assemble(n, point[..., None, :], se[..., None], None, margin)
