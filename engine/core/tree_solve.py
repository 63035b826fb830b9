"""The joint tree's velocity solve of one world: the bodies' metric, the
rows' Jacobian blocks and right-hand sides, the limit rows by their active
set, and the impulses (the factorisation itself is :mod:`engine.core.tree`).

Rows. Each tree joint has 6 rows on its sides a (parent body) and b (child
body): 3 point rows, whose velocity error is the anchors' relative velocity
v_b + ω_b × r_b - v_a - ω_a × r_a, and 3 angular rows E (ω_b - ω_a) with E's
rows the locked axes (hinge: the parent frame's y and z, fixed: the world
axes, ball: none). The blocks are J_b = [[I, -[r_b]×], [0, E]] and
J_a = -[[I, -[r_a]×], [0, E]], each row scaled by its mask (1 used, 0 unused
or broken). The right-hand side is r = J u + bias (clamped position error);
x = (J M⁻¹ Jᵀ)⁻¹ r and the soft step's impulse is d = -mass_scale x -
impulse_scale λ (Catto's soft step, Box2D v3 ``b2_solverStage``).

Limits. A joint's free angular slots hold its limit rows: slot 3 the twist
row (hinges and ball joints), slot 4 the swing row (ball joints). A limit
row is one-sided (σ λ ≥ 0) and rigid, so its impulse is found whole by an
active set: start from the rows the velocities would violate, drop rows
whose impulse pulls, add rows the solve drives past their bound. With at
most ``SCHUR_LIMIT_ROWS`` candidate rows the equality rows alone are
factored once per set of positions and each pass adds its active limit rows
A by their Schur complement (the range-space update of active-set methods,
Nocedal & Wright 2006, ch. 16): with x_E0 = A_EE⁻¹ r_E the equality rows'
solution, the limit rows' is S x_A = lr_A - J_A M⁻¹ J_Eᵀ x_E0 with
S = J_A P J_Aᵀ, P = M⁻¹ - M⁻¹ J_Eᵀ A_EE⁻¹ J_E M⁻¹ the bodies' block of
[M J_Eᵀ; J_E 0]⁻¹, and the equality rows' x_E = A_EE⁻¹ (r_E - J_E M⁻¹ J_Aᵀ
x_A), one substitution with J_Aᵀ x_A on the bodies. S is summed from walks
up the tree of the rows that are active (``tree.walk_up``,
``tree.path_product``), each walked once a solve. With more candidate rows,
each pass factors the system of its active rows afresh.

Metric. The tree bodies' metric is M = blockdiag(m I, I_w); with geometric
stiffness (Andrews, Teichmann & Kry 2017; Tournier et al. 2015) a joint
carrying an impulse λ at lever arm r adds h |λ| (|r|² I - r rᵀ)/|r| to each
of its bodies' inertia (the implicit-Euler share h² K of its stiffness),
capped at a multiple of the body's own inertia's trace.

Every function here is for one world; the batched entry points at the end
call them once per world. Nodes, joints and bodies are numbered as in
:mod:`engine.core.tree`: tree bodies 0..nb-1, tree joints 0..nj-1.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .jit import SERIAL_BELOW, allocating_kernel, inlined_kernel, kernel, parallel_kernel, prange
from .tree import factor, path_product, solve_nodes, substitute_one, sym3_inverse_into, walk_up
from .vec import (
    add,
    add_scaled,
    cross,
    dot,
    load3,
    load4,
    mat3_vec,
    minimum,
    quat_conj,
    quat_mul,
    rotate,
    scale,
    sub,
)

#: rad/s: a limit row closing faster than this after a solve joins the active set.
ACTIVE_SET_TOLERANCE = 1e-6
#: Most limit rows in a tree for its active set on one factorisation; with more,
#: each active-set pass factors the system of its active rows (``solve_world``'s ``schur``).
SCHUR_LIMIT_ROWS = 48


class TreeRows(NamedTuple):
    """The tree joints as rows and the tree bodies, read-only (nj joints, nb bodies, k limit rows)."""

    joint: np.ndarray  # (nj,) int64: the model's joint index of each tree joint
    a: np.ndarray  # (nj,) int64: side a (parent body)
    b: np.ndarray  # (nj,) int64: side b (child body)
    hinge: np.ndarray  # (nj,) bool
    fixed: np.ndarray  # (nj,) bool
    ball: np.ndarray  # (nj,) bool
    ang_mask: np.ndarray  # (nj, 3): the angular lock rows each kind uses
    eq_mask: np.ndarray  # (nj, 6): rows stored as the joint's impulses (point and lock rows)
    lo: np.ndarray  # (nj,) rad: lower twist bound, 0 where infinite
    hi: np.ndarray  # (nj,) rad: upper twist bound, 0 where infinite
    lo_finite: np.ndarray  # (nj,) bool
    hi_finite: np.ndarray  # (nj,) bool
    limit_exists: np.ndarray  # (nj, 2) bool: twist and swing rows of the whole joint
    cand_joint: np.ndarray  # (k,) int64: the tree joint of each possible limit row, twist rows first
    cand_slot: np.ndarray  # (k,) int64: 0 twist, 1 swing
    bodies: np.ndarray  # (nb,) int64: the tree bodies
    mass: np.ndarray  # (nb,) kg
    inertia: np.ndarray  # (nb, 3) kg m²: principal moments
    inv_mass: np.ndarray  # (N,) 1/kg of every body of the model


class TreeScratch(NamedTuple):
    """Per-world intermediates of the solve, kept between the solves of one set of positions."""

    E: np.ndarray  # (W, nj, 3, 3): lock-row axes
    mask: np.ndarray  # (W, nj, 6): the equality rows' mask
    Ja: np.ndarray  # (W, nj, 6, 6): blocks on side a (with the limit rows in their slots when limited)
    Jb: np.ndarray  # (W, nj, 6, 6): blocks on side b
    Dinv: np.ndarray  # (W, n, 6, 6): the factors
    L: np.ndarray  # (W, n, 6, 6)


def empty_scratch(W, nj, n) -> TreeScratch:
    return TreeScratch(np.zeros((W, nj, 3, 3)), np.zeros((W, nj, 6)), np.zeros((W, nj, 6, 6)),
                       np.zeros((W, nj, 6, 6)), np.zeros((W, n, 6, 6)), np.zeros((W, n, 6, 6)))


# ------------------------------------------------------------------ metric
@kernel
def metric(T, rot, iinv, geo_joint, geo_parent, geo_child, n_tree_loaded, weight, lam_lin, load_before,
           use_load_before, ra, rb, h, cap, use_geometric, iinv_out, M, M_inv, I, G):
    """The tree bodies' metric M and its inverse M_inv (nb, 6, 6) of one world.

    rot (N, 3, 3): the bodies' rotation matrices; iinv (N, 3, 3) their world
    inverse inertias, copied to iinv_out and, with ``use_geometric``, replaced
    there by the inverse of the stiffened inertia of every tree body that a
    loaded joint touches. Loaded joints: ``geo_joint`` (the tree joints, then
    the loop-closing joints solved with the tree, ``n_tree_loaded`` of the
    former) with parents, children and weights; λ = ``lam_lin`` (J, 3) N·s,
    with ``use_load_before`` the smaller of |λ| and ``load_before`` (J,);
    lever arms ra, rb (J, 3) m; h s; cap: the stiffness's trace at most
    cap times the body's inertia's. I (nb, 3, 3) and G (N, 3, 3): the
    caller's scratch (``metric_scratch``).
    """
    N = iinv.shape[0]
    nb = T.bodies.size
    for i in range(N):
        for r in range(3):
            for c in range(3):
                iinv_out[i, r, c] = iinv[i, r, c]
    for k in range(nb):
        body = T.bodies[k]
        R = rot[body]
        d0, d1, d2 = T.inertia[k, 0], T.inertia[k, 1], T.inertia[k, 2]
        for r in range(3):
            rd0, rd1, rd2 = R[r, 0] * d0, R[r, 1] * d1, R[r, 2] * d2
            for c in range(r, 3):
                v = rd0 * R[c, 0] + rd1 * R[c, 1] + rd2 * R[c, 2]
                I[k, r, c] = v
                I[k, c, r] = v
    if use_geometric:
        for i in range(N):
            for r in range(3):
                for c in range(3):
                    G[i, r, c] = 0.0
        n_loaded = geo_joint.size
        for part in range(2):
            lo, hi = (0, n_tree_loaded) if part == 0 else (n_tree_loaded, n_loaded)
            for side in range(2):
                for i in range(lo, hi):
                    j = geo_joint[i]
                    lam = load3(lam_lin, j)
                    f = math.sqrt(lam[0] * lam[0] + lam[1] * lam[1] + lam[2] * lam[2])
                    if use_load_before:
                        f = minimum(f, load_before[j])
                    f = f * h * weight[i]
                    r = load3(ra, j) if side == 0 else load3(rb, j)
                    body = geo_parent[i] if side == 0 else geo_child[i]
                    rn = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                    g = f / max(rn, 1e-12)
                    for p in range(3):
                        for q in range(3):
                            K = -r[p] * r[q]
                            if p == q:
                                K += rn * rn
                            G[body, p, q] += g * K
        for k in range(nb):
            body = T.bodies[k]
            Gb = G[body]
            trI = I[k, 0, 0] + I[k, 1, 1] + I[k, 2, 2]
            trG = Gb[0, 0] + Gb[1, 1] + Gb[2, 2]
            limit = cap * trI
            s = limit / trG if trG > limit else 1.0
            for r in range(3):
                for c in range(3):
                    I[k, r, c] = I[k, r, c] + Gb[r, c] * s
            if trG > 0.0:
                sym3_inverse_into(I, k, iinv_out, body)
    for k in range(nb):
        body = T.bodies[k]
        m, im = T.mass[k], T.inv_mass[body]
        for r in range(6):
            for c in range(6):
                M[k, r, c] = 0.0
                M_inv[k, r, c] = 0.0
        for r in range(3):
            M[k, r, r] = m
            M_inv[k, r, r] = im
            for c in range(3):
                M[k, 3 + r, 3 + c] = I[k, r, c]
                M_inv[k, 3 + r, 3 + c] = iinv_out[body, r, c]


@allocating_kernel
def metric_scratch(nb, N):
    """The scratch (I (nb, 3, 3), G (N, 3, 3)) of ``metric`` for nb tree
    bodies of N bodies, allocated once by a caller that computes it often."""
    return np.empty((nb, 3, 3)), np.empty((N, 3, 3))


# ------------------------------------------------------------------ rows
@kernel
def blocks(T, fpw, ra, rb, broken, E, mask, Ja, Jb):
    """The equality rows' lock axes E (nj, 3, 3), mask (nj, 6) and blocks
    Ja, Jb (nj, 6, 6) of one world from its joint geometry (frames fpw
    (J, 4), lever arms ra, rb (J, 3) m) and broken flags (J,)."""
    for j in range(T.joint.size):
        jj = T.joint[j]
        act = 0.0 if broken[jj] else 1.0
        for s in range(3):
            mask[j, s] = act
            mask[j, 3 + s] = act * T.ang_mask[j, s]
        for r in range(3):
            for c in range(3):
                E[j, r, c] = 0.0
        if T.hinge[j]:
            f = load4(fpw, jj)
            ey = rotate(f, (0.0, 1.0, 0.0))
            ez = rotate(f, (0.0, 0.0, 1.0))
            for c in range(3):
                E[j, 1, c] = ey[c]
                E[j, 2, c] = ez[c]
        elif T.fixed[j]:
            for c in range(3):
                E[j, c, c] = 1.0
        for side in range(2):
            out = Jb[j] if side == 0 else Ja[j]
            r = load3(rb, jj) if side == 0 else load3(ra, jj)
            for p in range(6):
                for q in range(6):
                    out[p, q] = 0.0
            for p in range(3):
                out[p, p] = 1.0
            # -[r]× = [[0, r_z, -r_y], [-r_z, 0, r_x], [r_y, -r_x, 0]]
            out[0, 4], out[0, 5] = r[2], -r[1]
            out[1, 3], out[1, 5] = -r[2], r[0]
            out[2, 3], out[2, 4] = r[1], -r[0]
            for p in range(3):
                for q in range(3):
                    out[3 + p, 3 + q] = E[j, p, q]
            for p in range(6):
                mp = mask[j, p]
                for q in range(6):
                    v = out[p, q] * mp
                    out[p, q] = v if side == 0 else -v


@kernel
def right_hand_side(T, E, mask, fpw, fcw, ra, rb, x, q, v, w, use_velocity, use_bias, bias_rate, max_push_out,
                    max_angular_push_out, r_out):
    """r = J u + bias (nj, 6) of one world, masked: the anchors' relative
    velocity and E (ω_b - ω_a) (without ``use_velocity``: 0), plus with
    ``use_bias`` the position errors times ``bias_rate`` (nj,) 1/s, clamped
    to ``max_push_out`` m/s and ``max_angular_push_out`` rad/s: the anchors'
    separation and the angular error (hinge: a_p × a_c of the two x axes;
    fixed: 2 vec(q_c q_p*) on the short arc)."""
    for j in range(T.joint.size):
        jj, a, b = T.joint[j], T.a[j], T.b[j]
        r_a, r_b = load3(ra, jj), load3(rb, jj)
        if use_velocity:
            wa, wb = load3(w, a), load3(w, b)
            lin = sub(sub(add(load3(v, b), cross(wb, r_b)), load3(v, a)), cross(wa, r_a))
            dw = sub(wb, wa)
            ang = mat3_vec(E, j, dw)
        else:
            lin = (0.0, 0.0, 0.0)
            ang = (0.0, 0.0, 0.0)
        rate = bias_rate[j]
        if use_bias and rate != 0.0:
            sep, err = position_errors(T, j, x, fpw, fcw, ra, rb)
            lin = add(lin, _clamp_norm(scale(rate, sep), max_push_out))
            ang = add(ang, mat3_vec(E, j, _clamp_norm(scale(rate, err), max_angular_push_out)))
        for s in range(3):
            r_out[j, s] = lin[s] * mask[j, s]
            r_out[j, 3 + s] = ang[s] * mask[j, 3 + s]


@kernel
def position_errors(T, j, x, fpw, fcw, ra, rb):
    """(separation, angular error) of row joint j: the anchors' separation
    x_b + r_b - x_a - r_a (m) and the angular error whose lock-row components
    the rows hold at zero (rad; hinge a_p × a_c of the two x axes, otherwise
    2 vec(q_c q_p*) on the short arc)."""
    jj, a, b = T.joint[j], T.a[j], T.b[j]
    lin = sub(sub(add(load3(x, b), load3(rb, jj)), load3(x, a)), load3(ra, jj))
    fp, fc = load4(fpw, jj), load4(fcw, jj)
    if T.hinge[j]:
        ang = cross(rotate(fp, (1.0, 0.0, 0.0)), rotate(fc, (1.0, 0.0, 0.0)))
    else:
        qd = quat_mul(fc, quat_conj(fp))
        sgn = -1.0 if qd[0] < 0 else 1.0
        ang = (2.0 * qd[1] * sgn, 2.0 * qd[2] * sgn, 2.0 * qd[3] * sgn)
    return lin, ang


@kernel
def _clamp_norm(a, limit):
    """a scaled down to length at most ``limit`` (as :func:`engine.math3d.clamp_norm`)."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return scale(min(n, limit) / max(n, 1e-300), a)


