"""Joint post-stabilisation of one world: Gauss-Newton passes of
C(q + Δq) = 0 over the tree joints (Cline & Pai 2003), on the tree's
factorisation (:mod:`engine.core.tree`); what the passes are for and how
their constants were chosen is in :mod:`engine.joint_projection`.

One pass at positions q, with the rows' position errors beyond their slop C
(nj, 6) and the projection's metric W (6x6 a body):

    (J W⁻¹ Jᵀ) μ = -C,    Δq = W⁻¹ Jᵀ μ,

J the tree rows' Jacobian blocks at q (``tree_solve.blocks``), C their
position errors (``tree_solve.right_hand_side`` without the velocities, at
bias rate 1 and no push-out limit) each shrunk by its slop. The metric is the
tree bodies' M (the step's, ``tree_solve.metric``) plus k u uᵀ, u = (n, r × n),
for every contact point within ``CONTACT_RANGE`` of touching (k = weight ×
the body's mass, ramped to 0 at the range) and for every point the static
contact projection moved out (k = weight × mass). Each body turns by at most
``MAX_TURN`` rad a pass (the world's step scaled alike); a pass that leaves
the merit (the 2-norm of the errors beyond the slop, angular rows at
``ANGULAR_SLOP_LEVER`` m) larger is taken back and the next one tries half
its step, at most ``MAX_HALVINGS`` times in a row; a world stops once its
merit is at most ``TOLERANCE`` times its smallest slop.

Sums are kept in the order of the numpy code these kernels replace: the
merit's sums over a world's rows are numpy's pairwise summation
(``_pairwise``), the contact terms are added side b, then side a, point by
point, row by row. The metric's 6x6 inverses are Gauss-Jordan
(``tree.inverse6_into``), not LAPACK's, so the passes agree with the numpy
ones to rounding.

Every kernel is for one world; the batched entry points at the end take a
list of worlds and run them one per call.
"""

from __future__ import annotations

import math

import numpy as np

from .jit import SERIAL_BELOW, allocating_kernel, kernel, parallel_kernel, prange
from .tree import factor, factor_scratch, inverse6_into, substitute
from .tree_solve import blocks, body_impulses, position_errors, right_hand_side
from .vec import (
    cross,
    load3,
    load4,
    quat_mul,
    quat_normalize,
    rotate,
    store3,
    store4,
)

#: m: contact points closer than this to touching add to the projection's metric.
CONTACT_RANGE = 0.01
#: m: the lever arm that turns the linear slop into the lock rows' angular slop (rad).
ANGULAR_SLOP_LEVER = 0.25
#: rad: the most a pass may turn a body.
MAX_TURN = 1.0
#: A pass that left a world's error larger is retried at half its step at most
#: this many times (each retry one of the passes); then the world stops.
MAX_HALVINGS = 3
#: A world's passes stop once its error beyond the slop is at most this
#: fraction of its smallest slop; a joint must exceed its slop by more than
#: this fraction of it to start a projection.
TOLERANCE = 0.01


# ------------------------------------------------------------------ helpers
@kernel
def _maximum(a, b):
    """np.maximum of two floats: NaN if either is NaN."""
    if math.isnan(a):
        return a
    if math.isnan(b):
        return b
    return max(a, b)


@kernel
def _pairwise_block(a, lo, n):
    """Σ a[lo:lo + n] for n <= 128 as numpy's pairwise summation sums it:
    below 8 terms in order, else in eight interleaved partial sums."""
    if n < 8:
        s = 0.0
        for i in range(lo, lo + n):
            s += a[i]
        return s
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    end = n - n % 8
    while i < end:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        s += a[lo + i]
        i += 1
    return s


