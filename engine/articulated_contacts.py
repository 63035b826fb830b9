"""Contacts of articulations on static bodies, solved with the articulation's
response (``Settings.articulated_contacts``).

The contact solver (``contact_solver``) gives each row the effective mass of
the one body it touches: a 1 kg foot stops, and the joint solve after it hands
the impulse to the 70 kg body above, so against rigid joints a resting
ragdoll chatters and its joints open (soft tree joints, ``SOFT_JOINTS``, let
the two agree, at the price of anchor error). Here the rows between a static body
(the ground) and bodies held by tree joints are solved in contact space, with
the joints in the metric:

* Unit impulse on contact column i (point p, direction d ∈ {n, t1, t2}, on
  body b with lever arm r): J_i = [d, r × d] on b. Unconstrained response
  U_i = M⁻¹ J_iᵀ (the tree's metric M: masses, world inertias).
* The tree joints (rows J_t, K = J_t M⁻¹ J_tᵀ, factored by the tree solver)
  answer with λ = -K⁻¹ J_t U_i, so the constrained response is
  Z_i = U_i - M⁻¹ J_tᵀ K⁻¹ J_t U_i (the Schur complement of the joints'
  KKT system: Baraff 1996, "Linear-time dynamics using Lagrange
  multipliers", section 7; Featherstone 2008, ch. 7's articulated inertia
  seen at a contact point).
* The Delassus matrix A = J_c Z (columns x columns per world) couples every
  point of every row on the articulation: projected Gauss-Seidel on it
  (``articulated_contact_sweeps`` per solve, two by default, the normal
  columns then the friction pairs, the same
  soft normal rows and Coulomb disc as ``contact_solver``), then the
  velocities change by Z Δλ at once: the joints stay satisfied at velocity
  level, with no joint error for the joint solve to hand back. The sweeps
  are sequential by nature (one Python iteration per column, vectorised over
  the worlds); where one world holds points (a batch of one world, or one
  world of a batch touching the ground), they run on Python floats, the same
  operations in the same order, as numpy's cost per call would dominate.

Z and A are computed once per step at the step's start positions, as the
contact rows keep their lever arms for the step. There are three columns
(normal, two friction directions) per valid contact point, packed per world
and padded to the batch's largest count C. Only the worlds with a valid
point are held, most points first, so that the work on a column (Z, A, the
sweeps) covers the worlds that have it, a prefix (``worlds_at``): at 256
fallen ragdolls (9-30 points, 18 on average) that, with A stored by
column (below), took the contacts' share of a step from 210 to 145 ms.
Memory per world: C x (6 x bodies
+ 7 + C) floats for Z, J, A and the per-column arrays; while they are built,
the tree's substitution holds one COLUMN_BLOCK x 6 block per tree node and
A's build about four C x COLUMN_BLOCK. A ragdoll lying
on the ground has up to about 31 valid points (C = 93) against 14 rows of 4
point slots (168 columns when every slot had its columns).

Restitution: a point's closing speed just before it first takes load in the
step is recorded as in ``contact_solver``, and its bounce (``bounce``) raises
its separating speed to the target in the same contact space. Not covered
(these rows keep the body-by-body Gauss-Seidel): rows between two moving
bodies, articulations closed by loops. Joint limits act after the tree solve (or in it, with
``joint_limits_in_tree``) and are not in Z.
"""

from __future__ import annotations

import math

import numpy as np

from .math3d import cross, mat_vec

COLUMN_BLOCK = 24  # contact columns per pass of the tree substitution in Z (8 points)


def _coulomb_scale(t1, t2, limit):
    """Factor that brings the tangent impulse (t1, t2) into the disc |λ_t| <= limit."""
    mag = np.sqrt(t1 * t1 + t2 * t2)
    return np.where(mag > limit, limit / np.maximum(mag, 1e-30), 1.0)


def _first(factors, n, W):
    """The tree's factors (``_TreeSolver._factor``: D⁻¹ and L, each (W,
    nodes, 6, 6)) of the first n of W worlds (views)."""
    if n == W:
        return factors
    Dinv, L = factors
    return Dinv[:n], L[:n]