@kernel
def limit_rows(T, jt, twist, js, c_swing, twist_defined, broken, iinv, w, lam_limit, h, use_bias,
               max_angular_push_out, lrows, lr, sigma, exists, lower, L):
    """The limit rows of one world's tree joints, after taking their
    accumulated impulses off the angular velocities ``w`` (N, 3) (and
    zeroing ``lam_limit`` (J, 3): lower, upper, swing), so that the active
    set finds each limit impulse whole.

    Outputs per tree joint: lrows (nj, 2, 3) the twist and swing rows' axes,
    lr (nj, 2) their right-hand sides Ċ + σ bias (speculative C/h while
    open; when violated the clamped rigid bias in the biased solve, none in
    the relax), sigma (nj, 2) the sign with σ λ ≥ 0 required, exists
    (nj, 2) and lower (nj,): the twist row is the lower bound's (the bound
    the twist heads for by the substep's end). L (nj, 3): scratch, the
    warm-started limit impulse of each joint."""
    nj = T.joint.size
    for j in range(nj):
        jj = T.joint[j]
        l0, l1, l2 = lam_limit[jj, 0], lam_limit[jj, 1], lam_limit[jj, 2]
        imp = add_scaled(scale(l0 - l1, load3(jt, jj)), l2, load3(js, jj))
        for c in range(3):
            L[j, c] = imp[c]
        a = T.a[j]
        ia = mat3_vec(iinv, a, imp)
        for c in range(3):
            w[a, c] += ia[c]
    for j in range(nj):
        b = T.b[j]
        ib = mat3_vec(iinv, b, load3(L, j))
        for c in range(3):
            w[b, c] += -ib[c]
    for j in range(nj):
        jj = T.joint[j]
        for s in range(3):
            lam_limit[jj, s] = 0.0
    for j in range(nj):
        jj, a, b = T.joint[j], T.a[j], T.b[j]
        tw = twist[jj]
        C_lo = tw - T.lo[j] if T.lo_finite[j] else math.inf
        C_hi = T.hi[j] - tw if T.hi_finite[j] else math.inf
        wrel = sub(load3(w, b), load3(w, a))
        Jt, Js = load3(jt, jj), load3(js, jj)
        ahead = h * dot(Jt, wrel)
        low = C_lo + ahead <= C_hi - ahead
        lower[j] = low
        whole = not broken[jj]
        e0 = T.limit_exists[j, 0] and whole and twist_defined[jj]
        e1 = T.limit_exists[j, 1] and whole
        exists[j, 0], exists[j, 1] = e0, e1
        sigma[j, 0] = 1.0 if low else -1.0
        sigma[j, 1] = 1.0
        for c in range(3):
            lrows[j, 0, c] = Jt[c]
            lrows[j, 1, c] = Js[c] if T.ball[j] else 0.0
        C0 = minimum(C_lo, C_hi) if e0 else 0.0
        C1 = c_swing[jj] if e1 else 0.0
        for s in range(2):
            C = C0 if s == 0 else C1
            row = (lrows[j, s, 0], lrows[j, s, 1], lrows[j, s, 2])
            rate = row[0] * wrel[0] + row[1] * wrel[1] + row[2] * wrel[2]
            if C > 0:
                bias = C / h
            elif use_bias:
                bias = max(C / h, -max_angular_push_out)
            else:
                bias = 0.0
            val = rate + sigma[j, s] * bias
            lr[j, s] = val if exists[j, s] else 0.0


