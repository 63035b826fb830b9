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
from .core import tree_solve
from .joints import BALL, FIXED, HINGE
from .math3d import inverse_or_nan, mat_vec
from .scatter import Scatter, scatter_add

LOOP_SOLVE_BYTES = 256 * 2 ** 20  # most temporaries of one chunk of worlds in the loop solve
LOOP_REGULARISATION = 1e-6  # of the largest diagonal entry, added to the loop rows' Schur complement
#: Most limit rows in a tree for its active set on one factorisation (``engine.core.tree_solve``).
SCHUR_LIMIT_ROWS = tree_solve.SCHUR_LIMIT_ROWS


def _mm(A, B):
    """A B for (..., n, k), (..., k, m)."""
    return np.matmul(A, B)


def _mtm(A, B):
    """Aᵀ B for (..., k, n), (..., k, m)."""
    return np.matmul(np.swapaxes(A, -1, -2), B)


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
        self.used_rows = np.flatnonzero(self.eq_mask.reshape(-1))  # of the joints' 6 rows each, flattened
        self.arrays = _row_arrays(joints, kind, parent, child, self.ang_mask, self.eq_mask)


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
        joint_child = np.zeros(t.n_nodes - nb, dtype=np.int64)  # each joint node's child body node
        for node in range(nb):
            if t.node_parent[node] >= nb:
                joint_child[t.node_parent[node] - nb] = node
        # The static tree for the factorisation kernels (engine.core.tree).
        self.layout = tree_kernels.TreeLayout(
            order=t.order, parent=t.node_parent.astype(np.int64), n_bodies=int(nb),
            leaf=np.ascontiguousarray(~has_child[:nb]), ball=np.ascontiguousarray(self.kind == BALL),
            child_is_b=np.ascontiguousarray(self.child_is_b, dtype=bool), joint_child=joint_child)
        self.limits = False
        self.exact_loop = None  # (articulations + 1,) bool: closed by loops solved with the tree (JointSet)
        self.loop_bodies = np.zeros(model.num_bodies, dtype=bool)  # (N,): bodies of those articulations (JointSet)
        self.body_node = np.full(model.num_bodies, -1, dtype=np.int64)  # (N,): each body's tree node, -1 off it
        self.body_node[t.bodies] = np.arange(t.bodies.size)
        self.active_set_passes = settings.joint_active_set_passes
        self.component, self.num_components, self.body_component = t.component, t.num_components, t.body_component
        self.geometric_weight = None  # per step: 1, or (W, tree joints) weights, or None
        self.loop_geometric_weight = None  # the same for the loop-closing rows solved with the tree
        self.loaded = None  # the step's (loaded joints, weights) of ``loaded_joints``, with geometric stiffness
        self._factored = None  # (state, blocks, factors) of the current positions and metric (see solve)
        # Per tree joint: which limit rows exist (twist, swing) while the joint
        # is whole, and the tree's possible limit rows (tree joint, slot 0 twist
        # or 1 swing), twist rows first.
        lo, hi = js.lower[j], js.upper[j]
        self.limit_exists = np.zeros((j.size, 2), dtype=bool)
        self.limit_exists[:, 0] = js.has_limit[j] & (self.kind != FIXED)
        self.limit_exists[:, 1] = js.has_swing[j]
        twist_j, swing_j = np.flatnonzero(self.limit_exists[:, 0]), np.flatnonzero(self.limit_exists[:, 1])
        self.limit_candidates = (np.concatenate((twist_j, swing_j)).astype(np.int64),
                                 np.repeat([0, 1], (twist_j.size, swing_j.size)).astype(np.int64))
        b = t.bodies
        self.arrays = self.arrays._replace(
            ball=np.ascontiguousarray(self.kind == BALL), lo=np.where(np.isfinite(lo), lo, 0.0),
            hi=np.where(np.isfinite(hi), hi, 0.0), lo_finite=np.isfinite(lo), hi_finite=np.isfinite(hi),
            limit_exists=self.limit_exists, cand_joint=self.limit_candidates[0], cand_slot=self.limit_candidates[1],
            bodies=b.astype(np.int64), mass=np.ascontiguousarray(model.mass[b], dtype=float),
            inertia=np.ascontiguousarray(model.inertia[b], dtype=float),
            inv_mass=np.array(model.inv_mass, dtype=float))
        self._scratch = None  # TreeScratch of the last solve's batch (engine.core.tree_solve)

    def begin_step(self, js, model, state, h):
        """The bodies' metric M (W, tree bodies, 6, 6) at the state's
        orientations, mass and world inertia and, with geometric stiffness,
        its added inertia (``engine.core.tree_solve.metric``); every joint
        row then uses the stiffened inverse inertias (``js._iinv``). Factors
        of earlier positions are dropped."""
        self._factored = None
        t = self.t
        W = state.orientation.shape[0]
        nb = t.n_bodies
        self.M, self.M_inv = np.empty((W, nb, 6, 6)), np.empty((W, nb, 6, 6))
        geometric = self.geometric_weight is not None
        J = state.joint_linear_impulse.shape[1]
        self.loaded = self.loaded_joints(js, W) if geometric else None  # for the step's substeps
        if geometric:
            idx, weight = self.loaded
            g = js.geometry(state)
            ra, rb = g.ra, g.rb
            iinv_out = np.empty_like(js._iinv)
        else:
            idx, weight = np.zeros(0, dtype=np.int64), np.zeros((W, 0))
            ra = rb = np.zeros((W, J, 3))
            iinv_out = js._iinv
        use_before = js._load_before is not None
        load_before = js._load_before if use_before else np.zeros((W, J))
        tree_solve.metric_batch(self.arrays, js._rot, js._iinv, idx, js.parent[idx], js.child[idx], self.joints.size,
                                np.ascontiguousarray(weight), state.joint_linear_impulse, load_before, use_before, ra,
                                rb, h, js.settings.joint_geometric_stiffness_cap, geometric, iinv_out, self.M,
                                self.M_inv)
        js._iinv = self.iinv = iinv_out

    def loaded_joints(self, js, W):
        """The joints whose load stiffens the metric (geometric stiffness):
        the tree joints, then the loop-closing joints solved with the tree
        (they carry load too), and their weights (W, loaded)."""
        parts = [(self.joints, self.geometric_weight)]
        if js.loop_rows is not None and self.loop_geometric_weight is not None:
            parts.append((js.loop_rows.joints, self.loop_geometric_weight))
        idx = np.concatenate([p[0] for p in parts]).astype(np.int64)
        weight = np.concatenate([np.broadcast_to(np.asarray(wt, dtype=float), (W, p.size)) for p, wt in parts],
                                axis=1)
        return idx, np.ascontiguousarray(weight)

    def uses_schur(self) -> bool:
        """Whether the active set runs on one factorisation (at most
        ``SCHUR_LIMIT_ROWS`` limit rows) rather than factoring each pass."""
        return self.limit_candidates[0].size <= SCHUR_LIMIT_ROWS

    def scratch(self, W):
        """The solve's ``TreeScratch`` for W worlds (kept between steps)."""
        S = self._scratch
        if S is None or S.mask.shape[0] != W:
            S = self._scratch = tree_solve.empty_scratch(W, self.joints.size, self.t.n_nodes)
            self._factored = None
        return S

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
        mask (W, nj, 6) (``engine.core.tree_solve.blocks``)."""
        a, b, fpw, fcw, ra, rb = js.frames(state, rows.joints)
        g = js.geometry(state)
        W, nj = state.num_worlds, rows.joints.size
        E, mask = np.empty((W, nj, 3, 3)), np.empty((W, nj, 6))
        Ja, Jb = np.empty((W, nj, 6, 6)), np.empty((W, nj, 6, 6))
        tree_solve.blocks_batch(rows.arrays, g.fpw, g.ra, g.rb, state.joint_broken, E, mask, Ja, Jb)
        return a, b, fpw, fcw, ra, rb, E, Ja, Jb, mask

    def right_hand_side(self, js, state, blocks, rows, use_bias, bias_rate, velocity=True, max_push_out=None,
                        max_angular_push_out=None):
        """``jacobians`` from the ``blocks`` of the current positions: (a, b,
        Ja, Jb, mask, r) with r = J·u + bias·C (W, nj, 6)."""
        if max_push_out is None:
            max_push_out = js.settings.joint_max_push_out
        if max_angular_push_out is None:
            max_angular_push_out = js.settings.joint_max_angular_push_out
        a, b, _, _, _, _, E, Ja, Jb, mask = blocks
        g = js.geometry(state)
        r = np.empty(mask.shape)
        # Without ``velocity`` the state may hold positions alone (the joint projection's).
        v, w = (state.velocity, state.angular_velocity) if velocity else (state.position, state.position)
        tree_solve.right_hand_side_batch(rows.arrays, E, mask, g.fpw, g.fcw, g.ra, g.rb, state.position,
                                         state.orientation, v, w, bool(velocity),
                                         bool(use_bias), _per_joint(bias_rate, mask.shape[0], mask.shape[1]),
                                         float(max_push_out), float(max_angular_push_out), r)
        return a, b, Ja, Jb, mask, r

    def limit_rows(self, js, state, h, use_bias):
        """The limit rows in the free angular slots of each tree joint (hinge
        slot 3, the twist; ball slots 3 and 4, twist and swing), after taking
        the accumulated limit impulse off the velocities
        (``engine.core.tree_solve.limit_rows``). Returns the rows' axes
        (W, nj, 3, 3), right-hand sides (W, nj, 3), sign σ (W, nj, 3) with
        σ·λ >= 0 required, which rows exist (W, nj, 3) and whether the twist
        row is the lower bound's (W, nj); the third slot never holds a row."""
        W, nj = state.num_worlds, self.joints.size
        lrows, lr = np.zeros((W, nj, 2, 3)), np.zeros((W, nj, 2))
        sigma, exists, lower = np.ones((W, nj, 2)), np.zeros((W, nj, 2), dtype=bool), np.zeros((W, nj), dtype=bool)
        tree_solve.limit_rows_batch(self.arrays, js.geometry(state), state.joint_broken, js._iinv,
                                    state.angular_velocity, state.joint_limit_impulse, h, bool(use_bias),
                                    float(js.settings.joint_max_angular_push_out), lrows, lr, sigma, exists, lower)
        pad = ((0, 0), (0, 0), (0, 1))
        return (np.pad(lrows, pad + ((0, 0),)), np.pad(lr, pad), np.pad(sigma, pad, constant_values=1.0),
                np.pad(exists, pad), lower)

    def solve(self, js, model, state, bias_rate, mass_scale, impulse_scale, use_bias, h):
        """One solve of the tree rows (``engine.core.tree_solve.solve_world``):
        the equality rows by the soft step (bias_rate, mass_scale,
        impulse_scale: scalars or (W, nj, 1)), and with limits in the tree the
        limit rows by their active set. The blocks and factors are built once
        per set of positions and metric: the relax solve of one substep and the
        biased solve of the next see the same positions (only the velocities
        change between them), so the second reuses the first's. Factors of a
        solve before the positions moved are never reused (a relax solve on
        stale factors can add energy)."""
        W, nj = state.num_worlds, self.joints.size
        S = self.scratch(W)
        refactor = self._factored is not state
        s = js.settings
        tree_solve.solve_batch(self.arrays, self.layout, js.geometry(state), state.joint_broken, js._iinv, self.M,
                               self.M_inv, state.position, state.orientation, state.velocity, state.angular_velocity,
                               state.joint_linear_impulse, state.joint_angular_impulse, state.joint_limit_impulse,
                               _per_joint(bias_rate, W, nj), _per_joint(mass_scale, W, nj),
                               _per_joint(impulse_scale, W, nj), bool(use_bias), float(h), float(s.joint_max_push_out),
                               float(s.joint_max_angular_push_out), bool(self.limits), self.uses_schur(),
                               int(self.active_set_passes), refactor, S)
        self._factored = state

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
        loop row. Returns x_T (W, nj, 6), x_L (W, nl, 6).

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