@allocating_kernel
def _pairwise(a, lo, n):
    """Σ a[lo:lo + n] by numpy's pairwise summation (``pairwise_sum`` of
    numpy's add.reduce on a contiguous run): up to 128 terms by
    ``_pairwise_block``, above that the two halves (the first a multiple of
    8 long) summed apart and added. The halving is walked with an explicit
    stack (numba's cache does not take recursive functions)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    s_lo = np.empty(64, dtype=np.int64)
    s_n = np.empty(64, dtype=np.int64)
    stage = np.empty(64, dtype=np.int64)  # 0: start, 1: left half done, 2: right half done
    left = np.empty(64)
    top = 0
    s_lo[0], s_n[0], stage[0] = lo, n, 0
    ret = 0.0
    while top >= 0:
        m = s_n[top]
        half = m // 2
        half -= half % 8
        if stage[top] == 0:
            if m <= 128:
                ret = _pairwise_block(a, s_lo[top], m)
                top -= 1
                continue
            stage[top] = 1
            top += 1
            s_lo[top], s_n[top], stage[top] = s_lo[top - 1], half, 0
        elif stage[top] == 1:
            left[top] = ret
            stage[top] = 2
            top += 1
            s_lo[top], s_n[top], stage[top] = s_lo[top - 1] + half, m - half, 0
        else:
            ret = left[top] + ret
            top -= 1
    return ret


@kernel
def frames(T, J, x, q, fpw, fcw, ra, rb):
    """The joint frames in the world fpw, fcw (J, 4) and lever arms ra, rb
    (J, 3) m of the rows' joints at positions x (N, 3), orientations q (N, 4)
    (those of ``joints._geometry_world``, the same products)."""
    for j in range(T.joint.size):
        jj = T.joint[j]
        qa, qb = load4(q, T.a[j]), load4(q, T.b[j])
        store4(fpw, jj, quat_mul(qa, load4(J.frame_p, jj)))
        store4(fcw, jj, quat_mul(qb, load4(J.frame_c, jj)))
        store3(ra, jj, rotate(qa, load3(J.anchor_p, jj)))
        store3(rb, jj, rotate(qb, load3(J.anchor_c, jj)))


# ------------------------------------------------------------------ one world
@allocating_kernel
def beyond_slop(T, J, use, lin_slop, x, q, broken):
    """Whether a used (``use`` (nj,)), unbroken joint of the rows ``T`` has
    its anchors apart by more than its linear slop ``lin_slop`` (nj,) m, or
    its lock rows' angular error beyond lin_slop / ANGULAR_SLOP_LEVER rad,
    each slop widened by TOLERANCE: the test for projecting a world. A
    hinge's error a_p × a_c is normal to a_p, so its two lock rows hold all
    of it; a fixed joint's rows are the whole vector; a ball joint has none."""
    nJ = J.kind.size
    fpw, fcw = np.empty((nJ, 4)), np.empty((nJ, 4))
    ra, rb = np.empty((nJ, 3)), np.empty((nJ, 3))
    frames(T, J, x, q, fpw, fcw, ra, rb)
    widen = 1.0 + TOLERANCE
    for j in range(T.joint.size):
        if not use[j] or broken[T.joint[j]]:
            continue
        lin, ang = position_errors(T, j, x, fpw, fcw, ra, rb)
        if math.sqrt(lin[0] * lin[0] + lin[1] * lin[1] + lin[2] * lin[2]) > lin_slop[j] * widen:
            return True
        locked = T.ang_mask[j, 0] != 0.0 or T.ang_mask[j, 1] != 0.0 or T.ang_mask[j, 2] != 0.0
        if locked and (math.sqrt(ang[0] * ang[0] + ang[1] * ang[1] + ang[2] * ang[2])
                       > (lin_slop[j] / ANGULAR_SLOP_LEVER) * widen):
            return True
    return False


