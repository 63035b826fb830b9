"""Contacts of articulations on static bodies, solved in contact space with
the joint tree's response: kernels for one world and their batched entry
points (``engine.articulated_contacts`` gathers their inputs).

A world's valid contact points (of rows between a static body and a body
held by tree joints) each give three columns: the normal n and the tangents
t1, t2 of its row, on its body b with lever arm r, J_i = [d, r × d]. Per
world, with the tree's metric M (masses, world inertias) and its joint rows
J_t, the KKT system [M J_tᵀ; J_t 0] = F D Fᵀ is factored once per step by
:func:`engine.core.tree.factor` (Baraff 1996, "Linear-time dynamics using
Lagrange multipliers"). The constrained response to an impulse f on the
bodies is the body part of [M J_tᵀ; J_t 0]⁻¹ [f; 0],

    Z f = (M⁻¹ - M⁻¹ J_tᵀ K⁻¹ J_t M⁻¹) f,    K = J_t M⁻¹ J_tᵀ

(section 7: the Schur complement of the joints' KKT system), one tree
solve (:func:`engine.core.tree.solve_nodes`) for any number of columns:

* the Delassus matrix A = J_c Z J_cᵀ (columns x columns): A_ri =
  (F⁻¹ e_r)ᵀ D⁻¹ (F⁻¹ e_i), each column's forward substitution a walk up
  the path from its body to the root (``tree.walk_up``), each pair a sum
  over the nodes the two paths share; the effective masses m_i = 1 / A_ii
  (0 where A_ii <= 0);
* projected Gauss-Seidel sweeps on A (the normal columns, then the friction
  pairs in the Coulomb disc; the soft normal rows of the contact solver,
  :mod:`engine.core.contacts`), the column velocities u = J_c P v (P v =
  Z M v: the velocities projected onto the tree joints' rows) kept up to
  date column by column, then v += Z J_cᵀ Δλ on every body at once.

Layout: the points of all worlds packed world by world (``pt_start``, W + 1),
each world's points in row then slot order, point p's columns 3p (normal),
3p + 1, 3p + 2 (friction); A per world column by column (A[a_start[w] + i k
+ r] = A[r, i], k the world's column count), so a sweep's update of u by
column i reads it contiguously. Every sum runs in an order fixed by the
world's own data, so a world stepped alone is the same world in a batch bit
for bit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .contacts import separation
from .jit import SERIAL_BELOW, allocating_kernel, kernel, parallel_kernel, prange
from .tree import factor, factor_scratch, path_product, solve_nodes, walk_up, walks
from .tree_solve import blocks
from .vec import cross


class ArticulatedArrays(NamedTuple):
    """One step's contact columns on articulations (W batch worlds, P valid
    points, C = 3 P columns, N bodies a world, nb tree bodies)."""

    held: np.ndarray  # (H,) int64: the worlds with a row, in world order
    pt_start: np.ndarray  # (W + 1,) int64: world w's points are pt_start[w]..pt_start[w + 1]
    pt_row: np.ndarray  # (P,) int64: each point's contact row
    pt_slot: np.ndarray  # (P,) int64: its slot (0..3) in the row
    row_start: np.ndarray  # (W + 1,) int64: world w's rows are rows[row_start[w]..row_start[w + 1]]
    rows: np.ndarray  # (rows,) int64: the rows solved here, world by world
    tree_bodies: np.ndarray  # (nb,) int64: the tree's bodies, in body order (tree nodes 0..nb-1)
    node: np.ndarray  # (N,) int64: each body's tree node, -1 off the tree
    order: np.ndarray  # (n,) int64: the tree's nodes leaves first (``engine.core.tree.TreeLayout``)
    parent: np.ndarray  # (n,) int64: each node's tree parent, -1 for a root
    factors: np.ndarray  # (W,) int64: world w's factors are Dinv[factors[w]], L[factors[w]] (-1: none)
    Dinv: np.ndarray  # (H, n, 6, 6): the factors of [M J_tᵀ; J_t 0] at the step's start, of the held worlds
    L: np.ndarray  # (H, n, 6, 6)
    M: np.ndarray  # (W, nb, 6, 6): the tree's metric (kg, kg m²) at the step's start
    body: np.ndarray  # (C,) int64: each column's body
    J: np.ndarray  # (C, 6): each column's row of J_c on its body, [d, r × d]
    A: np.ndarray  # (Σ k_w²,): each world's Delassus matrix by columns (m/s per N s)
    a_start: np.ndarray  # (W + 1,) int64: world w's A starts at a_start[w]
    m: np.ndarray  # (C,) kg: effective masses 1 / A_ii
    mu: np.ndarray  # (P,) friction coefficient of each point
    finite: np.ndarray  # (W,) bool: the world's A is finite (the sweeps may skip unchanged columns)


class ContactView(NamedTuple):
    """The fields of the step's ``ContactRowArrays`` (:mod:`engine.core.contacts`)
    that the solve reads and writes, the same arrays: a kernel call's cost
    grows with the arrays it is handed."""

    a: np.ndarray
    b: np.ndarray
    n: np.ndarray
    xa0: np.ndarray
    xb0: np.ndarray
    ra: np.ndarray
    rb: np.ndarray
    la: np.ndarray
    lb: np.ndarray
    sep0: np.ndarray
    lam_n: np.ndarray
    lam_t1: np.ndarray
    lam_t2: np.ndarray
    max_lam_n: np.ndarray
    s_close: np.ndarray
    vn_close: np.ndarray


class SoftParams(NamedTuple):
    """The constants of one solve: h (s), the soft contacts' bias_rate (1/s),
    mass_scale, impulse_scale, slop (m), max_push_out (m/s), thesis (the
    thesis's rigid rows), sweeps (Gauss-Seidel sweeps a solve)."""

    h: float
    bias_rate: float
    mass_scale: float
    impulse_scale: float
    slop: float
    max_push_out: float
    thesis: bool
    sweeps: int


# ------------------------------------------------------------------ helpers
@kernel
def _maximum(a, b):
    """np.maximum(a, b) of two floats: NaN kept, b where equal."""
    if a > b or math.isnan(a):
        return a
    return b


@kernel
def _minimum(a, b):
    """np.minimum(a, b) of two floats: NaN kept, b where equal."""
    if a < b or math.isnan(a):
        return a
    return b


# ------------------------------------------------------------------ layout (all worlds)
@allocating_kernel
def layout(world_rows, world_start, a_dyn, b_dyn, b, jointed, valid, off_tree):
    """The packing of a step's articulated columns: of the contact rows by
    world (``ContactRows.world_rows``, ``row_start``: world by world, in
    row order), those between a static body (side a) and a jointed moving
    one (side b) whose body is not ``off_tree`` (N,) (articulations closed
    by loops keep the body-by-body rows), and their valid points in row then
    slot order; the rows' fields dyn_a, dyn_b, b, valid and ``jointed`` as
    ``ContactRowArrays`` holds them. Returns (rows, row_start, held, pt_row,
    pt_slot, pt_start, a_start, factors) as ``ArticulatedArrays`` holds them
    (``factors[w]``: world w's place among the held, -1 if none)."""
    W = world_start.size - 1
    R = world_rows.size
    rows = np.empty(R, dtype=np.int64)
    pt_row = np.empty(R * valid.shape[1], dtype=np.int64)
    pt_slot = np.empty(R * valid.shape[1], dtype=np.int64)
    row_start = np.zeros(W + 1, dtype=np.int64)
    pt_start = np.zeros(W + 1, dtype=np.int64)
    a_start = np.zeros(W + 1, dtype=np.int64)
    factors = np.full(W, -1, dtype=np.int64)
    nr = npt = H = 0
    for i in range(W):
        for k in range(world_start[i], world_start[i + 1]):
            r = world_rows[k]
            if jointed[r] and not a_dyn[r] and b_dyn[r] and not off_tree[b[r]]:
                rows[nr] = r
                nr += 1
                for j in range(valid.shape[1]):
                    if valid[r, j]:
                        pt_row[npt] = r
                        pt_slot[npt] = j
                        npt += 1
        row_start[i + 1] = nr
        pt_start[i + 1] = npt
        cols = 3 * (pt_start[i + 1] - pt_start[i])
        a_start[i + 1] = a_start[i] + cols * cols
        if nr > row_start[i]:
            factors[i] = H
            H += 1
    held = np.empty(H, dtype=np.int64)
    for i in range(W):
        if factors[i] >= 0:
            held[factors[i]] = i
    return rows[:nr].copy(), row_start, held, pt_row[:npt].copy(), pt_slot[:npt].copy(), pt_start, a_start, factors


@kernel
def _zero_rows(y):
    """y (n, 6) = 0."""
    for i in range(y.shape[0]):
        for c in range(6):
            y[i, c] = 0.0


@allocating_kernel
def solve_work(S, first, stop):
    """The work buffers (float64, bool) of ``_solve_world`` and
    ``_warm_start_world`` for the worlds first..stop-1 (room for the most
    points one of them has), allocated once by a caller that solves many
    times."""
    most = 0
    if S.pt_start.size > stop:
        for w in range(first, stop):
            most = max(most, S.pt_start[w + 1] - S.pt_start[w])
    return np.empty(19 * most + 6 * S.order.size), np.empty(most, dtype=np.bool_)


# ------------------------------------------------------------------ response (one world)
@allocating_kernel
def _response_world(R, S, T, layout, fpw, ra, rb, broken, M_inv, w):
    """The factors, J, body, A, m and the finite flag of world w
    (``ArticulatedArrays``), from the step's ``ContactRowArrays`` R, the
    tree's rows T and layout, the world's joint frames fpw (J, 4), lever
    arms ra, rb (J, 3) and broken flags (J,), and the inverse M_inv
    (nb, 6, 6) of its metric S.M[w]: the tree's equality rows factored at
    the step's start (``tree_solve.blocks``, ``tree.factor``)."""
    f = S.factors[w]
    Dinv, L = S.Dinv[f], S.L[f]
    nj = T.joint.size
    E, mask = np.empty((nj, 3, 3)), np.empty((nj, 6))
    Ja, Jb = np.empty((nj, 6, 6)), np.empty((nj, 6, 6))
    blocks(T, fpw, ra, rb, broken, E, mask, Ja, Jb)
    acc, work = factor_scratch(S.order.size)
    factor(layout, Ja, Jb, mask, S.M[w], M_inv, True, True, Dinv, L, acc, work)
    p0, p1 = S.pt_start[w], S.pt_start[w + 1]
    lo = 3 * p0
    k = 3 * (p1 - p0)
    if k == 0:
        return
    n = S.order.size
    # The columns' J on their bodies, each walked up its body's path: F⁻¹ J_iᵀ and D⁻¹ F⁻¹ J_iᵀ.
    path, length, at, Y, Zp = walks(k, n)
    y = np.empty(6)
    for p in range(p0, p1):
        r, s = S.pt_row[p], S.pt_slot[p]
        lever = (R.rb[r, s, 0], R.rb[r, s, 1], R.rb[r, s, 2])
        b = R.b[r]
        for q in range(3):
            if q == 0:
                d = (R.n[r, 0], R.n[r, 1], R.n[r, 2])
            elif q == 1:
                d = (R.t1[r, 0], R.t1[r, 1], R.t1[r, 2])
            else:
                d = (R.t2[r, 0], R.t2[r, 1], R.t2[r, 2])
            c = 3 * p + q
            t = cross(lever, d)
            S.body[c] = b
            S.J[c, 0], S.J[c, 1], S.J[c, 2] = d
            S.J[c, 3], S.J[c, 4], S.J[c, 5] = t
            for x in range(6):
                y[x] = S.J[c, x]
            i = c - lo
            length[i] = walk_up(S.parent, Dinv, L, S.node[b], y, -1, y, path, at, Y, Zp, i)
    # A[r, i] = J_r Z J_iᵀ, symmetric; m = 1 / A_ii.
    a0 = S.a_start[w]
    finite = True
    for i in range(k):
        for r in range(i, k):
            v = path_product(path, length, Zp, at, Y, i, r)
            S.A[a0 + i * k + r] = v
            S.A[a0 + r * k + i] = v
            if not math.isfinite(v):
                finite = False
        diag = S.A[a0 + i * k + i]
        S.m[lo + i] = 1.0 / diag if diag > 0.0 else 0.0
    S.finite[w] = finite
    for p in range(p0, p1):
        S.mu[p] = R.mu[S.pt_row[p], S.pt_slot[p]]


@parallel_kernel
def response(R, S, T, layout, fpw, ra, rb, broken, M_inv):
    """``_response_world`` of every world in S.held; fpw, ra, rb, broken
    (W, J, ...) and M_inv (W, nb, 6, 6) of the batch."""
    H = S.held.size
    if H < SERIAL_BELOW:
        for q in range(H):
            w = S.held[q]
            _response_world(R, S, T, layout, fpw[w], ra[w], rb[w], broken[w], M_inv[w], w)
    else:
        for q in prange(H):
            w = S.held[q]
            _response_world(R, S, T, layout, fpw[w], ra[w], rb[w], broken[w], M_inv[w], w)


# ------------------------------------------------------------------ velocities (one world)
@kernel
def _column_velocities(S, w, vel, angvel, u, y):
    """u = J_c P v (k,) of world w: the column velocities after the joint
    solve's projection P v = Z M v = v - M⁻¹J_tᵀK⁻¹J_t v, one tree solve.
    vel, angvel: the world's (N, 3); y (n, 6): scratch."""
    lo, hi = 3 * S.pt_start[w], 3 * S.pt_start[w + 1]
    tb = S.tree_bodies
    M = S.M[w]
    f = S.factors[w]
    _zero_rows(y)
    for q in range(tb.size):
        b = tb[q]
        v = (vel[b, 0], vel[b, 1], vel[b, 2], angvel[b, 0], angvel[b, 1], angvel[b, 2])
        for r in range(6):
            acc = 0.0
            for x in range(6):
                acc += M[q, r, x] * v[x]
            y[q, r] = acc
    solve_nodes(S.order, S.parent, S.Dinv[f], S.L[f], y)
    for c in range(lo, hi):
        q = S.node[S.body[c]]
        acc = 0.0
        for x in range(6):
            acc += S.J[c, x] * y[q, x]
        u[c - lo] = acc


@kernel
def _apply_world(S, w, dlam, vel, angvel, y):
    """v += Z J_cᵀ Δλ on the tree bodies of world w, one tree solve; dlam
    (k,); y (n, 6): scratch."""
    lo, hi = 3 * S.pt_start[w], 3 * S.pt_start[w + 1]
    if hi == lo:
        return
    tb = S.tree_bodies
    f = S.factors[w]
    _zero_rows(y)
    for c in range(lo, hi):
        q = S.node[S.body[c]]
        g = dlam[c - lo]
        for x in range(6):
            y[q, x] += S.J[c, x] * g
    solve_nodes(S.order, S.parent, S.Dinv[f], S.L[f], y)
    for q in range(tb.size):
        b = tb[q]
        for x in range(3):
            vel[b, x] += y[q, x]
            angvel[b, x] += y[q, 3 + x]


@kernel
def _gather(R, S, w, lam):
    """The world's points' accumulated impulses (normal, t1, t2) as columns (k,)."""
    p0, p1 = S.pt_start[w], S.pt_start[w + 1]
    for p in range(p0, p1):
        r, s = S.pt_row[p], S.pt_slot[p]
        i = 3 * (p - p0)
        lam[i] = R.lam_n[r, s]
        lam[i + 1] = R.lam_t1[r, s]
        lam[i + 2] = R.lam_t2[r, s]


@kernel
def _scatter(R, S, w, lam):
    """Impulses (k,) back to the world's rows (0 in their invalid slots), and
    each slot's largest normal impulse of the step."""
    for q in range(S.row_start[w], S.row_start[w + 1]):
        r = S.rows[q]
        for s in range(4):
            R.lam_n[r, s] = 0.0
            R.lam_t1[r, s] = 0.0
            R.lam_t2[r, s] = 0.0
    p0, p1 = S.pt_start[w], S.pt_start[w + 1]
    for p in range(p0, p1):
        r, s = S.pt_row[p], S.pt_slot[p]
        i = 3 * (p - p0)
        R.lam_n[r, s] = lam[i]
        R.lam_t1[r, s] = lam[i + 1]
        R.lam_t2[r, s] = lam[i + 2]
    for q in range(S.row_start[w], S.row_start[w + 1]):
        r = S.rows[q]
        for s in range(4):
            R.max_lam_n[r, s] = _maximum(R.max_lam_n[r, s], R.lam_n[r, s])


# ------------------------------------------------------------------ warm start (one world)
@kernel
def _warm_start_world(R, S, w, vel, angvel, fw):
    """v += Z J_cᵀ λ of the stored impulses, if any is non-zero; fw: the
    work buffer of ``solve_work``."""
    k = 3 * (S.pt_start[w + 1] - S.pt_start[w])
    lam = fw[0:k]
    y = fw[k:k + 6 * S.order.size].reshape((S.order.size, 6))
    _gather(R, S, w, lam)
    for i in range(k):
        if lam[i] != 0.0:
            _apply_world(S, w, lam, vel, angvel, y)
            return


@parallel_kernel
def warm_start(R, S, vel, angvel):
    """``_warm_start_world`` of every held world; vel, angvel (W, N, 3)."""
    H = S.held.size
    if H < SERIAL_BELOW:
        fw, bw = solve_work(S, 0, S.pt_start.size - 1)
        for q in range(H):
            w = S.held[q]
            _warm_start_world(R, S, w, vel[w], angvel[w], fw)
    else:
        for q in prange(H):
            fw, bw = solve_work(S, S.held[q], S.held[q] + 1)
            _warm_start_world(R, S, S.held[q], vel[S.held[q]], angvel[S.held[q]], fw)


# ------------------------------------------------------------------ solve (one world)
@kernel
def _sweep(S, w, u, lam, sweep_start, gain, bias, isc, soft, u_before):
    """One projected Gauss-Seidel sweep of world w: the normal columns, then
    the friction pairs, updating the column velocities u and impulses lam
    (k,) in place; u_before (points,): each normal column's velocity at its
    update. Normal: λ = max(λ₀ + gain (u + bias) - isc λ₀, 0) (the last term
    with ``soft``), λ₀ the sweep's start; friction: λ_t - m_t u_t into the
    disc |λ_t| <= μ λ_n. u holds no -0.0, so while A is finite adding an
    exact zero change leaves it as it is: a column whose impulse did not
    change is skipped (inf · 0 is NaN, which must reach u)."""
    p0, p1 = S.pt_start[w], S.pt_start[w + 1]
    n = p1 - p0
    k = 3 * n
    lo = 3 * p0
    a0 = S.a_start[w]
    skip = S.finite[w]
    A, m = S.A, S.m
    for p in range(n):
        i = 3 * p
        ui = u[i]
        u_before[p] = ui
        d = gain[p] * (ui + bias[p])
        if soft:
            d = d - isc[p] * sweep_start[i]
        new = _maximum(sweep_start[i] + d, 0.0)
        change = new - sweep_start[i]
        if not skip or change != 0.0:
            base = a0 + i * k
            for r in range(k):
                u[r] += A[base + r] * change
        lam[i] = new
    for p in range(n):
        i, j, l = 3 * p, 3 * p + 1, 3 * p + 2
        t1 = lam[j] - m[lo + j] * u[j]
        t2 = lam[l] - m[lo + l] * u[l]
        limit = S.mu[p0 + p] * lam[i]
        mag = math.sqrt(t1 * t1 + t2 * t2)
        scale = limit / max(mag, 1e-30) if mag > limit else 1.0
        t1, t2 = t1 * scale, t2 * scale
        c1, c2 = t1 - lam[j], t2 - lam[l]
        if not skip or c1 != 0.0 or c2 != 0.0:
            bj, bl = a0 + j * k, a0 + l * k
            for r in range(k):
                u[r] += A[bj + r] * c1 + A[bl + r] * c2
        lam[j], lam[l] = t1, t2


@kernel
def _solve_world(R, S, w, pos, ori, vel, angvel, prm, use_bias, fw, bw):
    """``SoftParams.sweeps`` sweeps of world w (``_sweep``), each point's
    closing speed and gap recorded just before it first takes load (for
    restitution), then v += Z J_cᵀ Δλ and the impulses back to the rows. The
    normal columns' bias and gain: an open point (s > 0) is speculative
    (bias s/h, gain -m); a penetrating one soft in the biased solve (bias
    rate·min(s + slop, 0) capped at -max_push_out, gain -m·mass_scale,
    impulse scale) and rigid without bias otherwise. fw, bw: the work
    buffers of ``solve_work``."""
    p0, p1 = S.pt_start[w], S.pt_start[w + 1]
    n = p1 - p0
    k = 3 * n
    lo = 3 * p0
    h = prm.h
    soft = use_bias and not prm.thesis
    sep, bias, gain, isc = fw[0:n], fw[n:2 * n], fw[2 * n:3 * n], fw[3 * n:4 * n]
    v_close, s_close, u_before = fw[4 * n:5 * n], fw[5 * n:6 * n], fw[6 * n:7 * n]
    c = 7 * n  # then the columns' u, lam, start, sweep_start (k each), then y (n nodes, 6)
    u, lam, start, sweep_start = fw[c:c + k], fw[c + k:c + 2 * k], fw[c + 2 * k:c + 3 * k], fw[c + 3 * k:c + 4 * k]
    y = fw[c + 4 * k:c + 4 * k + 6 * S.order.size].reshape((S.order.size, 6))
    loaded = bw[0:n]
    for p in range(n):
        isc[p] = 0.0
    for p in range(n):
        r, s = S.pt_row[p0 + p], S.pt_slot[p0 + p]
        x = separation(R, r, s, pos, ori)
        sep[p] = x
        mi = S.m[lo + 3 * p]
        if soft:
            if x > 0.0:
                bias[p], gain[p] = x / h, -mi * 1.0
            else:
                bias[p] = _maximum(prm.bias_rate * _minimum(x + prm.slop, 0.0), -prm.max_push_out)
                gain[p] = -mi * prm.mass_scale
                isc[p] = prm.impulse_scale
        else:
            bias[p] = x / h if x > 0.0 else 0.0
            gain[p] = -mi
    _column_velocities(S, w, vel, angvel, u, y)
    for i in range(k):
        u[i] = u[i] + 0.0  # no -0.0 entries (see _sweep)
    _gather(R, S, w, lam)
    for i in range(k):
        start[i] = lam[i]
    for p in range(n):
        r, s = S.pt_row[p0 + p], S.pt_slot[p0 + p]
        loaded[p] = R.max_lam_n[r, s] > 0.0
        v_close[p] = R.vn_close[r, s]
        s_close[p] = R.s_close[r, s]
    for _ in range(prm.sweeps):
        for i in range(k):
            sweep_start[i] = lam[i]
        _sweep(S, w, u, lam, sweep_start, gain, bias, isc, soft, u_before)
        for p in range(n):
            if not loaded[p] and lam[3 * p] > 0.0:
                v_close[p] = u_before[p]
                s_close[p] = sep[p]
                loaded[p] = True
    for p in range(n):
        r, s = S.pt_row[p0 + p], S.pt_slot[p0 + p]
        R.vn_close[r, s] = v_close[p]
        R.s_close[r, s] = s_close[p]
    for i in range(k):
        start[i] = lam[i] - start[i]
    _apply_world(S, w, start, vel, angvel, y)
    _scatter(R, S, w, lam)


@parallel_kernel
def solve(R, S, pos, ori, vel, angvel, prm, use_bias):
    """``_solve_world`` of every held world; pos, ori, vel, angvel (W, N, ...)."""
    H = S.held.size
    if H < SERIAL_BELOW:
        fw, bw = solve_work(S, 0, S.pt_start.size - 1)
        for q in range(H):
            w = S.held[q]
            _solve_world(R, S, w, pos[w], ori[w], vel[w], angvel[w], prm, use_bias, fw, bw)
    else:
        for q in prange(H):
            fw, bw = solve_work(S, S.held[q], S.held[q] + 1)
            _solve_world(R, S, S.held[q], pos[S.held[q]], ori[S.held[q]], vel[S.held[q]], angvel[S.held[q]], prm,
                         use_bias, fw, bw)


# ------------------------------------------------------------------ restitution (one world)
@allocating_kernel
def _bounce_world(R, S, w, vel, angvel, bounce, target):
    """The points of world w marked in ``bounce`` (rows, 4): their normal
    impulses grow (λ_n >= 0) until each one's separating speed is its
    ``target`` (m/s), in one sweep over the normal columns with the coupling
    A, then v += Z J_cᵀ Δλ. A world without a marked point is left as it is."""
    p0, p1 = S.pt_start[w], S.pt_start[w + 1]
    n = p1 - p0
    k = 3 * n
    lo = 3 * p0
    a0 = S.a_start[w]
    on = False
    for p in range(p0, p1):
        if bounce[S.pt_row[p], S.pt_slot[p]]:
            on = True
    if not on:
        return
    u = np.empty(k)
    y = np.empty((S.order.size, 6))
    _column_velocities(S, w, vel, angvel, u, y)
    lam = np.empty(k)
    _gather(R, S, w, lam)
    start = lam.copy()
    for p in range(n):
        r, s = S.pt_row[p0 + p], S.pt_slot[p0 + p]
        if not bounce[r, s]:
            continue
        i = 3 * p
        new = _maximum(lam[i] - S.m[lo + i] * (u[i] - target[r, s]), 0.0)
        change = new - lam[i]
        base = a0 + i * k
        for x in range(k):
            u[x] += S.A[base + x] * change
        lam[i] = new
    for i in range(k):
        start[i] = lam[i] - start[i]
    _apply_world(S, w, start, vel, angvel, y)
    _scatter(R, S, w, lam)


@parallel_kernel
def bounce(R, S, vel, angvel, marked, target):
    """``_bounce_world`` of every held world; marked, target (rows, 4)."""
    H = S.held.size
    if H < SERIAL_BELOW:
        for q in range(H):
            w = S.held[q]
            _bounce_world(R, S, w, vel[w], angvel[w], marked, target)
    else:
        for q in prange(H):
            _bounce_world(R, S, S.held[q], vel[S.held[q]], angvel[S.held[q]], marked, target)


@parallel_kernel
def column_velocities(S, vel, angvel, u):
    """u (C,) = J_c P v of every held world's columns (``_column_velocities``)."""
    H = S.held.size
    if H < SERIAL_BELOW:
        for q in range(H):
            w = S.held[q]
            _column_velocities(S, w, vel[w], angvel[w], u[3 * S.pt_start[w]:3 * S.pt_start[w + 1]],
                               np.empty((S.order.size, 6)))
    else:
        for q in prange(H):
            _column_velocities(S, S.held[q], vel[S.held[q]], angvel[S.held[q]],
                               u[3 * S.pt_start[S.held[q]]:3 * S.pt_start[S.held[q] + 1]], np.empty((S.order.size, 6)))
