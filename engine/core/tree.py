"""The joint tree's block LDLᵀ factorisation and substitution: kernels for one
world and their batched entry points (Baraff 1996, "Linear-time dynamics
using Lagrange multipliers").

The equality rows of an articulation's joints, J (6 rows a joint: 3 point
rows, 3 angular lock rows, the unused ones masked) and the bodies' metric M
(6x6 a body: mass, world inertia) give the system

    [M  Jᵀ] [y]   [0]
    [J  0 ] [z] = [r],      z = -(J M⁻¹ Jᵀ)⁻¹ r.

Its nodes, bodies and joints, form a tree (body - joint - body ...), and a
block of the matrix is non-zero only on the diagonal and between a joint and
the bodies it joins. Eliminating the nodes leaves first (each node after all
its children) leaves every block's sparsity as it is, no fill-in, so the
factorisation and the solve take time linear in the number of bodies:

* a body node b's pivot is D_b = M_b - Σ_children J_pᵀ D_j⁻¹ J_p, where J_p
  is the block of each child joint j on b (b is j's tree parent); a joint
  node j's pivot is D_j = diag(mask - 1) - J_c D_c⁻¹ J_cᵀ, J_c the block of j
  on its one child body c (the -1 of an unused row makes it solve to 0, as it
  has no coupling);
* each non-root node stores D⁻¹ and L = D⁻¹ H, H its off-diagonal block to its
  tree parent: a body L_b = D_b⁻¹ J_cᵀ (body velocities x joint rows), a
  joint L_j = D_j⁻¹ J_p (joint rows x body velocities);
* the forward substitution takes the nodes leaves first, y_node = rhs_node
  - Σ_children L_childᵀ y_child (rhs: 0 on bodies, r on joints), the back
  substitution roots first, x_node = D⁻¹ y_node - L x_parent; on the
  joints these are z, and the kernels return -z = (J M⁻¹ Jᵀ)⁻¹ r.

Closed forms: a leaf body's pivot is M_b itself, so its inverse is the given
M⁻¹ block when known; a ball joint's angular rows are empty, so its pivot is
blockdiag(D[:3, :3], -I) and its inverse one 3x3 symmetric inverse by the
adjugate. Other pivots are inverted by Gauss-Jordan elimination with partial
pivoting; a singular one (a world already diverging) gives NaN, so that world
turns non-finite and is reported after the step instead of raising.

Nodes are numbered bodies first (0..nb-1, the tree bodies in order), then
joints (nb..n-1, the tree joints in order); arrays over nodes are (n, 6, 6),
over joints (nj, ...). Each batched entry point runs the world kernel once
per world (a ``prange`` loop from ``SERIAL_BELOW`` worlds), so a world's
factors and solutions never depend on the batch.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .jit import SERIAL_BELOW, allocating_kernel, kernel, parallel_kernel, prange
from .vec import sym3_inverse


class TreeLayout(NamedTuple):
    """The static joint tree (n nodes: nb bodies, then nj joints)."""

    order: np.ndarray  # (n,) int64: the nodes leaves first (each after all its children)
    parent: np.ndarray  # (n,) int64: each node's tree parent node, -1 for a root
    n_bodies: int  # nb
    leaf: np.ndarray  # (nb,) bool: body nodes without a child joint (pivot M_b)
    ball: np.ndarray  # (nj,) bool: ball joints (no angular rows: the closed-form pivot)
    child_is_b: np.ndarray  # (nj,) bool: the joint's side b is its tree child body (else side a)
    joint_child: np.ndarray  # (nj,) int64: the body node of each joint's tree child


# ------------------------------------------------------------ small dense blocks
@kernel
def inverse6_into(a, ia, out, o):
    """out[o] = a[ia]⁻¹ of a 6x6 matrix by Gauss-Jordan elimination with
    partial pivoting (the row with the largest |entry| of the column as
    pivot); a[ia] is overwritten. A zero pivot (singular in floating
    point) fills out with NaN; NaN entries propagate."""
    for i in range(6):
        for j in range(6):
            out[o, i, j] = 0.0
        out[o, i, i] = 1.0
    for c in range(6):
        p = c
        big = abs(a[ia, c, c])
        for r in range(c + 1, 6):
            v = abs(a[ia, r, c])
            if v > big:
                big = v
                p = r
        if big == 0.0:
            for i in range(6):
                for j in range(6):
                    out[o, i, j] = np.nan
            return
        if p != c:
            for j in range(6):
                t = a[ia, c, j]
                a[ia, c, j] = a[ia, p, j]
                a[ia, p, j] = t
                t = out[o, c, j]
                out[o, c, j] = out[o, p, j]
                out[o, p, j] = t
        piv = a[ia, c, c]
        for j in range(c + 1, 6):
            a[ia, c, j] = a[ia, c, j] / piv
        for j in range(6):
            out[o, c, j] = out[o, c, j] / piv
        a[ia, c, c] = 1.0
        for r in range(6):
            if r == c:
                continue
            f = a[ia, r, c]
            if f != 0.0:
                for j in range(c + 1, 6):
                    a[ia, r, j] -= f * a[ia, c, j]
                for j in range(6):
                    out[o, r, j] -= f * out[o, c, j]
            a[ia, r, c] = 0.0


@kernel
def sym3_inverse_into(a, ia, out, o):
    """out[o, :3, :3] = a[ia, :3, :3]⁻¹ of a symmetric matrix by the
    adjugate, reading its upper triangle (0 if singular), the cofactors and
    determinant summed as :func:`engine.math3d.sym3_inverse` sums them."""
    i00, i01, i02, i11, i12, i22 = sym3_inverse(a[ia, 0, 0], a[ia, 0, 1], a[ia, 0, 2], a[ia, 1, 1], a[ia, 1, 2],
                                                a[ia, 2, 2])
    out[o, 0, 0], out[o, 0, 1], out[o, 0, 2] = i00, i01, i02
    out[o, 1, 0], out[o, 1, 1], out[o, 1, 2] = i01, i11, i12
    out[o, 2, 0], out[o, 2, 1], out[o, 2, 2] = i02, i12, i22


@kernel
def mul_ab_into(A, ia, B, ib, out, o):
    """out[o] = A[ia] B[ib] of 6x6 blocks, each entry summed over i = 0..5 in
    order (the loop over a row's entries innermost, independent of each
    other)."""
    for r in range(6):
        for c in range(6):
            out[o, r, c] = 0.0
        for i in range(6):
            a = A[ia, r, i]
            for c in range(6):
                out[o, r, c] += a * B[ib, i, c]


@kernel
def mul_atb_into(A, ia, B, ib, out, o):
    """out[o] = A[ia]ᵀ B[ib] of 6x6 blocks, summed as ``mul_ab_into``."""
    for r in range(6):
        for c in range(6):
            out[o, r, c] = 0.0
        for i in range(6):
            a = A[ia, i, r]
            for c in range(6):
                out[o, r, c] += a * B[ib, i, c]


@kernel
def mul_abt_into(A, ia, B, ib, out, o):
    """out[o] = A[ia] B[ib]ᵀ of 6x6 blocks, each entry a dot product of two
    rows summed in order."""
    for r in range(6):
        for c in range(6):
            s = 0.0
            for i in range(6):
                s += A[ia, r, i] * B[ib, c, i]
            out[o, r, c] = s


# ------------------------------------------------------------ one world
@allocating_kernel
def factor_scratch(n):
    """The scratch (acc (n, 6, 6), work (1, 6, 6)) of ``factor`` over n
    nodes, allocated once by a caller that factors many times."""
    return np.empty((n, 6, 6)), np.empty((1, 6, 6))


@kernel
def factor(layout, Ja, Jb, mask, M, M_inv, use_leaf_inv, ball_rows, Dinv, L, acc, work):
    """Block LDLᵀ factors of [M Jᵀ; J 0] of one world into Dinv and L (n, 6, 6).

    Ja, Jb (nj, 6, 6): each joint's rows on its sides a and b; mask (nj, 6):
    1 on a used row, 0 on an unused one; M (nb, 6, 6): the bodies' metric
    (kg, kg·m²) and, with ``use_leaf_inv``, M_inv its inverse (the leaf
    bodies' pivots); ``ball_rows``: the ball joints' angular rows are empty,
    so their pivots take the closed form. L of a root is 0. acc (n, 6, 6)
    and work (1, 6, 6): the caller's scratch (see ``factor_scratch``)."""
    nb = layout.n_bodies
    n = layout.order.size
    # acc: Σ_children J_pᵀ D_j⁻¹ J_p of a body node, J_c D_c⁻¹ J_cᵀ of a joint node.
    for k in range(n):
        for r in range(6):
            for c in range(6):
                acc[k, r, c] = 0.0
    for k in range(n):
        node = layout.order[k]
        p = layout.parent[node]
        if node < nb:
            if use_leaf_inv and layout.leaf[node]:
                for r in range(6):
                    for c in range(6):
                        Dinv[node, r, c] = M_inv[node, r, c]
            else:
                for r in range(6):
                    for c in range(6):
                        work[0, r, c] = M[node, r, c] - acc[node, r, c]
                inverse6_into(work, 0, Dinv, node)
            if p < 0:
                for r in range(6):
                    for c in range(6):
                        L[node, r, c] = 0.0
                continue
            j = p - nb
            # L_b = D_b⁻¹ J_cᵀ; the parent joint's J_c D_b⁻¹ J_cᵀ = J_c L_b.
            if layout.child_is_b[j]:
                mul_abt_into(Dinv, node, Jb, j, L, node)
                mul_ab_into(Jb, j, L, node, acc, p)
            else:
                mul_abt_into(Dinv, node, Ja, j, L, node)
                mul_ab_into(Ja, j, L, node, acc, p)
        else:
            j = node - nb
            if ball_rows and layout.ball[j]:
                # blockdiag(D[:3, :3], -I): the point rows' 3x3 block and -1 on the empty rows.
                for r in range(3):
                    for c in range(3):
                        work[0, r, c] = -acc[node, r, c]
                    work[0, r, r] += mask[j, r] - 1.0
                for r in range(6):
                    for c in range(6):
                        Dinv[node, r, c] = 0.0
                sym3_inverse_into(work, 0, Dinv, node)
                for r in range(3, 6):
                    Dinv[node, r, r] = -1.0
            else:
                for r in range(6):
                    for c in range(6):
                        work[0, r, c] = -acc[node, r, c]
                    work[0, r, r] += mask[j, r] - 1.0
                inverse6_into(work, 0, Dinv, node)
            if p < 0:
                for r in range(6):
                    for c in range(6):
                        L[node, r, c] = 0.0
                continue
            # L_j = D_j⁻¹ J_p; the parent body's pivot loses J_pᵀ D_j⁻¹ J_p = J_pᵀ L_j.
            if layout.child_is_b[j]:
                mul_ab_into(Dinv, node, Ja, j, L, node)
                mul_atb_into(Ja, j, L, node, work, 0)
            else:
                mul_ab_into(Dinv, node, Jb, j, L, node)
                mul_atb_into(Jb, j, L, node, work, 0)
            for r in range(6):
                for c in range(6):
                    acc[p, r, c] += work[0, r, c]


@allocating_kernel
def substitute(layout, Dinv, L, R, X):
    """X = (J M⁻¹ Jᵀ)⁻¹ R of one world, R and X (nj, 6, k), through the
    factors of ``factor``: each column one ``solve_nodes`` with its
    right-hand side on the joints, x = -z on the joints' rows."""
    nb = layout.n_bodies
    n = layout.order.size
    y = np.empty((n, 6))
    for c in range(R.shape[2]):
        for node in range(n):
            for s in range(6):
                y[node, s] = R[node - nb, s, c] if node >= nb else 0.0
        solve_nodes(layout.order, layout.parent, Dinv, L, y)
        for j in range(n - nb):
            for s in range(6):
                X[j, s, c] = -y[nb + j, s]


@kernel
def solve_nodes(order, parent, Dinv, L, y):
    """y (n, 6) = [M Jᵀ; J 0]⁻¹ y of one world in place, a right-hand side on
    every node (bodies: forces, N s; joints: rows), through the factors of
    ``factor`` (order, parent: the layout's): the forward substitution leaves
    first, the back substitution roots first. Bodies get the constrained
    velocities, joints -z. Each entry a 6-term sum in order."""
    n = order.size
    for q in range(n):
        node = order[q]
        p = parent[node]
        if p < 0:
            continue
        # y_parent -= L_nodeᵀ y_node (children in node order, as they come leaves first).
        for s in range(6):
            acc = 0.0
            for i in range(6):
                acc += L[node, i, s] * y[node, i]
            y[p, s] -= acc
    for q in range(n - 1, -1, -1):
        node = order[q]
        p = parent[node]
        # x_node = D⁻¹ y_node - L_node x_parent (the parent's x is in y
        # already); y_node is read from a copy, as x_node overwrites it.
        yn = (y[node, 0], y[node, 1], y[node, 2], y[node, 3], y[node, 4], y[node, 5])
        for s in range(6):
            acc = 0.0
            for i in range(6):
                acc += Dinv[node, s, i] * yn[i]
            if p >= 0:
                t = 0.0
                for i in range(6):
                    t += L[node, s, i] * y[p, i]
                acc -= t
            y[node, s] = acc


@kernel
def substitute_one(layout, Dinv, L, r, x, y):
    """x = (J M⁻¹ Jᵀ)⁻¹ r of one world for one right-hand side, r and x
    (nj, 6): ``substitute`` of a single column; y (n, 6): scratch."""
    nb = layout.n_bodies
    n = layout.order.size
    for i in range(nb):
        for s in range(6):
            y[i, s] = 0.0
    for j in range(n - nb):
        for s in range(6):
            y[nb + j, s] = r[j, s]
    solve_nodes(layout.order, layout.parent, Dinv, L, y)
    for j in range(n - nb):
        for s in range(6):
            x[j, s] = -y[nb + j, s]


@allocating_kernel
def walks(k, n):
    """Room for k walks of ``walk_up`` over a tree of n nodes: (path (k, n),
    length (k,), at (k, n), Y (k, n, 6), Z (k, n, 6))."""
    return (np.empty((k, n), dtype=np.int64), np.empty(k, dtype=np.int64), np.empty((k, n), dtype=np.int64),
            np.empty((k, n, 6)), np.empty((k, n, 6)))


@kernel
def walk_up(parent, Dinv, L, node, y, inject_at, inject, path, at, Y, Z, c):
    """The forward substitution F⁻¹ e of a right-hand side e, y (6,) on one
    node plus ``inject`` (6,) on the node ``inject_at`` (-1: none) of the
    path above it, for the factors of ``factor`` ([M Jᵀ; J 0] = F D Fᵀ, F
    unit block-triangular along the tree): non-zero only on the path from
    the node to its root, one child a node, so a walk up the path
    (y_parent = e_parent - L_nodeᵀ y_node). Walk c's: the path's nodes go to
    ``path[c]`` (n,), each node's place on it to ``at[c]`` (n,), which the
    walk first fills with -1, F⁻¹ e and D⁻¹ F⁻¹ e on it to Y[c] and Z[c]
    (n, 6); y is overwritten. Returns the path's length."""
    for i in range(at.shape[1]):
        at[c, i] = -1
    m = 0
    while True:
        if node == inject_at:
            for s in range(6):
                y[s] += inject[s]
        path[c, m] = node
        at[c, node] = m
        for s in range(6):
            Y[c, m, s] = y[s]
            acc = 0.0
            for i in range(6):
                acc += Dinv[node, s, i] * y[i]
            Z[c, m, s] = acc
        m += 1
        p = parent[node]
        if p < 0:
            return m
        # y_parent = -L_nodeᵀ y_node, reading y_node from its copy in Y.
        for s in range(6):
            acc = 0.0
            for i in range(6):
                acc += L[node, i, s] * Y[c, m - 1, i]
            y[s] = -acc
        node = p


@kernel
def path_product(path, length, Z, at, Y, c, r):
    """eᵣᵀ [M Jᵀ; J 0]⁻¹ e_c = (F⁻¹ e_r)ᵀ D⁻¹ (F⁻¹ e_c) (the inverse is
    F⁻ᵀ D⁻¹ F⁻¹) from the walks c and r of ``walk_up``: a sum over the
    nodes the two paths share, c's path bottom up."""
    acc = 0.0
    for m in range(length[c]):
        mr = at[r, path[c, m]]
        if mr >= 0:
            for s in range(6):
                acc += Y[r, mr, s] * Z[c, m, s]
    return acc


# ------------------------------------------------------------ batches
@parallel_kernel
def factor_batch(layout, Ja, Jb, mask, M, M_inv, use_leaf_inv, ball_rows, Dinv, L):
    """``factor`` of every world: Ja, Jb (W, nj, 6, 6), mask (W, nj, 6), M and
    M_inv (W, nb, 6, 6) into Dinv, L (W, n, 6, 6)."""
    nw = Ja.shape[0]
    n = layout.order.size
    if nw < SERIAL_BELOW:
        acc, work = factor_scratch(n)
        for w in range(nw):
            factor(layout, Ja[w], Jb[w], mask[w], M[w], M_inv[w], use_leaf_inv, ball_rows, Dinv[w], L[w], acc, work)
    else:
        for w in prange(nw):
            acc, work = factor_scratch(n)
            factor(layout, Ja[w], Jb[w], mask[w], M[w], M_inv[w], use_leaf_inv, ball_rows, Dinv[w], L[w], acc, work)


@parallel_kernel
def substitute_batch(layout, Dinv, L, R, X):
    """``substitute`` of every world: R, X (W, nj, 6, k)."""
    nw = R.shape[0]
    if nw < SERIAL_BELOW:
        for w in range(nw):
            substitute(layout, Dinv[w], L[w], R[w], X[w])
    else:
        for w in prange(nw):
            substitute(layout, Dinv[w], L[w], R[w], X[w])