@allocating_kernel
def merit(T, J, keep, lin_slop, x, q, broken, fpw, fcw, ra, rb, E, mask, Ja, Jb, C, sq):
    """The tree rows at positions x, q: blocks E, mask, Ja, Jb (as
    ``tree_solve.blocks``) and C (nj, 6), the position errors of the kept
    (``keep``) joints shrunk by their slop (linear rows by ``lin_slop``,
    angular by lin_slop / ANGULAR_SLOP_LEVER): what is left beyond it.
    Returns the merit, √(Σ C_lin² + ANGULAR_SLOP_LEVER² Σ C_ang²) (m);
    ``sq`` (3 nj,) is scratch."""
    nj = T.joint.size
    frames(T, J, x, q, fpw, fcw, ra, rb)
    blocks(T, fpw, ra, rb, broken, E, mask, Ja, Jb)
    rate = np.ones(nj)
    right_hand_side(T, E, mask, fpw, fcw, ra, rb, x, q, x, x, False, True, rate, math.inf, math.inf, C)
    for j in range(nj):
        k = 1.0 if keep[j] else 0.0
        for part in range(2):
            o = 3 * part
            for s in range(3):
                C[j, o + s] = C[j, o + s] * k
            allowed = lin_slop[j] if part == 0 else lin_slop[j] / ANGULAR_SLOP_LEVER
            c0, c1, c2 = C[j, o], C[j, o + 1], C[j, o + 2]
            n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            f = _maximum(0.0, 1.0 - allowed / _maximum(n, 1e-300))
            for s in range(3):
                C[j, o + s] = C[j, o + s] * f
    for j in range(nj):
        for s in range(3):
            sq[3 * j + s] = C[j, s] * C[j, s]
    lin = _pairwise(sq, 0, 3 * nj)
    for j in range(nj):
        for s in range(3):
            sq[3 * j + s] = C[j, 3 + s] * C[j, 3 + s]
    ang = _pairwise(sq, 0, 3 * nj)
    return math.sqrt(lin + ANGULAR_SLOP_LEVER ** 2 * ang)


@kernel
def _add_point(P, body, lever, normal, k):
    """P[body] += k u uᵀ, u = (n, r × n): a spring of stiffness k against
    moving the point at lever r along n."""
    rn = cross(lever, normal)
    u = (normal[0], normal[1], normal[2], rn[0], rn[1], rn[2])
    for r in range(6):
        ku = k * u[r]
        for c in range(6):
            P[body, r, c] += ku * u[c]


@allocating_kernel
def metric(T, q, M_tree, mass, weight, row_lo, row_hi, row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep,
           m_lo, m_hi, m_body, m_lever, m_normal, M, M_inv):
    """The projection's metric of one world: M (nb, 6, 6) = the tree bodies'
    M_tree plus the contact terms, and its inverse M_inv (N, 6, 6) on every
    body (0 outside the tree). Contact terms, with ``weight`` > 0: the points
    of the contact rows ``row_order[row_lo:row_hi]`` (sides a, b, moving
    flags, levers in the bodies' frames la, lb (R, 4, 3), normal cn, valid and
    separation sep (R, 4) m) within CONTACT_RANGE of touching, at weight ×
    mass × (CONTACT_RANGE - sep) / CONTACT_RANGE, and the moved points
    ``m_lo:m_hi`` (body, lever in the body's frame, normal) at weight × mass;
    levers turned by the orientations q (N, 4). A world with a non-finite
    metric gets the identity (it is reported non-finite after the step)."""
    N = q.shape[0]
    nb = T.bodies.size
    P = np.zeros((N, 6, 6))
    if weight > 0:
        for side in range(2):
            for j in range(4):
                for k in range(row_lo, row_hi):
                    r = row_order[k]
                    moves = dyn_b[r] if side == 0 else dyn_a[r]
                    s = sep[r, j]
                    if not (valid[r, j] and s < CONTACT_RANGE and moves):
                        continue
                    ramp = min(max((CONTACT_RANGE - s) / CONTACT_RANGE, 0.0), 1.0)
                    if side == 0:
                        body = cb[r]
                        local = (lb[r, j, 0], lb[r, j, 1], lb[r, j, 2])
                    else:
                        body = ca[r]
                        local = (la[r, j, 0], la[r, j, 1], la[r, j, 2])
                    lever = rotate(load4(q, body), local)
                    _add_point(P, body, lever, load3(cn, r), weight * mass[body] * ramp)
        for k in range(m_lo, m_hi):
            body = m_body[k]
            lever = rotate(load4(q, body), load3(m_lever, k))
            _add_point(P, body, lever, load3(m_normal, k), weight * mass[body])
    finite = True
    for kk in range(nb):
        body = T.bodies[kk]
        for r in range(6):
            for c in range(6):
                v = M_tree[kk, r, c] + P[body, r, c]
                M[kk, r, c] = v
                if not np.isfinite(v):
                    finite = False
    if not finite:
        for kk in range(nb):
            for r in range(6):
                for c in range(6):
                    M[kk, r, c] = 1.0 if r == c else 0.0
    for i in range(N):
        for r in range(6):
            for c in range(6):
                M_inv[i, r, c] = 0.0
    work = np.empty((1, 6, 6))
    for kk in range(nb):
        for r in range(6):
            for c in range(6):
                work[0, r, c] = M[kk, r, c]
        inverse6_into(work, 0, M_inv, T.bodies[kk])