# ------------------------------------------------------------------ impulses
@kernel
def body_impulses(T, Ja, Jb, d, out):
    """out (N, 6) = Σ Jᵀ d per body of one world: side a's terms joint by
    joint, then side b's (the order of the numpy scatter this replaces)."""
    for i in range(out.shape[0]):
        for c in range(6):
            out[i, c] = 0.0
    for side in range(2):
        for j in range(T.joint.size):
            Jm = Ja[j] if side == 0 else Jb[j]
            body = T.a[j] if side == 0 else T.b[j]
            for c in range(6):
                s = 0.0
                for i in range(6):
                    s += Jm[i, c] * d[j, i]
                out[body, c] += s


@kernel
def _apply(T, d, imp, iinv, lam_lin, lam_ang, v, w):
    """Accumulate the equality impulses d * eq_mask into the joints' λ and
    apply the bodies' impulses imp (N, 6) = Jᵀ d to the velocities."""
    for j in range(T.joint.size):
        jj = T.joint[j]
        for s in range(3):
            lam_lin[jj, s] = lam_lin[jj, s] + d[j, s] * T.eq_mask[j, s]
            lam_ang[jj, s] = lam_ang[jj, s] + d[j, 3 + s] * T.eq_mask[j, 3 + s]
    for i in range(imp.shape[0]):
        im = T.inv_mass[i]
        for c in range(3):
            v[i, c] += imp[i, c] * im
        dw = mat3_vec(iinv, i, (imp[i, 3], imp[i, 4], imp[i, 5]))
        for c in range(3):
            w[i, c] += dw[c]


