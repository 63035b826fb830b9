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
  body b with lever arm r): J_i = [d, r × d] on b. With the tree joints'
  rows J_t and the tree's metric M (masses, world inertias), the
  constrained response is Z J_iᵀ with
  Z = M⁻¹ - M⁻¹ J_tᵀ K⁻¹ J_t M⁻¹, K = J_t M⁻¹ J_tᵀ: the body part of the
  joints' KKT system [M J_tᵀ; J_t 0]⁻¹ (Baraff 1996, "Linear-time dynamics
  using Lagrange multipliers", section 7; Featherstone 2008, ch. 7's
  articulated inertia seen at a contact point), whose tree factors give it
  in one linear-time solve.
* The Delassus matrix A = J_c Z J_cᵀ (columns x columns per world) couples
  every point of every row on the articulation: projected Gauss-Seidel on
  it (``articulated_contact_sweeps`` per solve, two by default, the normal
  columns then the friction pairs, the same soft normal rows and Coulomb
  disc as ``contact_solver``), then the velocities change by Z J_cᵀ Δλ at
  once: the joints stay satisfied at velocity level, with no joint error
  for the joint solve to hand back.

The factors and A are computed once per step at the step's start
positions, as the contact rows keep their lever arms for the step. There
are three columns (normal, two friction directions) per valid contact
point, packed world by world without padding; the work (A, the sweeps, the
restitution) is done by the kernels of :mod:`engine.core.articulated`, one
world at a time, so a world stepped alone is the same world in a batch bit
for bit. Memory per held world with k columns and n tree nodes: k x (k + 8)
floats for A, J and the per-column arrays, 72 n for the factors; while A
is built, each column's walk up its path holds up to 12 n floats. A ragdoll
lying on the ground has up to about 31 valid points (k = 93).

