"""Direct tree solve of the joint equality rows (Baraff 1996, "Linear-time dynamics using Lagrange multipliers").

The bodies and joints of an articulation form a tree of nodes (body - joint -
body ...). The system  [M  Jᵀ; J  0] [y; z] = [0; r]  has that tree's sparsity,
so its block LDLᵀ factorisation in leaves-first order has no fill-in and gives
x = -z = (J M⁻¹ Jᵀ)⁻¹ r exactly in time linear in the number of bodies. Each
joint node has 6 rows: 3 point rows and 3 angular lock rows (hinge: y, z of the
parent frame; fixed: world x, y, z; ball: none); unused rows get -1 on the
diagonal and no coupling, so they solve to 0. The factorisation and the
substitution are numba kernels for one world (:mod:`engine.core.tree`), run
once per world over the static layout compiled here (``_TreeSolver.layout``):
the factors are arrays over all nodes, D⁻¹ and L (W, nodes, 6, 6).

``JointSet`` (:mod:`engine.joints`) builds a ``_TreeSolver`` for the equality
rows of its articulations and, with ``joint_loops="exact"``, the ``_Rows`` of
the loop-closing joints solved with it.
"""

from __future__ import annotations

import numpy as np

from .core import tree as tree_kernels
from .joints import BALL, FIXED, HINGE
from .math3d import (EX, EY, EZ, clamp_norm, cross, dot, inverse_or_nan, mat_vec, quat_conj, quat_mul, quat_rotate,
                     sym3_inverse, world_inv_inertia)
from .scatter import Scatter, scatter_add


# Entries of -[r]× = [[0, r_z, -r_y], [-r_z, 0, r_x], [r_y, -r_x, 0]] in the
# top-right block of a 6x6 joint Jacobian: (row, column, component of r, sign).
_SKEW_ROW = np.array([0, 0, 1, 1, 2, 2])
_SKEW_COL = np.array([4, 5, 3, 5, 3, 4])
_SKEW_COMP = np.array([2, 1, 2, 0, 1, 0])
_SKEW_SIGN = np.array([1.0, -1.0, -1.0, 1.0, 1.0, -1.0])
_DIAG3 = np.arange(3)
LOOP_SOLVE_BYTES = 256 * 2 ** 20  # most temporaries of one chunk of worlds in the loop solve
LOOP_REGULARISATION = 1e-6  # of the largest diagonal entry, added to the loop rows' Schur complement
ACTIVE_SET_TOLERANCE = 1e-6  # rad/s: a limit row closing faster than this after a solve joins the active set
#: Most limit rows in a tree for its active set on one factorisation (``_limits_schur``); with
#: more, B's columns cost more than factoring each pass. A chain of n limited ball joints (2n
#: rows), ms a step at W = 1 and 32, refactoring -> one factorisation: n = 12 16.2 -> 12.0 and
#: 47.8 -> 35.7; n = 24 24.5 -> 18.6 and 68.2 -> 68.9; n = 40 27.8 -> 27.4 and 96 -> 128.
SCHUR_LIMIT_ROWS = 48


def _mm(A, B):
    """A B for (..., n, k), (..., k, m)."""
    return np.matmul(A, B)


def _mtm(A, B):
    """Aᵀ B for (..., k, n), (..., k, m)."""
    return np.matmul(np.swapaxes(A, -1, -2), B)


def _in_limit_slots(on, lrows, lr, Ja, Jb, mask, r=None):
    """Copies of the tree rows' Jacobian blocks Ja, Jb (W, nj, 6, 6), mask
    (W, nj, 6) and, if given, right-hand side r with the limit rows ``lrows``
    (W, nj, 3, 3; values ``lr``) in their joints' free slots 3 (twist) and 4
    (swing) where ``on`` (W, nj, >= 2)."""
    Ja, Jb, mask = Ja.copy(), Jb.copy(), mask.copy()
    r = None if r is None else r.copy()
    for k in range(2):
        use = on[..., k]
        Jb[..., 3 + k, 3:] = np.where(use[..., None], lrows[..., k, :], Jb[..., 3 + k, 3:])
        Ja[..., 3 + k, 3:] = np.where(use[..., None], -lrows[..., k, :], Ja[..., 3 + k, 3:])
        mask[..., 3 + k] = np.where(use, 1.0, mask[..., 3 + k])
        if r is not None:
            r[..., 3 + k] = np.where(use, lr[..., k], r[..., 3 + k])
    return (Ja, Jb, mask) if r is None else (Ja, Jb, mask, r)