@kernel
def _soft_impulses(T, x, mask, lim, use_lim, mass_scale, impulse_scale, lam_lin, lam_ang, d):
    """d = (-mass_scale x - impulse_scale λ) mask, minus x lim with
    ``use_lim``: the soft step on the equality rows, the whole (rigid)
    impulse on the limit-taken slots."""
    for j in range(T.joint.size):
        jj = T.joint[j]
        ms, isc = mass_scale[j], impulse_scale[j]
        for s in range(6):
            lam = lam_lin[jj, s] if s < 3 else lam_ang[jj, s - 3]
            val = -ms * x[j, s]
            if isc != 0.0:
                val = val - isc * lam
            val = val * mask[j, s]
            if use_lim:
                val = val - x[j, s] * lim[j, s]
            d[j, s] = val


# ------------------------------------------------------------------ dense solve
@kernel
def solve_dense(A, b, n, zero):
    """b[:n] = A[:n, :n]⁻¹ b[:n] by Gaussian elimination with partial
    pivoting, A overwritten. An unknown whose pivot is zero (degenerate
    rows: the matrix singular in floating point) is set to 0 and left out
    of the elimination, the answer on the other rows; NaN propagates.
    zero (n,) bool: scratch."""
    for c in range(n):
        zero[c] = False
    for c in range(n):
        p = c
        big = abs(A[c, c])
        for r in range(c + 1, n):
            if abs(A[r, c]) > big:
                big = abs(A[r, c])
                p = r
        if big == 0.0:
            zero[c] = True
            continue
        if p != c:
            for k in range(n):
                t = A[c, k]
                A[c, k] = A[p, k]
                A[p, k] = t
            t = b[c]
            b[c] = b[p]
            b[p] = t
        piv = A[c, c]
        for r in range(c + 1, n):
            f = A[r, c] / piv
            if f != 0.0:
                for k in range(c + 1, n):
                    A[r, k] -= f * A[c, k]
                b[r] -= f * b[c]
            A[r, c] = 0.0
    for c in range(n - 1, -1, -1):
        if zero[c]:
            b[c] = 0.0
            continue
        s = b[c]
        for k in range(c + 1, n):
            s -= A[c, k] * b[k]
        b[c] = s / A[c, c]