def _max0(x: float) -> float:
    """np.maximum(x, 0.0) of one float: x above 0, NaN kept, else +0.0 (as numpy gives for -0.0)."""
    return x if x > 0.0 or math.isnan(x) else 0.0


class ArticulatedContacts:
    """The rows of a step's ``ContactRows`` ``cr`` between a static body and a
    jointed body (without restitution), in contact space; ``js``: the
    model's ``JointSet`` after its ``begin_step``."""

    def __init__(self, model, state, cr, js):
        tree = js.tree
        rows = np.flatnonzero(cr.jointed & ~cr.dyn_a & cr.dyn_b)
        if tree is not None and tree.exact_loop is not None:
            # Articulations closed by loops keep the body-by-body rows: Z below knows the tree rows only.
            rows = rows[~tree.exact_loop[tree.body_component[cr.b[rows]]]]
        self.rows = rows
        self.empty = rows.size == 0 or tree is None
        if self.empty:
            return
        N = model.num_bodies
        # One column per valid point and direction, packed per world: a
        # point's index k among its world's valid points (in row and point
        # order) gives its normal column 3k and friction columns 3k+1, 3k+2.
        # A world's columns come in the order the rows came, and the padding
        # up to the batch's largest count is inert (valid False, J = 0).
        ri, pi = np.nonzero(cr.valid[rows])  # the valid points: local row, point
        pw_batch = cr.w[rows][ri]
        order = np.argsort(pw_batch, kind="stable")
        pws = pw_batch[order]
        k = np.empty(ri.size, dtype=np.int64)
        k[order] = np.arange(ri.size) - np.searchsorted(pws, pws, side="left")
        # The worlds with a valid point, most points first (ties in world
        # order): the arrays below hold them in that order, so the worlds
        # with a column q are the first worlds_at[q // 3], and each pass
        # over a column (Z and A below, the sweeps) works on that prefix
        # alone. A fallen ragdoll has 9-30 points (mean 18 of 256 worlds):
        # padded to the largest count, most of A was padding.
        count = np.bincount(pw_batch, minlength=state.num_worlds)
        self.worlds = np.argsort(-count, kind="stable")[:np.count_nonzero(count)]  # batch world of each slot
        # The batch's arrays are read through views where that order is the batch's own.
        identity = self.worlds.size == state.num_worlds and bool((self.worlds == np.arange(self.worlds.size)).all())
        self._batch = slice(None) if identity else self.worlds
        slot = np.empty(state.num_worlds, dtype=np.int64)
        slot[self.worlds] = np.arange(self.worlds.size)
        pw = slot[pw_batch]
        W = self.worlds.size
        self.W, self.N = W, N
        C = 3 * (int(k.max()) + 1 if k.size else 0)
        self.worlds_at = np.count_nonzero(count[self.worlds][None, :] > np.arange(C // 3)[:, None], axis=1).tolist()
        self.pt_local, self.pt_row, self.pt_p = (ri, pi), rows[ri], pi
        self.pt_w, self.pt_col = pw, 3 * k  # the point's slot (world) and normal column
        d = np.stack((cr.n[self.pt_row], cr.t1[self.pt_row], cr.t2[self.pt_row]), axis=1)  # (points, direction, 3)
        J = np.concatenate((d, cross(np.broadcast_to(cr.rb[self.pt_row, pi][:, None], d.shape), d)), axis=-1)
        w3 = np.broadcast_to(pw[:, None], (ri.size, 3))
        col3 = self.pt_col[:, None] + np.arange(3)
        b3 = np.broadcast_to(cr.b[self.pt_row][:, None], w3.shape)
        # Each column acts on one body: its 6-vector J (W, C, 6) and body (W, C) (padding: body 0, J = 0).
        self.J = np.zeros((W, C, 6))
        self.J[w3, col3] = J
        self.body = np.zeros((W, C), dtype=np.int64)
        self.body[w3, col3] = b3
        iinv = tree.iinv[self._batch]
        response = np.concatenate(  # U_i = M⁻¹ J_iᵀ on the column's body (points, direction, 6)
            (J[..., :3] * model.inv_mass[b3][..., None], mat_vec(iinv[w3, b3], J[..., 3:])), axis=-1)
        # Z = U - M⁻¹ J_tᵀ K⁻¹ J_t U, through the tree's factors at these
        # positions, COLUMN_BLOCK columns at a time: the substitution's and
        # the products' temporaries are a few times the size of the columns.
        # Z is stored by columns, each contiguous: Z_columns[w, i] = Z[w, :, i].
        a, b, _, _, _, _, _, Ja, Jb, mask = tree.blocks(js, state, tree)
        Ja, Jb, mask = Ja[self._batch], Jb[self._batch], mask[self._batch]
        self.M, self.tree_bodies = tree.M[self._batch], tree.t.bodies  # the metric of the joint solve, for _velocities
        factors = tree._factor(Ja, Jb, mask, self.M, M_inv=tree.M_inv[self._batch])
        self.Z_columns = np.empty((W, C, N * 6))
        for lo in range(0, C, COLUMN_BLOCK):
            hi = min(lo + COLUMN_BLOCK, C)
            n = self.worlds_at[lo // 3]
            self.Z_columns[n:, lo:hi] = 0.0
            sel = (col3 >= lo) & (col3 < hi)  # points of the first n worlds only
            U = np.zeros((n, N, 6, hi - lo))
            U[w3[sel], b3[sel], :, col3[sel] - lo] = response[sel]
            Jan, Jbn = Ja[:n], Jb[:n]
            B = (np.matmul(Jan, U[:, a]) + np.matmul(Jbn, U[:, b])) * mask[:n, ..., None]
            F = tree.body_columns(Jan, Jbn, tree._substitute_columns(_first(factors, n, W), B))
            U[..., :3, :] -= F[..., :3, :] * model.inv_mass[:, None, None]
            U[..., 3:, :] -= np.matmul(iinv[:n], F[..., 3:, :])
            self.Z_columns[:n, lo:hi] = U.reshape(n, N * 6, hi - lo).transpose(0, 2, 1)
        # A = J_c Z (C, C per world), stored by columns, each column of every
        # world in one contiguous block: A_by_column[i, w] = A[w, :, i], the
        # column velocities' change per unit impulse on column i (the sweeps
        # read one column of every world per update, 1.5 times faster
        # contiguous than as (W, C, C) slices; A is symmetric only to
        # rounding). Row r of J_c is J[r] on its body's six rows of Z, so
        # A[r, i] = Σ_d J[r, d] Z[6 body_r + d, i], summed over d in order,
        # element by element: a matrix product over the padded columns rounded
        # differently with the batch's column count, and a world stepped alone
        # left the batch's trajectory after 82 steps. The three columns of a
        # point share its body, so each Z row is gathered once per point.
        # Built after Z, not block by block within its loop: A alive beside the
        # substitution's temporaries raised the step's peak memory by a fifth.
        self.A_by_column = np.zeros((C, W, C))
        point_body = self.body[:, 0::3]
        J_points = self.J.reshape(W, C // 3, 3, 6)
        A = self.A_by_column.reshape(C, W, C // 3, 3)
        Z = self.Z_columns.reshape(W, C, N, 6)
        for lo in range(0, C, COLUMN_BLOCK):
            hi = min(lo + COLUMN_BLOCK, C)
            n = self.worlds_at[lo // 3]
            columns, worlds, bodies = np.arange(lo, hi)[:, None, None], np.arange(n)[:, None], point_body[:n]
            Zp = Z[worlds, columns, bodies]  # (block, n, points, 6): Z's rows at each point's body
            for d in range(6):
                A[lo:hi, :n] += Zp[..., None, d] * J_points[:n, :, :, d]
        diag = np.einsum("cwc->wc", self.A_by_column)
        self.m = np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1.0), 0.0)  # effective masses
        self.valid = np.zeros((W, C), dtype=bool)
        self.valid[w3, col3] = True
        self.mu = np.zeros((W, C))
        self.mu[pw, self.pt_col] = cr.mu[self.pt_row, pi]
        self.normals = np.arange(0, C, 3)  # every normal column is some world's point
        self.sweeps = model.settings.articulated_contact_sweeps
        # The sweeps skip unchanged columns only while A is finite (see solve).
        self.skip_unchanged = bool(np.isfinite(self.A_by_column).all())
        if W == 1:  # the step's constants of _sweep_one_world, as Python floats
            self._one_world_constants = (self.m[0].tolist(), self.mu[0].tolist(), self.normals.tolist())

    # ------------------------------------------------------------------ impulses
    def _gather(self, cr):
        """The valid points' accumulated impulses as (W, columns)."""
        lam = np.zeros(self.valid.shape)
        for k, src in enumerate((cr.lam_n, cr.lam_t1, cr.lam_t2)):
            lam[self.pt_w, self.pt_col + k] = src[self.pt_row, self.pt_p]
        return lam

    def _scatter(self, cr, lam):
        """Impulses (W, columns) back to the rows' points (0 at invalid points)."""
        for k, dst in enumerate((cr.lam_n, cr.lam_t1, cr.lam_t2)):
            dst[self.rows] = 0.0
            dst[self.pt_row, self.pt_p] = lam[self.pt_w, self.pt_col + k]
        cr.max_lam_n[self.rows] = np.maximum(cr.max_lam_n[self.rows], cr.lam_n[self.rows])

    def _normal_columns(self, values):
        """Per-point values (rows, P) of the rows as (W, columns) at the valid points' normal columns."""
        out = np.zeros(self.valid.shape)
        out[self.pt_w, self.pt_col] = values[self.pt_local]
        return out

    def _velocities(self, state):
        """Column velocities J_c P v (W, columns) after the joint solve that
        follows: P v = v - M⁻¹J_tᵀK⁻¹J_t v, the velocities projected onto the
        tree joints' rows (exact for the relax solve's unbiased rows; the
        limit rows and the bias are not in P). As Z = P M⁻¹J_cᵀ and
        M⁻¹PᵀM = P, J_c P v = Zᵀ M v: one product with the momenta. Read
        unprojected (J_c v), the columns saw a foot turned freely by its
        ankle motor within the substep, which the joint solve then takes
        back: the standing PD's feet spun at up to 125 rad/s in one of 20
        Balance worlds without pushes (rigid joints, ``CLOSED_JOINTS``)."""
        v = np.concatenate((state.velocity[self._batch], state.angular_velocity[self._batch]),
                           axis=-1)[:, self.tree_bodies, :, None]
        p = np.zeros((self.W, self.N, 6))
        p[:, self.tree_bodies] = np.matmul(self.M, v)[..., 0]
        # Each column a dot product over the 6 N body rows (contiguous; einsum
        # may use partial sums, but their grouping depends on 6 N alone), so a
        # world's columns do not depend on how many the batch pads to.
        return np.einsum("wk,wck->wc", p.reshape(self.W, self.N * 6), self.Z_columns)

    def _apply(self, state, lam):
        """Velocities += Z λ (every body of each articulation, in the worlds
        held; the others are left as they are). einsum sums
        each body row over the columns one after the other, in column order
        (as a loop of dv += Z[:, i] λ_i does, bit for bit, and 9 times
        faster at W = 256), so padded columns add exact zeros at the end;
        a matrix product would group the sum by the batch's column count, and
        a world stepped alone would differ from the same world in a batch in
        the last bits (``test_batch_replays_bit_for_bit``)."""
        dv = np.einsum("wck,wc->wk", self.Z_columns, lam).reshape(self.W, self.N, 6)
        state.velocity[self._batch] += dv[..., :3]
        state.angular_velocity[self._batch] += dv[..., 3:]

    def warm_start(self, state, cr):
        lam = self._gather(cr)
        if lam.any():
            self._apply(state, lam)

    # --------------------------------------------------------------------- solve
    def solve(self, state, cr, h, use_bias):
        """``Settings.articulated_contact_sweeps`` projected Gauss-Seidel sweeps
        over the columns (``contact_solver``'s per-point rules with the
        effective masses 1 / A_ii), then Z Δλ."""
        sep = self._normal_columns(cr.separation_of(state, self.rows))
        open_ = sep > 0
        if use_bias and not cr.thesis:
            soft = cr.soft
            bias = np.where(open_, sep / h, np.maximum(soft.bias_rate * np.minimum(sep + cr.slop, 0.0),
                                                       -cr.max_push_out))
            gain = -self.m * np.where(open_, 1.0, soft.mass_scale)
            isc = np.where(open_, 0.0, soft.impulse_scale)
        else:
            bias, gain, isc = np.where(open_, sep / h, 0.0), -self.m, None
        # u + 0.0 has no -0.0 entries, and a sum of two numbers is -0.0 only
        # if both are: so while A is finite, adding an exact zero change
        # (A_i · 0) never changes u, and the sweeps skip the columns whose
        # impulse did not change (95% of a fallen ragdoll's updates).
        u = self._velocities(state) + 0.0
        lam = self._gather(cr)
        start = lam.copy()
        n = self.normals
        # For restitution: each point's closing speed and gap just before it first takes load.
        loaded = self._normal_columns(cr.max_lam_n[self.rows])[:, n] > 0
        v_close = self._normal_columns(cr.vn_close[self.rows])
        s_close = self._normal_columns(cr.s_close[self.rows])
        sweep_columns = self._sweep_one_world if self.W == 1 else self._sweep_batch
        for sweep in range(self.sweeps):
            # A column's impulse changes only at its own update, so the terms
            # read from the sweep's start (the impulse term, the restitution
            # record) are taken out of the sweep's loop over the columns.
            sweep_start = start if sweep == 0 else lam.copy()
            isc_lam = None if isc is None else isc * sweep_start
            u_before = sweep_columns(u, lam, sweep_start, gain, bias, isc_lam)
            first = ~loaded & (lam[:, n] > 0)
            v_close[:, n] = np.where(first, u_before[:, n], v_close[:, n])
            s_close[:, n] = np.where(first, sep[:, n], s_close[:, n])
            loaded |= first
        cr.vn_close[self.pt_row, self.pt_p] = v_close[self.pt_w, self.pt_col]
        cr.s_close[self.pt_row, self.pt_p] = s_close[self.pt_w, self.pt_col]
        self._apply(state, lam - start)
        self._scatter(cr, lam)

    def _sweep_batch(self, u, lam, sweep_start, gain, bias, isc_lam):
        """One Gauss-Seidel sweep, the normal columns then the friction pairs,
        updating the column velocities u and impulses lam (W, columns) in
        place; returns each normal column's velocity at its update (0 in the
        worlds without the column). u holds no -0.0 (``solve``), so a column
        whose impulse changed in no world is skipped (when A is finite: inf ·
        0 is NaN, which must reach u). A column's update runs on the worlds
        that have it (``worlds_at``): in the others it is padding, its
        impulse 0 and its A column 0."""
        A, valid, skip, m, mu = self.A_by_column, self.valid, self.skip_unchanged, self.m, self.mu
        u_before = np.zeros(u.shape)
        du, du2 = np.empty(u.shape), np.empty(u.shape)  # products of a column of A, written in place
        for i, n in zip(self.normals, self.worlds_at):
            ui = u_before[:n, i] = u[:n, i]
            d = gain[:n, i] * (ui + bias[:n, i])
            if isc_lam is not None:
                d = d - isc_lam[:n, i]
            new = np.where(valid[:n, i], np.maximum(sweep_start[:n, i] + d, 0.0), 0.0)
            change = new - sweep_start[:n, i]
            if not skip or change.any():
                u[:n] += np.multiply(A[i, :n], change[:, None], out=du[:n])
            lam[:n, i] = new
        for i, n in zip(self.normals, self.worlds_at):
            t1 = lam[:n, i + 1] - m[:n, i + 1] * u[:n, i + 1]
            t2 = lam[:n, i + 2] - m[:n, i + 2] * u[:n, i + 2]
            scale = np.where(valid[:n, i], _coulomb_scale(t1, t2, mu[:n, i] * lam[:n, i]), 0.0)
            t1, t2 = t1 * scale, t2 * scale
            c1, c2 = t1 - lam[:n, i + 1], t2 - lam[:n, i + 2]
            if not skip or c1.any() or c2.any():
                np.multiply(A[i + 1, :n], c1[:, None], out=du[:n])
                du[:n] += np.multiply(A[i + 2, :n], c2[:, None], out=du2[:n])
                u[:n] += du[:n]
            lam[:n, i + 1], lam[:n, i + 2] = t1, t2
        return u_before

    def _sweep_one_world(self, u, lam, sweep_start, gain, bias, isc_lam):
        """``_sweep_batch`` where one world holds points: the same operations in
        the same order, on Python floats (IEEE doubles rounded as numpy's
        element-wise ones, no fused multiply-adds), with only the updates of
        u by a column of A in numpy. numpy's per-call cost, paid by every
        scalar of the batch loop, made the sweeps 30% of a single world's
        step. A column is skipped when its own impulse did not change, where
        the batch skips it only if none changed: the same u, as adding an
        exact zero leaves it as it is (u holds no -0.0, A is finite). So a
        world stepped alone stays the same world in a batch bit for bit
        (``test_batch_replays_bit_for_bit``). One world has no padding: every
        column is a valid point's, so the batch's masks are left out."""
        A, u0, skip = self.A_by_column[:, 0], u[0], self.skip_unchanged
        m, mu, normals = self._one_world_constants
        lam_l, start_l = lam[0].tolist(), sweep_start[0].tolist()
        gain_l, bias_l = gain[0].tolist(), bias[0].tolist()
        isc_l = None if isc_lam is None else isc_lam[0].tolist()
        u_before = np.empty(u.shape)
        ub = u_before[0]
        for i in normals:
            ui = ub[i] = u0.item(i)
            d = gain_l[i] * (ui + bias_l[i])
            if isc_l is not None:
                d = d - isc_l[i]
            new = _max0(start_l[i] + d)
            change = new - start_l[i]
            if not skip or change != 0.0:
                u0 += A[i] * change
            lam_l[i] = new
        for i in normals:
            j, k = i + 1, i + 2
            t1 = lam_l[j] - m[j] * u0.item(j)
            t2 = lam_l[k] - m[k] * u0.item(k)
            limit = mu[i] * lam_l[i]
            mag = math.sqrt(t1 * t1 + t2 * t2)
            scale = limit / max(mag, 1e-30) if mag > limit else 1.0
            t1, t2 = t1 * scale, t2 * scale
            c1, c2 = t1 - lam_l[j], t2 - lam_l[k]
            if not skip or c1 != 0.0 or c2 != 0.0:
                u0 += A[j] * c1 + A[k] * c2
            lam_l[j], lam_l[k] = t1, t2
        lam[0] = lam_l
        return u_before

    def bounce(self, state, cr, bounce, target):
        """Restitution of the rows' points marked in ``bounce`` (rows of the
        step, P): their impulses grow (λ_n ≥ 0) until each one's separating
        speed is ``target`` (m/s), in one sweep with the coupling A."""
        on = self._normal_columns(bounce[self.rows]) > 0
        if not on.any():
            return
        goal = self._normal_columns(target[self.rows])
        u = self._velocities(state)
        lam = self._gather(cr)
        start = lam.copy()
        for i in np.flatnonzero(on.any(axis=0)):
            new = np.where(on[:, i], np.maximum(lam[:, i] - self.m[:, i] * (u[:, i] - goal[:, i]), 0.0), lam[:, i])
            u += self.A_by_column[i] * (new - lam[:, i])[:, None]
            lam[:, i] = new
        self._apply(state, lam - start)
        self._scatter(cr, lam)