class _JointTree:
    """Static layout of the joint tree: nodes, their parents and the leaves-first order."""

    def __init__(self, parent, child, dynamic):
        J = len(parent)
        adj = {}
        self.joints = []  # joints solved by the tree
        # Union-find over dynamic bodies; a joint closing a loop is left out of the tree.
        root_of = {}

        def find(x):
            while root_of.get(x, x) != x:
                x = root_of[x]
            return x

        anchored = set()  # components attached to a static body
        for j in range(J):
            a, b = int(parent[j]), int(child[j])
            da, db = bool(dynamic[a]), bool(dynamic[b])
            if not (da or db):
                continue
            if da and db:
                ra, rb = find(a), find(b)
                if ra == rb:
                    continue
                if ra in anchored and rb in anchored:
                    continue  # would join two anchored trees: a loop through the world
                root_of[rb] = ra
                if rb in anchored:
                    anchored.discard(rb)
                    anchored.add(ra)
            else:
                r = find(a if da else b)
                if r in anchored:
                    continue
                anchored.add(r)
            self.joints.append(j)
            for x in (a, b):
                if dynamic[x]:
                    adj.setdefault(x, []).append(j)
        self.joints = np.array(self.joints, dtype=np.int64)
        # Articulation of each tree joint and body (-1 for bodies outside the tree).
        labels = {}
        self.component = np.array([labels.setdefault(find(int(child[j]) if dynamic[child[j]] else int(parent[j])), len(labels))
                                   for j in self.joints], dtype=np.int64)
        self.num_components = len(labels)
        self.body_component = np.full(len(dynamic), -1, dtype=np.int64)
        for x in adj:
            self.body_component[x] = labels[find(x)]
        bodies = sorted(adj)
        self.bodies = np.array(bodies, dtype=np.int64)
        nb = len(bodies)
        body_node = {b: i for i, b in enumerate(bodies)}
        joint_node = {int(j): nb + k for k, j in enumerate(self.joints)}
        n = nb + len(self.joints)
        node_parent = np.full(n, -1, dtype=np.int64)
        depth = np.full(n, -1, dtype=np.int64)
        # For joint nodes: whether the joint's parent body (side a) is the tree parent.
        self.a_is_parent = np.zeros(len(self.joints), dtype=bool)
        # Roots: the static-anchored joint of a component, else its lowest body.
        order = []
        roots = [joint_node[int(j)] for j in self.joints
                 if not (dynamic[parent[j]] and dynamic[child[j]])]
        for b in bodies:
            roots.append(body_node[b])
        for r in roots:
            if depth[r] >= 0:
                continue
            if r < nb and find(bodies[r]) in anchored:
                continue  # anchored component: rooted at its static joint
            depth[r] = 0
            stack = [r]
            while stack:
                u = stack.pop()
                order.append(u)
                if u < nb:
                    nbrs = [joint_node[j] for j in adj[bodies[u]]]
                else:
                    j = int(self.joints[u - nb])
                    nbrs = [body_node[int(x)] for x in (parent[j], child[j]) if dynamic[x]]
                for v in nbrs:
                    if depth[v] < 0:
                        depth[v] = depth[u] + 1
                        node_parent[v] = u
                        stack.append(v)
        assert (depth >= 0).all()
        for k, j in enumerate(self.joints):
            p = node_parent[nb + k]
            self.a_is_parent[k] = p >= 0 and bodies[p] == parent[j]
        self.n_nodes, self.n_bodies = n, nb
        self.node_parent = node_parent
        # Leaves first: deepest nodes first, each depth in node order, so every
        # node comes after all its children (which are one level deeper) and a
        # parent gathers its children's terms in node order.
        self.order = np.lexsort((np.arange(n), -depth)).astype(np.int64)
        self.body_pos = body_node


class _Rows:
    """The equality rows of a list of joints, 6 per joint: 3 point rows and 3
    angular lock rows (hinge: y, z of the parent frame; fixed: world x, y, z;
    ball: none), the unused ones masked."""

    def __init__(self, joints, kind, parent, child):
        self.joints, self.kind = joints, kind
        # Scatters of the rows' impulses onto their bodies.
        self.scatter_a = Scatter(parent)
        self.scatter_b = Scatter(child)
        # Angular lock rows used per kind (rows 3..5).
        self.ang_mask = np.zeros((len(joints), 3))
        self.ang_mask[kind == HINGE, 1:] = 1.0
        self.ang_mask[kind == FIXED] = 1.0
        self.eq_mask = np.concatenate((np.ones((len(joints), 3)), self.ang_mask), axis=1)  # rows stored as joint impulses
        self.hinges = np.flatnonzero(kind == HINGE)
        self.fixed = np.flatnonzero(kind == FIXED)
        self.used_rows = np.flatnonzero(self.eq_mask.reshape(-1))  # of the joints' 6 rows each, flattened

    def _position_errors(self, state, a, b, fpw, fcw, ra, rb):
        """The joints' position errors: anchor separation x_b + r_b - x_a - r_a (m)
        and the angular error vector (rad) whose lock-row components the rows
        hold at zero: hinge a_p × a_c of the two x axes, fixed 2 vec(q_c q_p*)."""
        lin = state.position.take(b, 1) + rb - state.position.take(a, 1) - ra
        ax_p = quat_rotate(fpw, EX)
        ax_c = quat_rotate(fcw, EX)
        herr = cross(ax_p, ax_c)
        qd = quat_mul(fcw, quat_conj(fpw))
        ferr = 2.0 * qd[..., 1:] * np.where(qd[..., 0:1] < 0, -1.0, 1.0)
        return lin, np.where((self.kind == HINGE)[:, None], herr, ferr)