# ------------------------------------------------------------------ the solve
@kernel
def _with_slots(T, on, lrows, mask, Ja, Jb, mask_out):
    """The limit rows where ``on`` (nj, 2) into the free slots 3 (twist) and
    4 (swing) of Ja, Jb (in place) and mask_out (a copy of mask)."""
    for j in range(T.joint.size):
        for s in range(6):
            mask_out[j, s] = mask[j, s]
        for k in range(2):
            if on[j, k]:
                for c in range(3):
                    Jb[j, 3 + k, 3 + c] = lrows[j, k, c]
                    Ja[j, 3 + k, 3 + c] = -lrows[j, k, c]
                mask_out[j, 3 + k] = 1.0


@kernel
def _slot_rhs(r, lr, on, rhs):
    """rhs = r with the limit rows' right-hand sides lr where ``on`` (nj, 2)
    in slots 3 (twist) and 4 (swing)."""
    for j in range(r.shape[0]):
        for s in range(6):
            val = r[j, s]
            if s == 3 and on[j, 0]:
                val = lr[j, 0]
            elif s == 4 and on[j, 1]:
                val = lr[j, 1]
            rhs[j, s] = val


# ------------------------------------------------------------------ work buffers
@allocating_kernel
def solve_work(nj, n, N, k):
    """The work buffers (float64, bool, int64) of ``solve_world`` for nj tree
    joints, n tree nodes, N bodies and k limit rows: allocated once by a
    caller that solves many times, carved into arrays by ``_work_views``."""
    floats = 131 * nj + 6 * N + 114 * n + k * k + k + 12 * k * n + 48
    return (np.empty(floats), np.empty(9 * nj + 2 * k, dtype=np.bool_),
            np.empty(2 * k + 2 * k * n, dtype=np.int64))


@inlined_kernel
def _work_views(fw, bw, iw, nj, n, N, k):
    """The arrays of one solve carved from the work buffers of ``solve_work``
    (uninitialised): lrows (nj, 2, 3), lr, lr0, dl and sigma (nj, 2); mask_f, rhs, r,
    lim, d (nj, 6); imp (N, 6); xs, x0 (nj, 6); Jaw, Jbw (nj, 6, 6);
    Dinv_w, L_w (n, 6, 6); S_A (k, k); delta (k,); ``factor``'s acc (n, 6, 6)
    and work (1, 6, 6); ``substitute_one``'s y (n, 6); ``limit_rows``' Lw
    (nj, 3); the limit rows' walks Yk, Zk (k, n, 6), y6 and e6 (6,); exists
    (nj, 2), lower (nj,), active, bad, add (nj, 2), ``solve_dense``'s zero
    (k,), walked (k,) (bool); act_idx (k,), the walks' length (k,), path
    and at (k, n) (int64)."""
    o = 0
    lrows = fw[o:o + 6 * nj].reshape((nj, 2, 3))
    o += 6 * nj
    lr = fw[o:o + 2 * nj].reshape((nj, 2))
    o += 2 * nj
    lr0 = fw[o:o + 2 * nj].reshape((nj, 2))
    o += 2 * nj
    dl = fw[o:o + 2 * nj].reshape((nj, 2))
    o += 2 * nj
    sigma = fw[o:o + 2 * nj].reshape((nj, 2))
    o += 2 * nj
    mask_f = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    rhs = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    r = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    lim = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    d = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    imp = fw[o:o + 6 * N].reshape((N, 6))
    o += 6 * N
    xs = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    x0 = fw[o:o + 6 * nj].reshape((nj, 6))
    o += 6 * nj
    Jaw = fw[o:o + 36 * nj].reshape((nj, 6, 6))
    o += 36 * nj
    Jbw = fw[o:o + 36 * nj].reshape((nj, 6, 6))
    o += 36 * nj
    Dinv_w = fw[o:o + 36 * n].reshape((n, 6, 6))
    o += 36 * n
    L_w = fw[o:o + 36 * n].reshape((n, 6, 6))
    o += 36 * n
    S_A = fw[o:o + k * k].reshape((k, k))
    o += k * k
    delta = fw[o:o + k]
    o += k
    acc = fw[o:o + 36 * n].reshape((n, 6, 6))
    o += 36 * n
    work = fw[o:o + 36].reshape((1, 6, 6))
    o += 36
    ys = fw[o:o + 6 * n].reshape((n, 6))
    o += 6 * n
    Lw = fw[o:o + 3 * nj].reshape((nj, 3))
    o += 3 * nj
    Yk = fw[o:o + 6 * k * n].reshape((k, n, 6))
    o += 6 * k * n
    Zk = fw[o:o + 6 * k * n].reshape((k, n, 6))
    o += 6 * k * n
    y6 = fw[o:o + 6]
    e6 = fw[o + 6:o + 12]
    zero = bw[9 * nj:9 * nj + k]
    walked = bw[9 * nj + k:9 * nj + 2 * k]
    length = iw[k:2 * k]
    path = iw[2 * k:2 * k + k * n].reshape((k, n))
    at = iw[2 * k + k * n:2 * k + 2 * k * n].reshape((k, n))
    exists = bw[0:2 * nj].reshape((nj, 2))
    lower = bw[2 * nj:3 * nj]
    active = bw[3 * nj:5 * nj].reshape((nj, 2))
    bad = bw[5 * nj:7 * nj].reshape((nj, 2))
    add = bw[7 * nj:9 * nj].reshape((nj, 2))
    return (lrows, lr, lr0, dl, sigma, mask_f, rhs, r, lim, d, imp, xs, x0, Jaw, Jbw, Dinv_w,
            L_w, S_A, delta, acc, work, ys, Lw, Yk, Zk, y6, e6, exists, lower, active, bad, add, zero, walked, iw[0:k],
            length, path, at)