@kernel
def _exp_turn(q, omega):
    """q turned by the rotation vector ω (rad): exp(ω/2) ⊗ q, renormalised
    (``math3d.quat_exp_integrate`` over h = 1, the same operations)."""
    angle = math.sqrt(omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2]) * 1.0
    half = 0.5 * angle
    if angle < 1e-8:
        s_over = 0.5 - angle * angle / 48.0
    else:
        s_over = math.sin(half) / angle
    f = s_over * 1.0
    dq = (math.cos(half), omega[0] * f, omega[1] * f, omega[2] * f)
    return quat_normalize(quat_mul(dq, q))


@allocating_kernel
def project(T, layout, J, keep, lin_slop, x, q, broken, M, M_inv, passes):
    """At most ``passes`` Gauss-Newton passes on one world's positions x
    (N, 3) and orientations q (N, 4), in place, in the metric M (nb, 6, 6),
    M_inv (N, 6, 6) (``metric``); ``keep`` (nj,): the joints projected,
    ``lin_slop`` (nj,) m their slop. Returns the merit at the end (m). Only
    bodies that move are written (a renormalised quaternion can differ in
    its last bit)."""
    nj = T.joint.size
    N = x.shape[0]
    nb = T.bodies.size
    nn = layout.order.size
    nJ = J.kind.size
    smallest = math.inf
    for j in range(nj):
        if keep[j]:
            smallest = min(smallest, lin_slop[j])
    stop = TOLERANCE * smallest
    M_inv_tree = np.empty((nb, 6, 6))
    for kk in range(nb):
        for r in range(6):
            for c in range(6):
                M_inv_tree[kk, r, c] = M_inv[T.bodies[kk], r, c]
    fpw, fcw = np.empty((nJ, 4)), np.empty((nJ, 4))
    ra, rb = np.empty((nJ, 3)), np.empty((nJ, 3))
    E, mask = np.empty((nj, 3, 3)), np.empty((nj, 6))
    Ja, Jb = np.empty((nj, 6, 6)), np.empty((nj, 6, 6))
    C, mask_k = np.empty((nj, 6)), np.empty((nj, 6))
    sq = np.empty(3 * nj)
    Dinv, L = np.empty((nn, 6, 6)), np.empty((nn, 6, 6))
    acc, work = factor_scratch(nn)
    rhs, X = np.empty((nj, 6, 1)), np.empty((nj, 6, 1))
    mu = np.empty((nj, 6))
    imp, d, last = np.empty((N, 6)), np.zeros((N, 6)), np.zeros((N, 6))
    bx, bq = np.empty((N, 3)), np.empty((N, 4))
    halvings = 0
    have_before = False
    before_err = 0.0
    err = 0.0
    for k in range(passes + 1):
        err = merit(T, J, keep, lin_slop, x, q, broken, fpw, fcw, ra, rb, E, mask, Ja, Jb, C, sq)
        back = False
        if have_before:
            # A pass that left the error larger is taken back: the
            # linearisation does not hold that far out. The next pass tries
            # half that step from the same start (backtracking), up to
            # MAX_HALVINGS times, after which the world stops.
            if err > before_err:
                halvings += 1
                for i in range(N):
                    for c in range(3):
                        x[i, c] = bx[i, c]
                    for c in range(4):
                        q[i, c] = bq[i, c]
                err = before_err
                if halvings > MAX_HALVINGS:
                    return err
                back = True
            else:
                halvings = 0
        if k == passes or not err > stop:
            return err
        if back:
            for i in range(N):
                for c in range(6):
                    d[i, c] = 0.5 * last[i, c]
        else:
            for j in range(nj):
                kj = 1.0 if keep[j] else 0.0
                for s in range(6):
                    mask_k[j, s] = mask[j, s] * kj
                    rhs[j, s, 0] = C[j, s]
            factor(layout, Ja, Jb, mask_k, M, M_inv_tree, True, True, Dinv, L, acc, work)
            substitute(layout, Dinv, L, rhs, X)
            for j in range(nj):
                for s in range(6):
                    mu[j, s] = -X[j, s, 0]
            body_impulses(T, Ja, Jb, mu, imp)
            turn = 0.0  # the largest turn (rad), NaN if any is (numpy's max)
            nan = False
            for i in range(N):
                for r in range(6):
                    v = 0.0
                    for c in range(6):
                        v += M_inv[i, r, c] * imp[i, c]
                    d[i, r] = v
                t = math.sqrt(d[i, 3] * d[i, 3] + d[i, 4] * d[i, 4] + d[i, 5] * d[i, 5])
                if math.isnan(t):
                    nan = True
                elif t > turn:
                    turn = t
            if nan:
                turn = math.nan
            # At most MAX_TURN rad for any body per pass, the whole world's step scaled alike.
            f = MAX_TURN / _maximum(turn, MAX_TURN)
            for i in range(N):
                for c in range(6):
                    d[i, c] = d[i, c] * f
        before_err = err
        have_before = True
        for i in range(N):
            for c in range(3):
                bx[i, c] = x[i, c]
            for c in range(4):
                bq[i, c] = q[i, c]
            for c in range(6):
                last[i, c] = d[i, c]
        for i in range(N):
            if (d[i, 0] != 0.0 or d[i, 1] != 0.0 or d[i, 2] != 0.0 or d[i, 3] != 0.0 or d[i, 4] != 0.0
                    or d[i, 5] != 0.0):
                for c in range(3):
                    x[i, c] = x[i, c] + d[i, c]
                store4(q, i, _exp_turn(load4(q, i), (d[i, 3], d[i, 4], d[i, 5])))
    return err