def _row_arrays(joints, kind, parent, child, ang_mask, eq_mask):
    """The ``TreeRows`` of a list of joints (``engine.core.tree_solve``) without
    limits or bodies (``_TreeSolver`` fills those for the tree's joints)."""
    joints = np.asarray(joints, dtype=np.int64)
    n = joints.size
    none = np.zeros(n, dtype=bool)
    return tree_solve.TreeRows(
        joint=joints, a=np.asarray(parent, dtype=np.int64), b=np.asarray(child, dtype=np.int64),
        hinge=np.ascontiguousarray(kind == HINGE), fixed=np.ascontiguousarray(kind == FIXED),
        ball=np.ascontiguousarray(kind == BALL), ang_mask=np.ascontiguousarray(ang_mask, dtype=float),
        eq_mask=np.ascontiguousarray(eq_mask, dtype=float), lo=np.zeros(n), hi=np.zeros(n), lo_finite=none,
        hi_finite=none, limit_exists=np.zeros((n, 2), dtype=bool), cand_joint=np.zeros(0, dtype=np.int64),
        cand_slot=np.zeros(0, dtype=np.int64), bodies=np.zeros(0, dtype=np.int64), mass=np.zeros(0),
        inertia=np.zeros((0, 3)), inv_mass=np.zeros(0))


def _per_joint(x, W, nj):
    """A softness term (a scalar, or (W, nj) or (W, nj, 1) per joint) as a contiguous (W, nj) array."""
    if np.ndim(x) == 0:
        return np.full((W, nj), float(x))
    a = np.asarray(x, dtype=float)
    if a.ndim == 3:
        a = a[..., 0]
    if a.shape != (W, nj):
        a = np.broadcast_to(a, (W, nj))
    return np.ascontiguousarray(a)