@kernel
def _limit_impulses(T, on, lrows, d, imp):
    """imp (N, 6) += the limit rows' impulses d[j, 3 + s] along their axes
    lrows[j, s] where ``on`` (nj, 2): +axis on side b, -axis on side a."""
    for j in range(T.joint.size):
        a, b = T.a[j], T.b[j]
        for s in range(2):
            if on[j, s]:
                lam = d[j, 3 + s]
                for c in range(3):
                    t = lrows[j, s, c] * lam
                    imp[b, 3 + c] += t
                    imp[a, 3 + c] -= t


@kernel
def _limit_row_change(T, iinv, imp, lrows, out):
    """out (nj, 2) = J_lim (Δω_b - Δω_a) of every limit row (axes lrows
    (nj, 2, 3)) for the bodies' impulses imp (N, 6): the change of its
    velocity, rad/s, were they applied."""
    for j in range(T.joint.size):
        a, b = T.a[j], T.b[j]
        dwa = mat3_vec(iinv, a, (imp[a, 3], imp[a, 4], imp[a, 5]))
        dwb = mat3_vec(iinv, b, (imp[b, 3], imp[b, 4], imp[b, 5]))
        rel = sub(dwb, dwa)
        for s in range(2):
            out[j, s] = lrows[j, s, 0] * rel[0] + lrows[j, s, 1] * rel[1] + lrows[j, s, 2] * rel[2]


@kernel
def _walk_limit_row(T, layout, Dinv, L, j, s, lrows, y, inject, path, at, Y, Z, c):
    """Walk c of ``tree.walk_up``: F⁻¹ of limit row (j, s)'s body-space
    vector J_lᵀ (+axis on side b's angular rows, -axis on side a's), from
    the joint's tree child body up its path through the joint, picking up
    the other side at the joint's tree parent (none for a root joint, whose
    other side is static). Returns the path's length."""
    sign = 1.0 if layout.child_is_b[j] else -1.0
    for i in range(3):
        y[i] = 0.0
        inject[i] = 0.0
        y[3 + i] = sign * lrows[j, s, i]
        inject[3 + i] = -sign * lrows[j, s, i]
    return walk_up(layout.parent, Dinv, L, layout.joint_child[j], y, layout.parent[layout.n_bodies + j], inject,
                   path, at, Y, Z, c)