Restitution: a point's closing speed just before it first takes load in the
step is recorded as in ``contact_solver``, and its bounce (``bounce``) raises
its separating speed to the target in the same contact space. Not covered
(these rows keep the body-by-body Gauss-Seidel): rows between two moving
bodies, articulations closed by loops. Joint limits act after the tree solve (or in it, with
``joint_limits_in_tree``) and are not in Z.
"""

from __future__ import annotations

import numpy as np

from .core import articulated as kernels


class ArticulatedContacts:
    """The rows of a step's ``ContactRows`` ``cr`` between a static body and a
    jointed body (without restitution), in contact space; ``js``: the
    model's ``JointSet`` after its ``begin_step``."""

    def __init__(self, model, state, cr, js):
        tree = js.tree
        self.empty = tree is None
        if self.empty:
            return
        W = state.num_worlds
        # The rows world by world (in row order within a world), and their
        # valid points in row then slot order: point p's columns are 3p
        # (normal), 3p + 1 and 3p + 2 (friction along t1, t2). Articulations
        # closed by loops keep the body-by-body rows: Z knows the tree rows only.
        A = cr.arrays
        rows_w, row_start, held, pt_row, slot, pt_start, a_start, factors = kernels.layout(
            cr.world_rows, cr.row_start, A.dyn_a, A.dyn_b, A.b, cr.jointed, A.valid, tree.loop_bodies)
        self.rows = rows_w
        self.empty = rows_w.size == 0
        if self.empty:
            return
        C = 3 * pt_row.size
        # The held worlds' factors of the tree at these positions (filled by the response kernel).
        n = tree.layout.order.size
        self.arrays = S = kernels.ArticulatedArrays(
            held=held, pt_start=pt_start, pt_row=pt_row, pt_slot=slot, row_start=row_start,
            rows=rows_w, tree_bodies=tree.t.bodies, node=tree.body_node, order=tree.layout.order,
            parent=tree.layout.parent, factors=factors, Dinv=np.empty((held.size, n, 6, 6)),
            L=np.empty((held.size, n, 6, 6)), M=np.ascontiguousarray(tree.M), body=np.empty(C, dtype=np.int64),
            J=np.empty((C, 6)), A=np.empty(int(a_start[-1])), a_start=a_start, m=np.empty(C),
            mu=np.empty(pt_row.size), finite=np.ones(W, dtype=bool))
        self.sweeps = int(model.settings.articulated_contact_sweeps)
        self.contact_view = kernels.ContactView(*(getattr(cr.arrays, f) for f in kernels.ContactView._fields))
        g = js.geometry(state)
        kernels.response(cr.arrays, S, tree.arrays, tree.layout, g.fpw, g.ra, g.rb, state.joint_broken,
                         np.ascontiguousarray(tree.M_inv))

    # ------------------------------------------------------------------ views
    def delassus(self, w):
        """World w's Delassus matrix A = J_c Z (k, k)."""
        S = self.arrays
        k = 3 * int(S.pt_start[w + 1] - S.pt_start[w])
        return S.A[S.a_start[w]:S.a_start[w + 1]].reshape(k, k).T

    def response(self, w):
        """World w's constrained responses Z J_iᵀ of its columns (k, N, 6):
        each body's (v, ω) change per N s of impulse on column i (m/s,
        rad/s), from the solve that applies the impulses."""
        S = self.arrays
        cols = self.columns(w)
        k, N = cols.stop - cols.start, S.node.size
        out = np.zeros((k, N, 6))
        for i in range(k):
            unit = np.zeros(k)
            unit[i] = 1.0
            kernels._apply_world(S, w, unit, out[i, :, :3], out[i, :, 3:], np.empty((S.order.size, 6)))
        return out

    def columns(self, w):
        """The slice of world w's columns in the packed arrays (Z, J, body, m)."""
        S = self.arrays
        return slice(3 * int(S.pt_start[w]), 3 * int(S.pt_start[w + 1]))

    def velocities(self, state):
        """Column velocities (C,) J_c P v after the joint solve that follows:
        P v = v - M⁻¹J_tᵀK⁻¹J_t v, the velocities projected onto the tree
        joints' rows (exact for the relax solve's unbiased rows; the limit
        rows and the bias are not in P). Read
        unprojected (J_c v), the columns saw a foot turned freely by its
        ankle motor within the substep, which the joint solve then takes
        back: the standing PD's feet spun at up to 125 rad/s in one of 20
        Balance worlds without pushes (rigid joints, ``CLOSED_JOINTS``).
        Columns of worlds without a point: none."""
        u = np.zeros(self.arrays.m.size)
        kernels.column_velocities(self.arrays, state.velocity, state.angular_velocity, u)
        return u

    # ------------------------------------------------------------------ steps
    def warm_start(self, state, cr):
        """Velocities += Z J_cᵀ λ of the rows' stored impulses."""
        kernels.warm_start(self.contact_view, self.arrays, state.velocity, state.angular_velocity)

    def solve(self, state, cr, h, use_bias):
        """``Settings.articulated_contact_sweeps`` projected Gauss-Seidel sweeps
        over the columns (``contact_solver``'s per-point rules with the
        effective masses 1 / A_ii), then Z J_cᵀ Δλ."""
        kernels.solve(self.contact_view, self.arrays, state.position, state.orientation, state.velocity,
                      state.angular_velocity, self.params(cr, h), bool(use_bias))

    def params(self, cr, h):
        """The solve's constants (``engine.core.articulated.SoftParams``) for substeps of h s."""
        soft = cr.soft
        return kernels.SoftParams(h=float(h), bias_rate=float(soft.bias_rate), mass_scale=float(soft.mass_scale),
                                  impulse_scale=float(soft.impulse_scale), slop=float(cr.slop),
                                  max_push_out=float(cr.max_push_out), thesis=bool(cr.thesis), sweeps=self.sweeps)

    def bounce(self, state, cr, bounce, target):
        """Restitution of the rows' points marked in ``bounce`` (rows of the
        step, P): their impulses grow (λ_n ≥ 0) until each one's separating
        speed is ``target`` (m/s), in one sweep with the coupling A."""
        kernels.bounce(self.contact_view, self.arrays, state.velocity, state.angular_velocity,
                       np.ascontiguousarray(bounce, dtype=bool), np.ascontiguousarray(target, dtype=np.float64))
