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
   planes (Sutherland-Hodgman on a polygon of at most 8 vertices held in a
   scratch array); clipped vertices below the reference face plane plus the
   margin are contacts, reduced to 4 (deepest, farthest from it, then the
   largest triangles on either side).
3. Edge axis: one point midway between the closest points of the two edges.

Arguments and result as in :mod:`.plane`; ``poly[buf]`` is a
(2, 8, 3) float scratch (the clipping's two vertex buffers) that no other
thread uses meanwhile. Units: metres.
"""

from __future__ import annotations

import math

from ..jit import kernel
from ..vec import column, cross, dot, pick3, quat_to_matrix, sub
from .geometry import closest_points_segments, sign_nonneg, sort4i
from .manifold import MAX_POINTS, candidate, invalidated, manifold, single

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
#: Vertices the clipped polygon can have: the incident quad (4) plus one per side plane.
POLY_CAP = 8


@kernel
def _entry(m, i, j):
    """m[i][j] of a matrix held as a tuple of rows, for indices known at run time."""
    return pick3(column(m, i), j)


@kernel
def _clip(poly, buf, src, dst, cap, count, coord, sign, limit):
    """Sutherland-Hodgman against one plane: keep ``sign * x[coord] <= limit``.

    ``poly[buf, src, :cap]`` holds the polygon, its first ``count`` vertices in
    cyclic order. Each edge (v_k, v_k+1) emits v_k if inside and the crossing
    point if the edge crosses the plane. ``poly[buf, dst, :cap + 1]`` receives the
    emitted vertices in that order, then the candidates not emitted (so every
    entry of the buffer is a deterministic function of the polygon). Returns
    the new count.
    """
    n_out = 0
    new_count = 0
    for emitted in (True, False):
        for k in range(cap):
            exists = k < count
            nxt = k + 1 if k + 1 < count else 0
            gp = sign * poly[buf, src, k, coord] - limit
            gq = sign * poly[buf, src, nxt, coord] - limit
            in_p = gp <= 0.0
            in_q = gq <= 0.0
            emit_p = exists and in_p
            emit_x = exists and (in_p != in_q)
            if emit_p == emitted and n_out <= cap:
                for c in range(3):
                    poly[buf, dst, n_out, c] = poly[buf, src, k, c]
                n_out += 1
            if emit_x == emitted and n_out <= cap:
                alpha = gp / (gp - gq) if emit_x else gp
                for c in range(3):
                    p = poly[buf, src, k, c]
                    poly[buf, dst, n_out, c] = p + (poly[buf, src, nxt, c] - p) * alpha
                n_out += 1
        if emitted:
            new_count = n_out
    return new_count


@kernel
def _face_contact(ref_pos, ref_m, ref_h, inc_pos, inc_m, inc_h, f, sgn, margin, flip, poly, buf):
    """Clip the incident box's face against face ``f`` of the reference box
    (whose outward normal towards the incident box is ``sgn`` times its axis
    f); ``flip``: the reference box is b (the normal is reversed to a -> b)."""
    f1, f2 = (f + 1) % 3, (f + 2) % 3
    axis_n, axis_u, axis_v = column(ref_m, f), column(ref_m, f1), column(ref_m, f2)
    hn, hu, hv = pick3(ref_h, f), pick3(ref_h, f1), pick3(ref_h, f2)
    n_ref = (axis_n[0] * sgn, axis_n[1] * sgn, axis_n[2] * sgn)  # reference -> incident

    # Incident face: the one whose outward normal is most anti-parallel to n_ref.
    align = (dot(inc_m[0], n_ref), dot(inc_m[1], n_ref), dot(inc_m[2], n_ref))
    g = 0
    if abs(align[1]) > abs(align[0]):
        g = 1
    if abs(align[2]) > abs(pick3(align, g)):
        g = 2
    g1, g2 = (g + 1) % 3, (g + 2) % 3
    cg = column(inc_m, g)
    off = sign_nonneg(pick3(align, g)) * pick3(inc_h, g)
    centre = (inc_pos[0] - cg[0] * off, inc_pos[1] - cg[1] * off, inc_pos[2] - cg[2] * off)
    c1, h1 = column(inc_m, g1), pick3(inc_h, g1)
    c2, h2 = column(inc_m, g2), pick3(inc_h, g2)
    ta = (c1[0] * h1, c1[1] * h1, c1[2] * h1)
    tb = (c2[0] * h2, c2[1] * h2, c2[2] * h2)
    # Vertices in cyclic order, as signs along (ta, tb): (+,+), (-,+), (-,-), (+,-);
    # stored in the reference face's coordinates (normal, u, v).
    for k in range(4):
        su = 1.0 if k == 0 or k == 3 else -1.0
        sv = 1.0 if k < 2 else -1.0
        vert = (centre[0] + su * ta[0] + sv * tb[0], centre[1] + su * ta[1] + sv * tb[1],
                centre[2] + su * ta[2] + sv * tb[2])
        rel = sub(vert, ref_pos)
        poly[buf, 0, k, 0] = dot(rel, axis_n)
        poly[buf, 0, k, 1] = dot(rel, axis_u)
        poly[buf, 0, k, 2] = dot(rel, axis_v)
    count = _clip(poly, buf, 0, 1, 4, 4, 1, 1.0, hu)
    count = _clip(poly, buf, 1, 0, 5, count, 1, -1.0, hu)
    count = _clip(poly, buf, 0, 1, 6, count, 2, 1.0, hv)
    count = _clip(poly, buf, 1, 0, 7, count, 2, -1.0, hv)  # the polygon is now poly[buf, 0, :POLY_CAP]

    # Reduce to at most 4 points: depth below the reference face of each vertex.
    n_mask = 0
    dmin = math.inf
    for k in range(POLY_CAP):
        depth = sgn * poly[buf, 0, k, 0] - hn
        if k < count and depth < margin:
            n_mask += 1
            dmin = min(dmin, depth)
    i0 = i1 = i2 = i3 = 0
    ok0 = ok1 = ok2 = ok3 = False
    if n_mask > MAX_POINTS:
        # The deepest (the first within DEEP_TOL of it), the farthest from it,
        # and the largest triangles with those two on either side.
        ia = -1
        for k in range(POLY_CAP):
            depth = sgn * poly[buf, 0, k, 0] - hn
            if k < count and depth < margin and depth <= dmin + DEEP_TOL:
                ia = k
                break
        ua, va = poly[buf, 0, ia, 1], poly[buf, 0, ia, 2]
        ib = 0
        best = -math.inf
        for k in range(POLY_CAP):
            depth = sgn * poly[buf, 0, k, 0] - hn
            dist2 = -1.0
            if k < count and depth < margin:
                du, dv = poly[buf, 0, k, 1] - ua, poly[buf, 0, k, 2] - va
                dist2 = du * du + dv * dv
            if k == 0 or dist2 > best:
                best = dist2
                ib = k
        okb = best > AREA_EPS
        ub, vb = poly[buf, 0, ib, 1], poly[buf, 0, ib, 2]
        ic = idd = 0
        a_max = -math.inf
        a_min = math.inf
        for k in range(POLY_CAP):
            depth = sgn * poly[buf, 0, k, 0] - hn
            if k < count and depth < margin:
                area = (ub - ua) * (poly[buf, 0, k, 2] - va) - (vb - va) * (poly[buf, 0, k, 1] - ua)
                a3, a4 = area, area
            else:
                a3, a4 = -math.inf, math.inf
            if k == 0 or a3 > a_max:
                a_max = a3
                ic = k
            if k == 0 or a4 < a_min:
                a_min = a4
                idd = k
        okc = a_max > AREA_EPS
        okd = a_min < -AREA_EPS
        # Back in polygon order, so that the slots follow the polygon.
        i0, i1, i2, i3 = sort4i(ia, ib if okb else POLY_CAP, ic if okc else POLY_CAP, idd if okd else POLY_CAP)
        ok0, ok1, ok2, ok3 = i0 < POLY_CAP, i1 < POLY_CAP, i2 < POLY_CAP, i3 < POLY_CAP
        i0 = i0 if ok0 else 0
        i1 = i1 if ok1 else 0
        i2 = i2 if ok2 else 0
        i3 = i3 if ok3 else 0
    else:
        # All of them in polygon order, then the other vertices in order in the empty slots.
        slot = 0
        for chosen in (True, False):
            for k in range(POLY_CAP):
                depth = sgn * poly[buf, 0, k, 0] - hn
                if (k < count and depth < margin) == chosen and slot < MAX_POINTS:
                    if slot == 0:
                        i0, ok0 = k, chosen
                    elif slot == 1:
                        i1, ok1 = k, chosen
                    elif slot == 2:
                        i2, ok2 = k, chosen
                    else:
                        i3, ok3 = k, chosen
                    slot += 1

    n = (-n_ref[0], -n_ref[1], -n_ref[2]) if flip else n_ref  # a -> b
    return manifold(n, _vertex_slot(poly, buf, i0, ok0, sgn, hn, ref_pos, axis_n, axis_u, axis_v, margin),
                    _vertex_slot(poly, buf, i1, ok1, sgn, hn, ref_pos, axis_n, axis_u, axis_v, margin),
                    _vertex_slot(poly, buf, i2, ok2, sgn, hn, ref_pos, axis_n, axis_u, axis_v, margin),
                    _vertex_slot(poly, buf, i3, ok3, sgn, hn, ref_pos, axis_n, axis_u, axis_v, margin))


@kernel
def _vertex_slot(poly, buf, k, ok, sgn, hn, ref_pos, axis_n, axis_u, axis_v, margin):
    """The slot of clipped vertex k (reference-face coordinates in
    ``poly[buf, 0, k]``): its depth below the reference face, the point midway
    between it and its projection on the face."""
    sep = sgn * poly[buf, 0, k, 0] - hn
    x_n = poly[buf, 0, k, 0] - 0.5 * sgn * sep
    x_u, x_v = poly[buf, 0, k, 1], poly[buf, 0, k, 2]
    p = (ref_pos[0] + axis_n[0] * x_n + axis_u[0] * x_u + axis_v[0] * x_v,
         ref_pos[1] + axis_n[1] * x_n + axis_u[1] * x_u + axis_v[1] * x_v,
         ref_pos[2] + axis_n[2] * x_n + axis_u[2] * x_u + axis_v[2] * x_v)
    return candidate(p, sep, ok, margin)


@kernel
def _edge_normal(ma, mb, t, i, j):
    """Unit normal of a's edge axis i and b's edge axis j, oriented from a to b."""
    axis = cross(column(ma, i), column(mb, j))
    length = max(math.sqrt(dot(axis, axis)), PARALLEL_SIN)
    n = (axis[0] / length, axis[1] / length, axis[2] / length)
    s = sign_nonneg(dot(t, n))
    return (n[0] * s, n[1] * s, n[2] * s)


@kernel
def _edge_contact(pa, ma, ha, pb, mb, hb, n, i, j, se, margin):
    """One point between a's edge along axis i and b's edge along axis j (normal n, a -> b)."""
    # Support edges: a's edge furthest along n, b's edge furthest along -n.
    ca = pa
    cb = pb
    for k in range(3):
        axk, bxk = column(ma, k), column(mb, k)
        fa = 0.0 if i == k else sign_nonneg(dot(axk, n)) * pick3(ha, k)
        fb = 0.0 if j == k else sign_nonneg(dot(bxk, n)) * pick3(hb, k)
        ca = (ca[0] + axk[0] * fa, ca[1] + axk[1] * fa, ca[2] + axk[2] * fa)
        cb = (cb[0] - bxk[0] * fb, cb[1] - bxk[1] * fb, cb[2] - bxk[2] * fb)
    ai, hai = column(ma, i), pick3(ha, i)
    bj, hbj = column(mb, j), pick3(hb, j)
    ea = (ai[0] * hai, ai[1] * hai, ai[2] * hai)
    eb = (bj[0] * hbj, bj[1] * hbj, bj[2] * hbj)
    a0 = sub(ca, ea)
    b0 = sub(cb, eb)
    da = (2.0 * ea[0], 2.0 * ea[1], 2.0 * ea[2])
    db = (2.0 * eb[0], 2.0 * eb[1], 2.0 * eb[2])
    s, u = closest_points_segments(a0, da, b0, db)
    p = (0.5 * ((a0[0] + da[0] * s) + (b0[0] + db[0] * u)), 0.5 * ((a0[1] + da[1] * s) + (b0[1] + db[1] * u)),
         0.5 * ((a0[2] + da[2] * s) + (b0[2] + db[2] * u)))
    return single(n, p, se, margin)


@kernel
def box_box(pa, qa, ha, pb, qb, hb, margin, poly, buf):
    """Box a, box b: up to 4 points for face contact, 1 for edge-edge contact.

    Face contacts keep the incident face's vertex order in the slots (a box
    resting inside a larger face gives its 4 bottom corners in fixed slots).
    Boxes apart by the margin or more along some axis get no valid point.
    """
    ma = quat_to_matrix(qa)  # columns: a's axes in the world
    mb = quat_to_matrix(qb)
    t = sub(pb, pa)
    rot = ((dot(ma[0], mb[0]), dot(ma[0], mb[1]), dot(ma[0], mb[2])),
           (dot(ma[1], mb[0]), dot(ma[1], mb[1]), dot(ma[1], mb[2])),
           (dot(ma[2], mb[0]), dot(ma[2], mb[1]), dot(ma[2], mb[2])))
    ab = ((abs(rot[0][0]), abs(rot[0][1]), abs(rot[0][2])),
          (abs(rot[1][0]), abs(rot[1][1]), abs(rot[1][2])),
          (abs(rot[2][0]), abs(rot[2][1]), abs(rot[2][2])))

    # 1. Separation along the 15 axes (the first of equal ones wins).
    ia = ib = ie = 0
    sa = sb = se = -math.inf
    for i in range(3):
        s = abs(dot(t, ma[i])) - (pick3(ha, i) + hb[0] * ab[i][0] + hb[1] * ab[i][1] + hb[2] * ab[i][2])
        if i == 0 or s > sa:
            sa, ia = s, i
    for j in range(3):
        s = abs(dot(t, mb[j])) - (ha[0] * _entry(ab, 0, j) + ha[1] * _entry(ab, 1, j) + ha[2] * _entry(ab, 2, j)
                                  + pick3(hb, j))
        if j == 0 or s > sb:
            sb, ib = s, j
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            axis = cross(ma[i], column(mb, j))
            length = math.sqrt(dot(axis, axis))
            if length > PARALLEL_SIN:
                ra = pick3(ha, i1) * _entry(ab, i2, j) + pick3(ha, i2) * _entry(ab, i1, j)
                rb = pick3(hb, j1) * _entry(ab, i, j2) + pick3(hb, j2) * _entry(ab, i, j1)
                s = (abs(dot(t, axis)) - ra - rb) / length
            else:
                s = -math.inf
            if (i == 0 and j == 0) or s > se:
                se, ie = s, 3 * i + j
    use_b = sb > sa + FACE_ABS
    sf = sb if use_b else sa
    use_edge = se > sf + EDGE_REL * abs(sf) + EDGE_ABS
    apart = max(max(sa, sb), se) >= margin

    # The reference face and its outward normal towards the other box.
    if use_b:
        f = ib
        axis_n = column(mb, f)
        sgn = sign_nonneg(dot(sub(pa, pb), axis_n))
        n_face = (-axis_n[0] * sgn, -axis_n[1] * sgn, -axis_n[2] * sgn)  # a -> b
    else:
        f = ia
        axis_n = column(ma, f)
        sgn = sign_nonneg(dot(t, axis_n))
        n_face = (axis_n[0] * sgn, axis_n[1] * sgn, axis_n[2] * sgn)
    n_edge = n_face
    if use_edge:
        n_edge = _edge_normal(ma, mb, t, ie // 3, ie % 3)
        use_edge = abs(dot(n_edge, n_face)) < EDGE_FACE_COS
    if use_edge:
        m = _edge_contact(pa, ma, ha, pb, mb, hb, n_edge, ie // 3, ie % 3, se, margin)
    elif use_b:
        m = _face_contact(pb, mb, hb, pa, ma, ha, f, sgn, margin, True, poly, buf)
    else:
        m = _face_contact(pa, ma, ha, pb, mb, hb, f, sgn, margin, False, poly, buf)
    return invalidated(m) if apart else m