@kernel
def solve_world(T, layout, fpw, fcw, ra, rb, jt, twist, js, c_swing, twist_defined, broken, iinv, M, M_inv, x, q,
                v, w, lam_lin, lam_ang, lam_limit, bias_rate, mass_scale, impulse_scale, use_bias, h, max_push_out,
                max_angular_push_out, limits, schur, active_set_passes, refactor, S_E, S_mask, S_Ja, S_Jb, S_Dinv,
                S_L, fw, bw, iw):
    """One solve of the tree rows of one world, in place on the velocities
    v, w (N, 3) and the impulses λ (J, 3): the equality rows by the soft
    step and, with ``limits``, the limit rows by their active set
    (``active_set_passes`` passes at most; ``schur``: on one factorisation
    of the equality rows, the active limit rows added by their Schur
    complement, else factoring each pass). ``refactor``: the positions or
    the metric changed since the last solve, so the blocks and factors in
    the scratch (S_*) are rebuilt; otherwise they are reused.
    bias_rate, mass_scale, impulse_scale (nj,): the softness of each joint.
    fw, bw, iw: the caller's work buffers (``solve_work``), reused by every
    solve on its thread."""
    nj = T.joint.size
    nb = layout.n_bodies
    N = v.shape[0]
    k = T.cand_joint.size
    (lrows, lr, lr0, dl, sigma, mask_f, rhs, r, lim, d, imp, xs, x0, Jaw, Jbw, Dinv_w, L_w, S_A, delta, acc, work,
     ys, Lw, Yk, Zk, y6, e6, exists, lower, active, bad, add, zero, walked, act_idx, length, path, at) = _work_views(
        fw, bw, iw, nj, S_Dinv.shape[0], N, k)
    for j in range(nj):
        lower[j] = False
        for s in range(2):
            sigma[j, s] = 1.0
            lr[j, s] = 0.0
            exists[j, s] = False
            for c in range(3):
                lrows[j, s, c] = 0.0
        for s in range(6):
            lim[j, s] = 0.0
            d[j, s] = 0.0
    if limits:
        limit_rows(T, jt, twist, js, c_swing, twist_defined, broken, iinv, w, lam_limit, h, use_bias,
                   max_angular_push_out, lrows, lr, sigma, exists, lower, Lw)
    if refactor:
        blocks(T, fpw, ra, rb, broken, S_E, S_mask, S_Ja, S_Jb)
        if schur or not limits:
            # The equality rows alone (the limit rows, if any, join by their Schur complement).
            factor(layout, S_Ja, S_Jb, S_mask, M, M_inv, True, True, S_Dinv, S_L, acc, work)
    right_hand_side(T, S_E, S_mask, fpw, fcw, ra, rb, x, q, v, w, True, use_bias, bias_rate, max_push_out,
                    max_angular_push_out, r)
    if not limits:
        substitute_one(layout, S_Dinv, S_L, r, xs, ys)
        _soft_impulses(T, xs, S_mask, lim, False, mass_scale, impulse_scale, lam_lin, lam_ang, d)
        body_impulses(T, S_Ja, S_Jb, d, imp)
        _apply(T, d, imp, iinv, lam_lin, lam_ang, v, w)
        return
    for j in range(nj):
        for s in range(2):
            active[j, s] = exists[j, s] and sigma[j, s] * lr[j, s] < 0
    if schur:
        # x_E0 = A_EE⁻¹ r_E, and the limit rows' right-hand side after it:
        # lr0 = lr - J_L M⁻¹ J_Eᵀ x_E0.
        substitute_one(layout, S_Dinv, S_L, r, x0, ys)
        body_impulses(T, S_Ja, S_Jb, x0, imp)
        _limit_row_change(T, iinv, imp, lrows, dl)
        for j in range(nj):
            for s in range(2):
                lr0[j, s] = lr[j, s] - dl[j, s]
        for c in range(k):
            walked[c] = False
    Ja_use, Jb_use = S_Ja, S_Jb
    passes = 0
    for _ in range(active_set_passes):
        passes += 1
        # x = A⁻¹ r over the equality rows and the active limit rows.
        if schur:
            na = 0
            for c in range(k):
                if active[T.cand_joint[c], T.cand_slot[c]]:
                    act_idx[na] = c
                    na += 1
                    if not walked[c]:
                        length[c] = _walk_limit_row(T, layout, S_Dinv, S_L, T.cand_joint[c], T.cand_slot[c], lrows,
                                                    y6, e6, path, at, Yk, Zk, c)
                        walked[c] = True
            if na == 0:
                for j in range(nj):
                    for s in range(6):
                        xs[j, s] = x0[j, s]
            else:
                # S x_A = lr0_A, S = J_A P J_Aᵀ from the rows' walks (symmetric).
                for p in range(na):
                    cp = act_idx[p]
                    for qq in range(p, na):
                        val = path_product(path, length, Zk, at, Yk, cp, act_idx[qq])
                        S_A[p, qq] = val
                        S_A[qq, p] = val
                for p in range(na):
                    cp = act_idx[p]
                    delta[p] = lr0[T.cand_joint[cp], T.cand_slot[cp]]
                solve_dense(S_A, delta, na, zero)
                # x_E = A_EE⁻¹ (r_E - J_E M⁻¹ J_Aᵀ x_A): J_Aᵀ x_A on the bodies, r on the joints.
                for node in range(nb):
                    for s in range(6):
                        ys[node, s] = 0.0
                for j in range(nj):
                    for s in range(6):
                        ys[nb + j, s] = r[j, s]
                for p in range(na):
                    cp = act_idx[p]
                    j, sl = T.cand_joint[cp], T.cand_slot[cp]
                    sign = delta[p] if layout.child_is_b[j] else -delta[p]
                    child, parent = layout.joint_child[j], layout.parent[nb + j]
                    for c in range(3):
                        t = sign * lrows[j, sl, c]
                        ys[child, 3 + c] += t
                        if parent >= 0:
                            ys[parent, 3 + c] -= t
                solve_nodes(layout.order, layout.parent, S_Dinv, S_L, ys)
                for j in range(nj):
                    for s in range(6):
                        xs[j, s] = -ys[nb + j, s]
                for p in range(na):
                    cp = act_idx[p]
                    xs[T.cand_joint[cp], 3 + T.cand_slot[cp]] = delta[p]
        else:
            for j in range(nj):
                for p in range(6):
                    for qq in range(6):
                        Jaw[j, p, qq] = S_Ja[j, p, qq]
                        Jbw[j, p, qq] = S_Jb[j, p, qq]
            _with_slots(T, active, lrows, S_mask, Jaw, Jbw, mask_f)
            factor(layout, Jaw, Jbw, mask_f, M, M_inv, True, False, Dinv_w, L_w, acc, work)
            _slot_rhs(r, lr, active, rhs)
            substitute_one(layout, Dinv_w, L_w, rhs, xs, ys)
            Ja_use, Jb_use = Jaw, Jbw
        for j in range(nj):
            lim[j, 3] = 1.0 if active[j, 0] else 0.0
            lim[j, 4] = 1.0 if active[j, 1] else 0.0
        _soft_impulses(T, xs, S_mask, lim, True, mass_scale, impulse_scale, lam_lin, lam_ang, d)
        # The limit rows after the impulses: lr + J_lim (Δω_b - Δω_a).
        body_impulses(T, Ja_use, Jb_use, d, imp)
        if schur:
            _limit_impulses(T, active, lrows, d, imp)
        _limit_row_change(T, iinv, imp, lrows, dl)
        change = False
        for j in range(nj):
            for s in range(2):
                bad[j, s] = active[j, s] and sigma[j, s] * -xs[j, 3 + s] < 0
                after = lr[j, s] + dl[j, s]
                add[j, s] = exists[j, s] and not active[j, s] and sigma[j, s] * after < -ACTIVE_SET_TOLERANCE
                if bad[j, s] or add[j, s]:
                    change = True
        if not change:
            break
        # Drop pulling rows first; add violated rows once none of the joint's pulls.
        for j in range(nj):
            bad_joint = bad[j, 0] or bad[j, 1]
            for s in range(2):
                active[j, s] = (active[j, s] and not bad[j, s]) or (add[j, s] and not bad_joint)
    # The last pass's d (and its body impulses imp) is the one applied when the passes run out.
    if passes > 0:
        _apply(T, d, imp, iinv, lam_lin, lam_ang, v, w)
    for j in range(nj):
        jj = T.joint[j]
        tw = d[j, 3] * lim[j, 3]
        lam_limit[jj, 0] = tw if lower[j] else 0.0
        lam_limit[jj, 1] = 0.0 if lower[j] else -tw
        lam_limit[jj, 2] = d[j, 4] * lim[j, 4]