@allocating_kernel
def project_world(T, layout, J, keep, lin_slop, x, q, broken, M_tree, mass, weight, row_lo, row_hi, row_order, ca,
                  cb, dyn_a, dyn_b, la, lb, cn, valid, sep, m_lo, m_hi, m_body, m_lever, m_normal, passes):
    """``metric`` then ``project`` of one world; returns its merit at the end (m)."""
    N = x.shape[0]
    M = np.empty((T.bodies.size, 6, 6))
    M_inv = np.empty((N, 6, 6))
    metric(T, q, M_tree, mass, weight, row_lo, row_hi, row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep,
           m_lo, m_hi, m_body, m_lever, m_normal, M, M_inv)
    return project(T, layout, J, keep, lin_slop, x, q, broken, M, M_inv, passes)


@allocating_kernel
def _merit_world(T, J, keep, lin_slop, x, q, broken):
    """``merit`` of one world with its own scratch."""
    nj, nJ = T.joint.size, J.kind.size
    return merit(T, J, keep, lin_slop, x, q, broken, np.empty((nJ, 4)), np.empty((nJ, 4)), np.empty((nJ, 3)),
                 np.empty((nJ, 3)), np.empty((nj, 3, 3)), np.empty((nj, 6)), np.empty((nj, 6, 6)),
                 np.empty((nj, 6, 6)), np.empty((nj, 6)), np.empty(3 * nj))


@allocating_kernel
def _project_one(T, layout, J, w, keep, lin_slop, x, q, broken, M_tree, mass, weight, row_start, row_order, ca, cb,
                 dyn_a, dyn_b, la, lb, cn, valid, sep, m_start, m_body, m_lever, m_normal, passes, err, i):
    err[i] = project_world(T, layout, J, keep, lin_slop[w], x[w], q[w], broken[w], M_tree[w], mass, weight,
                           row_start[w], row_start[w + 1], row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep,
                           m_start[w], m_start[w + 1], m_body, m_lever, m_normal, passes)


@allocating_kernel
def _beyond_one(T, J, w, use, lin_slop, x, q, broken, out, i):
    out[i] = beyond_slop(T, J, use, lin_slop[w], x[w], q[w], broken[w])