class _TreeSolver(_Rows):
    """Per-substep factorisation and solve of the joint tree (see ``_JointTree``)."""

    def __init__(self, js, model, settings):
        t = _JointTree(js.parent, js.child, model.dynamic)
        self.t = t
        j = t.joints
        super().__init__(j, js.kind[j], js.parent[j], js.child[j])
        root = t.node_parent[t.n_bodies:] < 0
        dyn_b = model.dynamic[js.child[j]]
        self.child_is_b = np.where(root, dyn_b, t.a_is_parent)
        nb = t.n_bodies
        self.num_bodies = model.num_bodies
        has_child = np.zeros(t.n_nodes, dtype=bool)
        has_child[t.node_parent[t.node_parent >= 0]] = True
        # The static tree for the factorisation kernels (engine.core.tree).
        self.layout = tree_kernels.TreeLayout(
            order=t.order, parent=t.node_parent.astype(np.int64), n_bodies=int(nb),
            leaf=np.ascontiguousarray(~has_child[:nb]), ball=np.ascontiguousarray(self.kind == BALL),
            child_is_b=np.ascontiguousarray(self.child_is_b, dtype=bool))
        self.limits = False
        self.exact_loop = None  # (articulations + 1,) bool: closed by loops solved with the tree (JointSet)
        self.active_set_passes = settings.joint_active_set_passes
        self.component, self.num_components, self.body_component = t.component, t.num_components, t.body_component
        self.geometric_weight = None  # per step: 1, or (W, tree joints) weights, or None
        self.loop_geometric_weight = None  # the same for the loop-closing rows solved with the tree
        self._factored = None  # (state, blocks, factors) of the current positions and metric (see solve)
        # Per tree joint, for limit_rows: the twist bounds with infinite ones as
        # 0 (rad), which bounds are finite, the ball joints (as a column) and
        # which limit rows exist (twist, swing, none) while the joint is whole.
        lo, hi = js.lower[j], js.upper[j]
        self.limit_exists = np.zeros((j.size, 3), dtype=bool)
        self.limit_exists[:, 0] = js.has_limit[j] & (self.kind != FIXED)
        self.limit_exists[:, 1] = js.has_swing[j]
        self._limit_constants = (np.where(np.isfinite(lo), lo, 0.0), np.where(np.isfinite(hi), hi, 0.0),
                                 np.isfinite(lo), np.isfinite(hi), (self.kind == BALL)[:, None], self.limit_exists)

    def begin_step(self, js, model, state, h):
        """The bodies' metric M (W, tree bodies, 6, 6) at the state's
        orientations: mass, world inertia and, with geometric stiffness, its
        added inertia. Factors of earlier positions are dropped."""
        self._factored = None
        t = self.t
        b = t.bodies
        W = state.orientation.shape[0]
        M = np.zeros((W, t.n_bodies, 6, 6))
        m = model.mass[b]
        for k in range(3):
            M[..., k, k] = m
        I = world_inv_inertia(None, model.inertia[b], js._rot[:, b])
        self.iinv = js._iinv
        if self.geometric_weight is not None:
            # Geometric stiffness (Andrews, Teichmann & Kry 2017; Tournier et al.
            # 2015): a joint carrying force f at lever arm r resists turning the
            # body with stiffness ~ |f| (|r|² I - r rᵀ)/|r|; its implicit-Euler
            # share h² K is added to the body's inertia in the joint solve, which
            # keeps light links between heavy loads from the explicit
            # instability of the constraint-force direction.
            # Loop-closing joints solved with the tree carry load too: without
            # theirs, a 20 kg ball on a chain pinned at both ends gained 12 J in
            # 3 s (benchmarks.stability chain_loop).
            G = np.zeros((W, model.num_bodies, 3, 3))
            parts = [(self.joints, self.geometric_weight)]
            if js.loop_rows is not None and self.loop_geometric_weight is not None:
                parts.append((js.loop_rows.joints, self.loop_geometric_weight))
            for idx, weight in parts:
                _, _, _, _, ra, rb = js.frames(state, idx)
                lam = state.joint_linear_impulse[:, idx]
                f = np.sqrt(dot(lam, lam))
                if js._load_before is not None:
                    # Within a step: the smaller of the loads before and after this
                    # substep's biased solve (see JointSet.positions_moved).
                    f = np.minimum(f, js._load_before[:, idx])
                f = f * h * weight  # h² |F| = h |λ|
                for body, r in ((js.parent[idx], ra), (js.child[idx], rb)):
                    rn = np.sqrt(dot(r, r))
                    g = f / np.maximum(rn, 1e-12)
                    K = -r[..., :, None] * r[..., None, :]
                    for k in range(3):
                        K[..., k, k] += rn * rn
                    np.add.at(G, (slice(None), body), g[..., None, None] * K)
            # Capped at a few times the body's own inertia: the stiffness grows with
            # the load, and the load needed to turn a heavier body grows with it.
            G = G[:, b]
            trI = I[..., 0, 0] + I[..., 1, 1] + I[..., 2, 2]
            trG = G[..., 0, 0] + G[..., 1, 1] + G[..., 2, 2]
            cap = js.settings.joint_geometric_stiffness_cap * trI
            scale = np.where(trG > cap, cap / np.where(trG > cap, trG, 1.0), 1.0)
            I = I + G * scale[..., None, None]
            inv = js._iinv.copy()
            # Bodies without added stiffness keep their inverse as computed (bit
            # for bit, so a world reads the same stepped alone or in a batch).
            inv[:, b] = np.where((trG > 0)[..., None, None], sym3_inverse(I), inv[:, b])
            # Every joint row (warm start, limits, tree) uses the same metric.
            js._iinv = self.iinv = inv
        M[..., 3:, 3:] = I
        self.M = M
        # Its inverse, blockdiag(I/m, I_w⁻¹): the pivots of leaf bodies.
        M_inv = np.zeros(M.shape)
        M_inv[..., _DIAG3, _DIAG3] = model.inv_mass[b][:, None]
        M_inv[..., 3:, 3:] = self.iinv[:, b]
        self.M_inv = M_inv

    def jacobians(self, js, state, use_bias, bias_rate, velocity=True, max_push_out=None,
                  max_angular_push_out=None, rows=None):
        """Jacobian blocks (W, nj, 6, 6) of each tree joint (or of the joints
        of ``rows``, a ``_Rows``) wrt its sides a and b, the row mask and the
        right-hand side J·u + bias·C (without ``velocity``: bias·C alone); the
        bias is clamped to the joint push-out speeds unless other limits are
        given."""
        blocks = self.blocks(js, state, self if rows is None else rows)
        return self.right_hand_side(js, state, blocks, self if rows is None else rows, use_bias, bias_rate,
                                    velocity, max_push_out, max_angular_push_out)

    def blocks(self, js, state, rows):
        """The part of ``jacobians`` that depends on the positions alone:
        sides a, b, the joint frames and lever arms, the lock-row axes E
        (W, nj, 3, 3), the Jacobian blocks Ja, Jb (W, nj, 6, 6) and the row
        mask (W, nj, 6)."""
        idx = rows.joints
        a, b, fpw, fcw, ra, rb = js.frames(state, idx)
        shape = ra.shape
        W, nj = shape[0], shape[1]
        act = js._active(state, idx)
        mask = np.empty((W, nj, 6))
        mask[..., :3] = act[..., None]
        mask[..., 3:] = act[..., None] * rows.ang_mask
        # Angular lock rows: hinge (0, y, z) of the parent frame, fixed I, ball none.
        E = np.zeros((W, nj, 3, 3))
        if rows.hinges.size:
            fh = fpw.take(rows.hinges, 1)
            E[:, rows.hinges, 1] = quat_rotate(fh, EY)
            E[:, rows.hinges, 2] = quat_rotate(fh, EZ)
        E[:, rows.fixed] = np.eye(3)
        # Side b: [[I, -[r_b]×], [0, E]]; side a: -[[I, -[r_a]×], [0, E]]; rows masked.
        J = np.zeros((2, W, nj, 6, 6))
        J[..., _DIAG3, _DIAG3] = 1.0
        J[..., _SKEW_ROW, _SKEW_COL] = np.stack((rb, ra))[..., _SKEW_COMP] * _SKEW_SIGN
        J[..., 3:, 3:] = E
        J *= mask[..., None]
        Jb, Ja = J[0], np.negative(J[1], out=J[1])
        return a, b, fpw, fcw, ra, rb, E, Ja, Jb, mask

    def right_hand_side(self, js, state, blocks, rows, use_bias, bias_rate, velocity=True, max_push_out=None,
                        max_angular_push_out=None):
        """``jacobians`` from the ``blocks`` of the current positions: (a, b,
        Ja, Jb, mask, r) with r = J·u + bias·C (W, nj, 6)."""
        if max_push_out is None:
            max_push_out = js.settings.joint_max_push_out
        if max_angular_push_out is None:
            max_angular_push_out = js.settings.joint_max_angular_push_out
        a, b, fpw, fcw, ra, rb, E, Ja, Jb, mask = blocks
        r = np.empty(mask.shape)
        if velocity:
            va, vb = state.velocity.take(a, 1), state.velocity.take(b, 1)
            wa, wb = state.angular_velocity.take(a, 1), state.angular_velocity.take(b, 1)
            r[..., :3] = vb + cross(wb, rb) - va - cross(wa, ra)
            r[..., 3:] = mat_vec(E, wb - wa)
        else:
            r[...] = 0.0
        if use_bias and np.any(bias_rate):
            lin, ang = rows._position_errors(state, a, b, fpw, fcw, ra, rb)
            r[..., :3] += clamp_norm(bias_rate * lin, max_push_out)
            r[..., 3:] += mat_vec(E, clamp_norm(bias_rate * ang, max_angular_push_out))
        r *= mask
        return a, b, Ja, Jb, mask, r

    def limit_rows(self, js, state, h, use_bias):
        """Limit rows in the free angular slots of each tree joint: hinge slot 3
        (twist), ball slots 3 (twist) and 4 (swing). The accumulated limit impulse
        is taken off the velocities first, so the active-set solve finds the
        whole (rigid, one-sided) limit impulse afresh.
        Returns J rows (W, nj, 3, 3), rhs (W, nj, 3), sign σ (W, nj, 3) with
        σ·λ >= 0 required, and which rows exist (W, nj, 3)."""
        idx = self.joints
        a, b = js.parent[idx], js.child[idx]
        lo0, hi0, lo_finite, hi_finite, ball_col, exists_static = self._limit_constants
        lam = state.joint_limit_impulse[:, idx]
        Jt, twist, Js, Cs, twist_defined = js.limit_geometry(state, idx)
        # Remove the warm-started limit impulse.
        L = (lam[..., 0:1] - lam[..., 1:2]) * Jt + lam[..., 2:3] * Js
        scatter_add(state.angular_velocity, self.scatter_a, mat_vec(js._iinv[:, a], L))
        scatter_add(state.angular_velocity, self.scatter_b, -mat_vec(js._iinv[:, b], L))
        state.joint_limit_impulse[:, idx] = 0.0
        C_lo = np.where(lo_finite, twist - lo0, np.inf)
        C_hi = np.where(hi_finite, hi0 - twist, np.inf)
        # One twist row per joint: the bound the twist is heading for by the
        # substep's end (a light limb can cross the whole range in a substep).
        wrel = state.angular_velocity[:, b] - state.angular_velocity[:, a]
        ahead = h * dot(Jt, wrel)
        lower = C_lo + ahead <= C_hi - ahead
        W, nj = twist.shape
        rows = np.zeros((W, nj, 3, 3))
        rows[..., 0, :] = Jt
        rows[..., 1, :] = np.where(ball_col, Js, 0.0)
        exists = exists_static & ~state.joint_broken.take(idx, 1)[..., None]
        exists[..., 0] &= twist_defined
        sigma = np.ones((W, nj, 3))
        sigma[..., 0] = np.where(lower, 1.0, -1.0)
        C = np.zeros((W, nj, 3))
        C[..., 0] = np.where(exists[..., 0], np.minimum(C_lo, C_hi), 0.0)
        C[..., 1] = np.where(exists[..., 1], Cs, 0.0)
        r = mat_vec(rows, wrel)
        # Speculative while open (C/h), rigid position bias when violated in
        # the biased solve, none in the relax solve.
        bias = np.where(C > 0, C / h, np.maximum(C / h, -js.settings.joint_max_angular_push_out) if use_bias else 0.0)
        r = r + sigma * bias
        r = np.where(exists, r, 0.0)
        return rows, r, sigma, exists, lower

    def solve(self, js, model, state, bias_rate, mass_scale, impulse_scale, use_bias, h):
        if not self.limits:
            # Factored once per set of positions and metric: the relax solve of
            # one substep and the biased solve of the next see the same
            # positions (only velocities change between them), so the second
            # reuses the first's factors, the same numbers (5 factorisations a
            # step instead of 8 at 4 substeps). Factors of a solve before the
            # positions moved are never reused: the relax solve on the biased
            # solve's factors let a 100 kg ball on a light chain gain energy
            # (benchmarks.stability ball_and_chain_far).
            if self._factored is None or self._factored[0] is not state:
                blocks = self.blocks(js, state, self)
                self._factored = (state, blocks, self._factor(blocks[7], blocks[8], blocks[9]))
            _, blocks, factors = self._factored
            a, b, Ja, Jb, mask, r = self.right_hand_side(js, state, blocks, self, use_bias, bias_rate)
            x = self._substitute(factors, r)
            # The relax solve and rigid rows: no impulse term (its accumulated
            # impulses are not gathered).
            lam_term = 0.0 if np.ndim(impulse_scale) == 0 and impulse_scale == 0.0 else impulse_scale * self._lam(state)
            d = (-mass_scale * x - lam_term) * mask
            self._apply(js, model, state, a, b, Ja, Jb, d)
            return
        lrows, lr, sigma, exists, lower = self.limit_rows(js, state, h, use_bias)
        if self.limit_candidates[0].size <= SCHUR_LIMIT_ROWS:
            a, b, Ja, Jb, d, lim = self._limits_schur(js, state, lrows, lr, sigma, exists, bias_rate, mass_scale,
                                                      impulse_scale, use_bias)
        else:
            a, b, Ja, Jb, d, lim = self._limits_refactored(js, state, lrows, lr, sigma, exists, bias_rate,
                                                           mass_scale, impulse_scale, use_bias)
        self._apply(js, model, state, a, b, Ja, Jb, d)
        # Store: twist row impulse is λ_lo - λ_hi, swing row λ_swing.
        idx = self.joints
        tw = d[..., 3] * lim[..., 3]
        state.joint_limit_impulse[:, idx, 0] = np.where(lower, tw, 0.0)
        state.joint_limit_impulse[:, idx, 1] = np.where(lower, 0.0, -tw)
        state.joint_limit_impulse[:, idx, 2] = d[..., 4] * lim[..., 4]

    def _limits_schur(self, js, state, lrows, lr, sigma, exists, bias_rate, mass_scale, impulse_scale, use_bias):
        """The tree solve with the limit rows of ``limit_rows`` by their active
        set (``_active_set``), on one factorisation per set of positions.
        Returns a, b, Ja, Jb, the impulses d (W, nj, 6) and the limit-taken
        slots lim (W, nj, 6)."""
        # One factorisation: that of the system with every existing limit row
        # in its joint's free slot (positions alone, so the relax solve of one
        # substep and the biased solve of the next share it, as above), and
        # B = A⁻¹ on the limit rows (A = J M⁻¹ Jᵀ). Dropping the rows D (λ_D = 0,
        # their equations gone) is solving with their right-hand side moved by
        # δ_D, where B_DD δ_D = -(B r)_D: the other rows' equations hold as they
        # were. The same λ as factoring the active rows alone, to rounding (the
        # Schur complement update of active-set QP methods, Nocedal & Wright
        # 2006, ch. 16).
        if self._factored is None or self._factored[0] is not state:
            self._factored = (state, *self._limit_factors(js, state, lrows, exists))
        _, blocks, Ja, Jb, factors, B_cols, B_lim = self._factored
        a, b, _, _, mask, r = self.right_hand_side(js, state, blocks, self, use_bias, bias_rate)
        r[..., 3:5] = np.where(exists[..., :2], lr[..., :2], r[..., 3:5])
        x0 = self._substitute(factors, r)
        cj, cs = self.limit_candidates
        x0_lim = x0[:, cj, 3 + cs]  # (W, k)
        exists_c = exists[:, cj, cs]
        W, nj = mask.shape[:2]

        def solve_for(active):
            drop = exists_c & ~active[:, cj, cs]
            if not drop.any():
                return x0, Ja, Jb
            Bd = np.where(drop[:, :, None] & drop[:, None, :], B_lim, np.eye(cj.size))
            rhs = np.where(drop, -x0_lim, 0.0)[..., None]
            try:
                delta = np.linalg.solve(Bd, rhs)
            except np.linalg.LinAlgError:  # a singular B_DD (degenerate rows): least squares
                delta = np.matmul(np.linalg.pinv(Bd), rhs)
            # Worlds dropping nothing keep x0 as it is (their bits never depend on the others').
            x = np.where(drop.any(axis=-1)[:, None, None], x0 + np.matmul(B_cols, delta).reshape(W, nj, 6), x0)
            return x, Ja, Jb  # rows of dropped slots carry d = 0 (mask and lim are 0 there)

        return (a, b, *self._active_set(js, state, a, b, mask, lrows, lr, sigma, exists, mass_scale, impulse_scale,
                                        solve_for))

    def _limits_refactored(self, js, state, lrows, lr, sigma, exists, bias_rate, mass_scale, impulse_scale,
                           use_bias):
        """``_limits_schur`` for trees with many limit rows: the system of the
        active rows factored afresh in each pass (cheaper once B's columns
        cost more than the passes' factorisations: ``SCHUR_LIMIT_ROWS``)."""
        a, b, Ja, Jb, mask, r = self.jacobians(js, state, use_bias, bias_rate)

        def solve_for(active):
            Ja2, Jb2, m2, r2 = _in_limit_slots(active, lrows, lr, Ja, Jb, mask, r)
            return self._factor_solve(Ja2, Jb2, m2, r2, ball_rows=False), Ja2, Jb2

        return (a, b, *self._active_set(js, state, a, b, mask, lrows, lr, sigma, exists, mass_scale, impulse_scale,
                                        solve_for))

    def _active_set(self, js, state, a, b, mask, lrows, lr, sigma, exists, mass_scale, impulse_scale, solve_for):
        """Active set over the limit rows: start from the rows the current
        velocities would violate, drop rows that pull, add rows the solve's
        impulses would drive past their limit. ``solve_for(active)`` gives x
        = A⁻¹ r over the equality rows and the active limit rows, and the
        Jacobian blocks it used. Returns Ja, Jb, d, lim."""
        lam_eq = 0.0 if np.ndim(impulse_scale) == 0 and impulse_scale == 0.0 else impulse_scale * self._lam(state)
        active = exists & (sigma * lr < 0)
        for _ in range(self.active_set_passes):
            x, Ja, Jb = solve_for(active)
            lim = np.zeros(x.shape)
            lim[..., 3:5] = active[..., :2]  # rows taken by limits (free slots of the joint): rigid, whole λ
            d = (-mass_scale * x - lam_eq) * mask - x * lim
            bad = active[..., :2] & (sigma[..., :2] * -x[..., 3:5] < 0)  # limit impulses λ = -x that pull
            after = self._rows_after(js, state, a, b, Ja, Jb, d, lrows, lr)
            add = exists[..., :2] & ~active[..., :2] & (sigma[..., :2] * after[..., :2] < -ACTIVE_SET_TOLERANCE)
            if not (bad.any() or add.any()):
                break
            # Drop pulling rows first; add violated rows once none pulls.
            bad_joint = bad.any(axis=-1, keepdims=True)
            active[..., :2] = (active[..., :2] & ~bad) | (add & ~bad_joint)
        return Ja, Jb, d, lim

    def _limit_factors(self, js, state, lrows, exists):
        """For ``solve`` with limits: the position blocks, the Jacobian blocks
        Ja, Jb with every existing limit row (``limit_rows``) in its slot, the
        factors of that system, and B = A⁻¹ on the limit rows: its columns
        B_cols (W, 6 nj, k) and the limit rows' block B_lim (W, k, k), k the
        tree's possible limit rows (``limit_candidates``)."""
        blocks = self.blocks(js, state, self)
        Ja, Jb, mask = _in_limit_slots(exists, lrows, None, *blocks[7:10])
        factors = self._factor(Ja, Jb, mask, ball_rows=False)
        cj, cs = self.limit_candidates
        W, nj, k = mask.shape[0], mask.shape[1], cj.size
        R = np.zeros((W, nj, 6, k))
        R[:, cj, 3 + cs, np.arange(k)] = 1.0
        X = self._substitute_columns(factors, R)
        return blocks, Ja, Jb, factors, X.reshape(W, nj * 6, k), X[:, cj, 3 + cs]

    def _rows_after(self, js, state, a, b, Ja, Jb, d, lrows, lr):
        """Limit row values (lr is at the current velocities) after the
        impulses Jᵀd: lr + J_lim (Δω_b - Δω_a)."""
        dw = mat_vec(self.iinv, self._body_impulses(Ja, Jb, d)[..., 3:])
        return lr + mat_vec(lrows, dw[:, b] - dw[:, a])

    def _body_impulses(self, Ja, Jb, d, rows=None):
        """Jᵀ d summed per body: (W, num_bodies, 6) linear and angular impulses."""
        return self.body_columns(Ja, Jb, d[..., None], rows)[..., 0]

    def solve_with_loops(self, js, model, state, soft_tree, soft_loop, use_bias):
        """The tree rows and the loop-closing rows (``js.loop_rows``) solved
        together, exactly (``solve_coupled``), then softened row by row as the
        tree's alone: Δλ = -mass_scale x - impulse_scale λ."""
        (bias_t, ms_t, isc_t), (bias_l, ms_l, isc_l) = soft_tree, soft_loop
        rows = js.loop_rows
        tree_rows = self.jacobians(js, state, use_bias, bias_t)
        loop_rows = self.jacobians(js, state, use_bias, bias_l, rows=rows)
        a, b, Ja, Jb, mask, _ = tree_rows
        la, lb, La, Lb, lmask, _ = loop_rows
        inv_m = model.inv_mass

        def inv_mass_times(v, worlds):
            """M⁻¹ v for per-body (W, N, 6, k) blocks of the worlds ``worlds``."""
            out = np.empty(v.shape)
            out[..., :3, :] = v[..., :3, :] * inv_m[:, None, None]
            out[..., 3:, :] = np.matmul(self.iinv[worlds], v[..., 3:, :])
            return out

        x_t, x_l = self.solve_coupled(tree_rows, loop_rows, rows, inv_mass_times)
        self._apply(js, model, state, a, b, Ja, Jb, (-ms_t * x_t - isc_t * self._lam(state)) * mask)
        self._apply(js, model, state, la, lb, La, Lb, (-ms_l * x_l - isc_l * self._lam(state, rows)) * lmask, rows)

    def body_columns(self, JA, JB, x, rows=None):
        """Σ Jᵀ x per body, (W, N, 6, k), from row blocks x (W, n, 6, k) of the
        tree's joints (or of ``rows``)."""
        rows = self if rows is None else rows
        out = np.zeros((x.shape[0], self.num_bodies, 6, x.shape[-1]))
        scatter_add(out, rows.scatter_a, _mtm(JA, x))
        scatter_add(out, rows.scatter_b, _mtm(JB, x))
        return out

    def solve_coupled(self, tree_rows, loop_rows, rows, inv_metric_times, M=None, M_inv=None):
        """x = K⁻¹ r over the tree rows T and the loop rows L together, K = J W⁻¹ Jᵀ
        (W: the bodies' metric, the mass matrices or ``M`` with
        ``inv_metric_times(v)`` = W⁻¹ v on (W, N, 6, k) blocks; ``M_inv``:
        the inverse of ``M`` on the tree bodies, if known, for the leaf
        pivots). The tree factorisation gives X = K_TT⁻¹ K_TL column by column
        and y = K_TT⁻¹ r_T; the loop rows solve the dense Schur complement

            (K_LL - K_LT X) x_L = r_L - K_LT y,     x_T = y - X x_L

        (Baraff 1996, section 7: loops by the tree plus a small dense system).
        ``tree_rows``, ``loop_rows``: ``jacobians`` of each. One column per used
        loop row: a 10x10 grid of ball joints pinned at two corners has 82
        loops, 246 columns, and stepped at 74-83 ms against 31 ms with
        Gauss-Seidel loop rows. Returns x_T (W, nj, 6), x_L (W, nl, 6).

        Its temporaries hold bodies x loop rows per world (about 5 MB for that
        grid), so the worlds go through in chunks of at most
        ``LOOP_SOLVE_BYTES``; each world's arithmetic is its own either way.
        ``inv_metric_times(v, worlds)`` takes the chunk's world slice."""
        W, nl = loop_rows[5].shape[:2]
        # (W, n, 6, m) float64 blocks alive at once: G, V and a product per
        # body, at most six per tree joint for the substitution (its kernel
        # holds one per tree node and the result per tree joint), four per
        # loop joint: an over-estimate of the peak.
        per_world = 8 * 6 * rows.used_rows.size * (3 * self.num_bodies + 6 * tree_rows[5].shape[1] + 4 * nl)
        chunk = max(1, LOOP_SOLVE_BYTES // max(per_world, 1))
        if W <= chunk:
            return self._solve_coupled(tree_rows, loop_rows, rows, inv_metric_times, M, M_inv, slice(None))
        parts = [self._solve_coupled(tree_rows, loop_rows, rows, inv_metric_times, M, M_inv, slice(w, min(w + chunk, W)))
                 for w in range(0, W, chunk)]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def _solve_coupled(self, tree_rows, loop_rows, rows, inv_metric_times, M, M_inv, worlds):
        """``solve_coupled`` for the worlds of the slice ``worlds``."""
        a, b, Ja, Jb, mask, r = (x if i < 2 else x[worlds] for i, x in enumerate(tree_rows))
        la, lb, La, Lb, lmask, lr = (x if i < 2 else x[worlds] for i, x in enumerate(loop_rows))
        if M is None:
            M, M_inv = self.M, self.M_inv
        factors = self._factor(Ja, Jb, mask, M[worlds], M_inv=None if M_inv is None else M_inv[worlds])
        W, nl = lr.shape[:2]

        def rows_of(JA, JB, ia, ib, v):
            """J v for row blocks with sides ia, ib: (W, n, 6, k) from (W, N, 6, k)."""
            return _mm(JA, v.take(ia, 1)) + _mm(JB, v.take(ib, 1))

        # G = W⁻¹ J_Lᵀ, one column per used loop row (the kinds' rows; broken
        # joints' rows are masked per world below).
        used = rows.used_rows
        m = used.size
        eye = np.zeros((W, nl * 6, m))
        eye[:, used, np.arange(m)] = 1.0
        G = inv_metric_times(self.body_columns(La, Lb, eye.reshape(W, nl, 6, m), rows), worlds)
        X = self._substitute_columns(factors, rows_of(Ja, Jb, a, b, G))  # K_TT⁻¹ K_TL (W, nj, 6, m)
        V = inv_metric_times(self.body_columns(Ja, Jb, X), worlds)
        S = (rows_of(La, Lb, la, lb, G) - rows_of(La, Lb, la, lb, V)).reshape(W, nl * 6, m)[:, used]
        # Rows of a straight chain between two pins are redundant (a 10x10 grid
        # pinned at two corners of one edge): a relative 1e-6 on the diagonal
        # keeps S definite; an impulse in that null space moves nothing.
        diag = np.arange(m)
        lm = lmask.reshape(W, nl * 6)[:, used]
        S[:, diag, diag] += (1.0 - lm) + LOOP_REGULARISATION * S[:, diag, diag].max(axis=1, keepdims=True)
        y = self._substitute_columns(factors, r[..., None])  # K_TT⁻¹ r_T
        Ky = rows_of(La, Lb, la, lb, inv_metric_times(self.body_columns(Ja, Jb, y), worlds))
        rhs = (lr[..., None] - Ky).reshape(W, nl * 6, 1)[:, used] * lm[..., None]
        # A world already diverging (non-finite S) is solved as identity rows:
        # it is reported non-finite after the step instead of stopping the batch.
        bad = ~np.isfinite(S).all(axis=(1, 2))
        if bad.any():
            S[bad] = np.eye(m)
        try:
            x_used = np.linalg.solve(S, rhs)  # (W, m, 1)
        except np.linalg.LinAlgError:  # singular in floating point: a diverging world, NaN as above
            x_used = np.matmul(inverse_or_nan(S), rhs)
        x_t = (y - np.matmul(X, x_used[:, None]))[..., 0]
        x_l = np.zeros((W, nl * 6))
        x_l[:, used] = x_used[..., 0]
        return x_t, x_l.reshape(W, nl, 6)

    def _lam(self, state, rows=None):
        """Accumulated equality-row impulses (W, n, 6) of the tree's joints (or of ``rows``)."""
        idx = (self if rows is None else rows).joints
        return np.concatenate((state.joint_linear_impulse.take(idx, 1), state.joint_angular_impulse.take(idx, 1)),
                              axis=-1)

    def _apply(self, js, model, state, a, b, Ja, Jb, d, rows=None):
        """Accumulate the equality-row impulses d of the tree's joints (or of
        ``rows``; rows 3..5 of limit-taken slots are not stored here) and apply
        J_aᵀ d, J_bᵀ d."""
        rows = self if rows is None else rows
        new = self._lam(state, rows) + d * rows.eq_mask
        state.joint_linear_impulse[:, rows.joints] = new[..., :3]
        state.joint_angular_impulse[:, rows.joints] = new[..., 3:]
        imp = self._body_impulses(Ja, Jb, d, rows)
        state.velocity += imp[..., :3] * model.inv_mass[:, None]
        state.angular_velocity += mat_vec(self.iinv, imp[..., 3:])

    def _factor_solve(self, Ja, Jb, mask, r, M=None, ball_rows=True, M_inv=None):
        """(J M⁻¹ Jᵀ)⁻¹ r over the rows in mask (others 0); M, ``ball_rows``
        and ``M_inv`` as in ``_factor``."""
        return self._substitute(self._factor(Ja, Jb, mask, M, ball_rows, M_inv), r)

    def _factor(self, Ja, Jb, mask, M=None, ball_rows=True, M_inv=None):
        """Block LDLᵀ factors of [M Jᵀ; J 0] in leaves-first order (M: the
        bodies' (W, tree bodies, 6, 6) metric, default their mass matrices;
        ``M_inv``, if known, its inverse), by the kernels of
        :mod:`engine.core.tree`, one world at a time.

        A body node's pivot is D_b = M_b - Σ_children J_pᵀ D_j⁻¹ J_p; a joint
        node's is D_j = diag(mask - 1) - J_c D_c⁻¹ J_cᵀ (its one child body c).
        Closed forms: a leaf body's pivot is M_b, whose inverse is M_inv's
        (with the mass metric blockdiag(I/m, I_w⁻¹)); a ball joint's (``ball_rows``: its
        angular rows 3-5 are empty, as ``blocks`` builds them) is
        blockdiag(D_j[:3, :3], -I), one 3x3 inverse by the adjugate (it reads
        the upper triangle of a block symmetric to rounding, and the block is
        negative definite, never singular: -I for a broken joint). Returns
        D⁻¹ and L = D⁻¹ H_parent of every node, each (W, nodes, 6, 6), nodes
        numbered tree bodies first, then tree joints (L of a root is 0)."""
        metric, leaf_inv = (self.M, self.M_inv) if M is None else (M, M_inv)
        W, n = mask.shape[0], self.t.n_nodes
        Dinv = np.empty((W, n, 6, 6))
        L = np.empty((W, n, 6, 6))
        metric = np.ascontiguousarray(metric, dtype=np.float64)
        tree_kernels.factor_batch(self.layout, np.ascontiguousarray(Ja, dtype=np.float64),
                                  np.ascontiguousarray(Jb, dtype=np.float64),
                                  np.ascontiguousarray(mask, dtype=np.float64), metric,
                                  metric if leaf_inv is None else np.ascontiguousarray(leaf_inv, dtype=np.float64),
                                  leaf_inv is not None, bool(ball_rows), Dinv, L)
        return Dinv, L

    def _substitute(self, factors, r):
        """Forward and back substitution with the factors of ``_factor``:
        (J M⁻¹ Jᵀ)⁻¹ r for r (W, nj, 6)."""
        return self._substitute_columns(factors, r[..., None])[..., 0]

    def _substitute_columns(self, factors, R):
        """The same for k right-hand sides at once, R (W, nj, 6, k)."""
        Dinv, L = factors
        X = np.empty(R.shape)
        tree_kernels.substitute_batch(self.layout, Dinv, L, np.ascontiguousarray(R, dtype=np.float64), X)
        return X  # (J M⁻¹ Jᵀ)⁻¹ R per joint