# ------------------------------------------------------------------ batches
@parallel_kernel
def metric_batch(T, rot, iinv, geo_joint, geo_parent, geo_child, n_tree_loaded, weight, lam_lin, load_before,
                 use_load_before, ra, rb, h, cap, use_geometric, iinv_out, M, M_inv):
    """``metric`` of every world (weight (W, loaded), load_before (W, J))."""
    nw = rot.shape[0]
    nb, N = T.bodies.size, rot.shape[1]
    if nw < SERIAL_BELOW:
        I, G = metric_scratch(nb, N)
        for wi in range(nw):
            metric(T, rot[wi], iinv[wi], geo_joint, geo_parent, geo_child, n_tree_loaded, weight[wi], lam_lin[wi],
                   load_before[wi], use_load_before, ra[wi], rb[wi], h, cap, use_geometric, iinv_out[wi], M[wi],
                   M_inv[wi], I, G)
    else:
        for wi in prange(nw):
            I, G = metric_scratch(nb, N)
            metric(T, rot[wi], iinv[wi], geo_joint, geo_parent, geo_child, n_tree_loaded, weight[wi], lam_lin[wi],
                   load_before[wi], use_load_before, ra[wi], rb[wi], h, cap, use_geometric, iinv_out[wi], M[wi],
                   M_inv[wi], I, G)


@parallel_kernel
def blocks_batch(T, fpw, ra, rb, broken, E, mask, Ja, Jb):
    """``blocks`` of every world."""
    nw = fpw.shape[0]
    if nw < SERIAL_BELOW:
        for wi in range(nw):
            blocks(T, fpw[wi], ra[wi], rb[wi], broken[wi], E[wi], mask[wi], Ja[wi], Jb[wi])
    else:
        for wi in prange(nw):
            blocks(T, fpw[wi], ra[wi], rb[wi], broken[wi], E[wi], mask[wi], Ja[wi], Jb[wi])


@parallel_kernel
def right_hand_side_batch(T, E, mask, fpw, fcw, ra, rb, x, q, v, w, use_velocity, use_bias, bias_rate, max_push_out,
                          max_angular_push_out, r_out):
    """``right_hand_side`` of every world (bias_rate (W, nj))."""
    nw = fpw.shape[0]
    if nw < SERIAL_BELOW:
        for wi in range(nw):
            right_hand_side(T, E[wi], mask[wi], fpw[wi], fcw[wi], ra[wi], rb[wi], x[wi], q[wi], v[wi], w[wi],
                            use_velocity, use_bias, bias_rate[wi], max_push_out, max_angular_push_out, r_out[wi])
    else:
        for wi in prange(nw):
            right_hand_side(T, E[wi], mask[wi], fpw[wi], fcw[wi], ra[wi], rb[wi], x[wi], q[wi], v[wi], w[wi],
                            use_velocity, use_bias, bias_rate[wi], max_push_out, max_angular_push_out, r_out[wi])


@parallel_kernel
def solve_batch(T, layout, g, broken, iinv, M, M_inv, x, q, v, w, lam_lin, lam_ang, lam_limit, bias_rate, mass_scale,
                impulse_scale, use_bias, h, max_push_out, max_angular_push_out, limits, schur, active_set_passes,
                refactor, S):
    """``solve_world`` of every world (g: the JointGeometry, S: the TreeScratch; softness (W, nj))."""
    nw = v.shape[0]
    if nw < SERIAL_BELOW:
        fw, bw, iw = solve_work(T.joint.size, S.Dinv.shape[1], v.shape[1], T.cand_joint.size)
        for wi in range(nw):
            solve_world(T, layout, g.fpw[wi], g.fcw[wi], g.ra[wi], g.rb[wi], g.jt[wi], g.twist[wi], g.js[wi],
                        g.c_swing[wi], g.twist_defined[wi], broken[wi], iinv[wi], M[wi], M_inv[wi], x[wi], q[wi],
                        v[wi], w[wi], lam_lin[wi], lam_ang[wi], lam_limit[wi], bias_rate[wi], mass_scale[wi],
                        impulse_scale[wi], use_bias, h, max_push_out, max_angular_push_out, limits, schur,
                        active_set_passes, refactor, S.E[wi], S.mask[wi], S.Ja[wi], S.Jb[wi], S.Dinv[wi], S.L[wi],
                        fw, bw, iw)
    else:
        for wi in prange(nw):
            fw, bw, iw = solve_work(T.joint.size, S.Dinv.shape[1], v.shape[1], T.cand_joint.size)
            solve_world(T, layout, g.fpw[wi], g.fcw[wi], g.ra[wi], g.rb[wi], g.jt[wi], g.twist[wi], g.js[wi],
                        g.c_swing[wi], g.twist_defined[wi], broken[wi], iinv[wi], M[wi], M_inv[wi], x[wi], q[wi],
                        v[wi], w[wi], lam_lin[wi], lam_ang[wi], lam_limit[wi], bias_rate[wi], mass_scale[wi],
                        impulse_scale[wi], use_bias, h, max_push_out, max_angular_push_out, limits, schur,
                        active_set_passes, refactor, S.E[wi], S.mask[wi], S.Ja[wi], S.Jb[wi], S.Dinv[wi], S.L[wi],
                        fw, bw, iw)


@parallel_kernel
def limit_rows_batch(T, g, broken, iinv, w, lam_limit, h, use_bias, max_angular_push_out, lrows, lr, sigma, exists,
                     lower):
    """``limit_rows`` of every world (g: the JointGeometry)."""
    nw = w.shape[0]
    nj = T.joint.size
    if nw < SERIAL_BELOW:
        L = np.empty((nj, 3))
        for wi in range(nw):
            limit_rows(T, g.jt[wi], g.twist[wi], g.js[wi], g.c_swing[wi], g.twist_defined[wi], broken[wi], iinv[wi],
                       w[wi], lam_limit[wi], h, use_bias, max_angular_push_out, lrows[wi], lr[wi], sigma[wi],
                       exists[wi], lower[wi], L)
    else:
        for wi in prange(nw):
            limit_rows(T, g.jt[wi], g.twist[wi], g.js[wi], g.c_swing[wi], g.twist_defined[wi], broken[wi], iinv[wi],
                       w[wi], lam_limit[wi], h, use_bias, max_angular_push_out, lrows[wi], lr[wi], sigma[wi],
                       exists[wi], lower[wi], np.empty((nj, 3)))