@allocating_kernel
def _merit_one(T, J, w, keep, lin_slop, x, q, broken, out, i):
    out[i] = _merit_world(T, J, keep, lin_slop[w], x[w], q[w], broken[w])


# ------------------------------------------------------------------ batches
@parallel_kernel
def beyond_slop_batch(T, J, worlds, use, lin_slop, x, q, broken, out):
    """``beyond_slop`` of each world in ``worlds`` into out (len(worlds),)
    (lin_slop (W, nj); x, q, broken: the state's arrays)."""
    n = worlds.size
    if n < SERIAL_BELOW:
        for i in range(n):
            _beyond_one(T, J, worlds[i], use, lin_slop, x, q, broken, out, i)
    else:
        for i in prange(n):
            _beyond_one(T, J, worlds[i], use, lin_slop, x, q, broken, out, i)


@parallel_kernel
def merit_batch(T, J, worlds, keep, lin_slop, x, q, broken, out):
    """``merit`` of each world in ``worlds`` into out (len(worlds),) m."""
    n = worlds.size
    if n < SERIAL_BELOW:
        for i in range(n):
            _merit_one(T, J, worlds[i], keep, lin_slop, x, q, broken, out, i)
    else:
        for i in prange(n):
            _merit_one(T, J, worlds[i], keep, lin_slop, x, q, broken, out, i)


@parallel_kernel
def project_batch(T, layout, J, worlds, keep, lin_slop, x, q, broken, M_tree, mass, weight, row_start, row_order,
                  ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep, m_start, m_body, m_lever, m_normal, passes, err):
    """``project_world`` of each world in ``worlds``, in place on the state's
    x, q (W, N, ...); M_tree (W, nb, 6, 6): the step's tree metric; the
    contact rows of world w are row_order[row_start[w]:row_start[w + 1]],
    its moved points m_start[w]:m_start[w + 1]. err (len(worlds),): the
    merit each world is left with (m)."""
    n = worlds.size
    if n < SERIAL_BELOW:
        for i in range(n):
            _project_one(T, layout, J, worlds[i], keep, lin_slop, x, q, broken, M_tree, mass, weight, row_start,
                         row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep, m_start, m_body, m_lever,
                         m_normal, passes, err, i)
    else:
        for i in prange(n):
            _project_one(T, layout, J, worlds[i], keep, lin_slop, x, q, broken, M_tree, mass, weight, row_start,
                         row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep, m_start, m_body, m_lever,
                         m_normal, passes, err, i)


@allocating_kernel
def _metric_one(T, w, q, M_tree, mass, weight, row_start, row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid, sep,
                m_start, m_body, m_lever, m_normal, M, M_inv, i):
    metric(T, q[w], M_tree[w], mass, weight, row_start[w], row_start[w + 1], row_order, ca, cb, dyn_a, dyn_b, la,
           lb, cn, valid, sep, m_start[w], m_start[w + 1], m_body, m_lever, m_normal, M[i], M_inv[i])


@parallel_kernel
def metric_batch(T, worlds, q, M_tree, mass, weight, row_start, row_order, ca, cb, dyn_a, dyn_b, la, lb, cn, valid,
                 sep, m_start, m_body, m_lever, m_normal, M, M_inv):
    """``metric`` of each world in ``worlds`` into M (len(worlds), nb, 6, 6)
    and M_inv (len(worlds), N, 6, 6) (for the loop-closing rows' path)."""
    n = worlds.size
    if n < SERIAL_BELOW:
        for i in range(n):
            _metric_one(T, worlds[i], q, M_tree, mass, weight, row_start, row_order, ca, cb, dyn_a, dyn_b, la, lb,
                        cn, valid, sep, m_start, m_body, m_lever, m_normal, M, M_inv, i)
    else:
        for i in prange(n):
            _metric_one(T, worlds[i], q, M_tree, mass, weight, row_start, row_order, ca, cb, dyn_a, dyn_b, la, lb,
                        cn, valid, sep, m_start, m_body, m_lever, m_normal, M, M_inv, i)
