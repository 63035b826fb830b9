"""Contact rows in the soft-step solver (after Box2D v3 ``src/contact_solver.c``).

One row is one (world, pair) manifold of up to 4 points sharing a normal n
(from body a to body b). Per point, with lever arms r_a, r_b from the body
centres (fixed for the step) and relative velocity v_rel = (v_b + ω_b × r_b)
- (v_a + ω_a × r_a):

* normal: effective mass m_n = 1 / (1/m_a + 1/m_b + (r_a×n)·I_a⁻¹(r_a×n) +
  (r_b×n)·I_b⁻¹(r_b×n)); current separation s = s₀ + n·(Δ(x_b + r_b) -
  Δ(x_a + r_a)) recomputed each substep from the bodies' displacement, so the
  narrow phase runs once per step. While open (s > 0) the row is speculative:
  bias s/h, rigid; when penetrating, the biased solve uses the contact
  softness (stiffness min(contact_hertz, substep rate / 4), Box2D v3) with the
  push-out speed capped at ``max_push_out``; the relax solve is rigid with no
  bias. The accumulated impulse λ_n ≥ 0.
* friction: two tangent rows, rigid, with the accumulated tangent impulse
  clamped to the disc |λ_t| ≤ μ λ_n (Coulomb). μ is the static coefficient
  for a point that was sticking at the start of the step (tangential speed
  under ``STICK_SPEED``) and the kinetic coefficient for one that was sliding.
* restitution: once per step after the substeps, as a sequence of impacts
  (the sequential-collision model of Guendelman, Bridson & Fedkiw 2003, which
  passes a Newton's cradle's momentum down the row; a simultaneous solve
  spreads it over all balls). Among free bodies, in the rows an impact can
  reach, the normal and friction impulses this step put on points that were
  not loaded at its start are taken off again, restoring the velocities
  before the impact; then a few sweeps over the colours give every
  approaching row one impact: its points' separating speeds become e times
  their closing speeds, solved together within the row (a box landing flat
  bounces without spin). Bodies held by joints are left to the joint solve:
  their impact was solved with the joints, and their bouncing points only
  get the impulse that raises their separating speed to the target. A
  point's first impact uses its closing speed just before it first took load
  in the step (Box2D takes it at the step start; within a step gravity adds
  up to g·dt to the closing speed, which would cost ~7% of each bounce
  height at 60 Hz), taken at the start of the row's sweep so all points of a
  face share it.

With ``Settings.articulated_contacts`` the rows between a static body and
jointed bodies leave the colours and are solved with the articulation's
response instead (``articulated_contacts``; ``ContactRows.attach``).

Here a step's rows are held and handed to the kernels of
:mod:`engine.core.contacts`: the gather of the rows from the detection, their
preparation (lever arms, effective masses, friction coefficients), the
colouring and sweep order, the warm start, the sweeps, restitution's
targets and impacts, the thesis's position projection and the store of the
impulses. The sweeps take each world's rows colour by colour (no body twice
in a colour; the colouring: ``Settings.contact_coloring``), the 4 points of
a row in sequence: the normal points (twice, ``NORMAL_PASSES``, in a row
between two moving bodies), then the friction points once.
"""

from __future__ import annotations

import numpy as np

from .core import contacts as kernels
from .core import world
from .core.world import contact_row_arrays
from .soft import make_soft

STICK_SPEED = 0.01  # m/s: below it a contact point uses static friction
CONTACT_HERTZ_CAP = 0.25  # contact stiffness at most this fraction of the substep rate (Box2D v3)


class ContactRows:
    """The contact rows of one step, with their impulses: the (world, pair)
    rows of ``keep`` (W, P) (R of them) from the detection's manifolds
    ``normal``, ``point``, ``sep``, ``valid`` (rows w P + p)."""

    def __init__(self, model, state, contacts, keep, normal, point, sep, valid, R, h):
        s = contacts.settings
        N = model.num_bodies
        W = state.num_worlds
        point_r, lam_t = np.empty((R, 4, 3)), np.empty((R, 4, 3))
        self.p = np.empty(R, dtype=np.int64)
        self.jointed = np.empty(R, dtype=bool)  # rows touching a body held by a joint
        self.gravity_n = np.empty(R)  # m/s², relative normal acceleration from uniform gravity (negative: closing)
        # The gather fills the manifold's and the model's fields, the prepare
        # kernel the step-constant ones.
        self.arrays = A = contact_row_arrays(R)
        self.bouncy = kernels.gather(keep, normal, point, sep, valid, state.contact_normal_impulse,
                                     state.contact_friction_impulse, contacts.pair_a, contacts.pair_b, model.dynamic,
                                     model.inv_mass, contacts.held, contacts.restitution, contacts.gravity, A, self.p,
                                     point_r, lam_t, self.jointed, self.gravity_n)
        kernels.prepare(A, self.p, point_r, lam_t, state.position, state.orientation, state.velocity,
                        state.angular_velocity, model.inv_inertia, contacts.mu_static, contacts.mu_kinetic,
                        STICK_SPEED)
        self.w, self.a, self.b = A.w, A.a, A.b
        self.dyn_a, self.dyn_b, self.inv_ma, self.inv_mb = A.dyn_a, A.dyn_b, A.inv_ma, A.inv_mb
        self.valid, self.e = A.valid, A.e
        self.h = h
        self.n, self.t1, self.t2 = A.n, A.t1, A.t2
        self.xa0, self.xb0, self.ra, self.rb, self.la, self.lb = A.xa0, A.xb0, A.ra, A.rb, A.la, A.lb
        self.sep0, self.ia, self.ib = A.sep0, A.ia, A.ib
        self.mn, self.mt1, self.mt2, self.mu = A.mn, A.mt1, A.mt2, A.mu
        self.threshold = s.restitution_threshold
        self.lam_n, self.lam_t1, self.lam_t2, self.max_lam_n = A.lam_n, A.lam_t1, A.lam_t2, A.max_lam_n
        self.vn_close, self.s_close = A.vn_close, A.s_close
        if self.bouncy:
            # The step's start impulses, and Σ of earlier substeps' λ (each
            # substep applies its λ once): the impulses of the step, taken
            # back by an impact (restitution).
            self.lam_n_start = A.lam_n.copy()
            self.lam_n_step = np.zeros((R, 4))
            self.lam_t1_step = np.zeros((R, 4))
            self.lam_t2_step = np.zeros((R, 4))
        self.warm_starts = 0
        hertz = min(s.contact_hertz, CONTACT_HERTZ_CAP / h)
        self.soft = make_soft(hertz, s.contact_damping_ratio, h)
        self.thesis = s.solver == "thesis"
        self.max_push_out = s.max_push_out
        self.slop = s.linear_slop
        # Only with a relax solve to take back the stiffer bias's velocity: without one the
        # 10-box stack of benchmarks.accuracy sank 0.4 m (2.1 mm with the plain spring).
        self.load_stiffening = s.contact_load_stiffening if s.relax_iterations > 0 else 1.0
        self.g_mag = contacts.g_mag
        self.num_worlds = W
        # Colours world by world ("greedy": top down, first fit; "ordered": in
        # row order, a Gauss-Seidel sweep in row order), then the sweep order.
        self.color = np.empty(R, dtype=np.int64)
        self.world_rows, self.row_start = kernels.color_rows(A, W, N, point_r, contacts.gravity,
                                                             s.contact_coloring == "greedy", self.color)
        self.order, self.world_start = kernels.sweep_order(A.w, self.color, W)
        self.articulated = None  # ArticulatedContacts of this step's rows on articulations, if attached
        self._p = self._params(h)

    # ------------------------------------------------------------------------
    @property
    def colors(self):
        """The swept rows by colour (index arrays, rows ascending, colours
        that hold a row), across worlds."""
        swept = np.flatnonzero(self.color >= 0)
        by = swept[np.argsort(self.color[swept], kind="stable")]
        bounds = np.flatnonzero(np.diff(self.color[by])) + 1
        return np.split(by, bounds) if by.size else []

    def _params(self, h):
        if getattr(self, "_p", None) is not None and self._p.h == h:
            return self._p
        return kernels.SolverParams(
            h=float(h), bias_rate=float(self.soft.bias_rate), mass_scale=float(self.soft.mass_scale),
            impulse_scale=float(self.soft.impulse_scale), max_push_out=float(self.max_push_out),
            slop=float(self.slop), load_cap=float(self.load_stiffening), g_mag=self.g_mag,
            bouncy=self.bouncy, thesis=self.thesis)

    def warm_start(self, model, state):
        if self.warm_starts and self.bouncy:  # only restitution takes them back
            kernels.add_step_impulses(self.arrays, self.lam_n_step, self.lam_t1_step, self.lam_t2_step)
        self.warm_starts += 1
        if self.articulated is not None:
            self.articulated.warm_start(state, self)
        kernels.warm_start(self.arrays, self.order, self.world_start, state.velocity, state.angular_velocity)

    def separation_of(self, state, rows):
        """Current separations (len(rows), 4) in m of ``rows``, from the bodies'
        displacement this step."""
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        out = np.empty((rows.size, self.valid.shape[1]))
        kernels.separations(self.arrays, rows, state.position, state.orientation, out)
        return out

    def separation(self, state):
        """Current separation (rows, points) of every row, m."""
        return self.separation_of(state, np.arange(self.w.size))

    def solve(self, model, state, h, use_bias, only_free=False):
        """One Gauss-Seidel sweep over the rows (``only_free``: those whose
        bodies carry no joint), then the articulated rows' solve."""
        kernels.solve(self.arrays, self.order, self.world_start, state.position, state.orientation,
                      state.velocity, state.angular_velocity, self._params(h), bool(use_bias), bool(only_free))
        if not only_free and self.articulated is not None:
            self.articulated.solve(state, self, h, use_bias)

    def attach(self, articulated):
        """Hand the rows of ``articulated`` (an ``ArticulatedContacts``) to it:
        they leave the sweep, and the warm start and every sweep end with
        its contact-space solve."""
        if articulated.empty:
            return
        self.articulated = articulated
        self.color[articulated.rows] = -1
        self.order, self.world_start = kernels.sweep_order(self.w, self.color, self.num_worlds)

    def substep_arrays(self, h):
        """The rows' arguments of the compiled substeps: (ContactStep,
        ContactRowArrays, ArticulatedArrays, SolverParams, SoftParams)
        (``engine.core.world``)."""
        ar = self.articulated
        if ar is None:
            S, ap = world.no_columns()
        else:
            S, ap = ar.arrays, ar.params(self, h)
        steps = (self.lam_n_step, self.lam_t1_step, self.lam_t2_step) if self.bouncy else (np.zeros((0, 4)),) * 3
        C = world.ContactStep(on=True, order=self.order, world_start=self.world_start, world_rows=self.world_rows,
                              row_start=self.row_start, bouncy=bool(self.bouncy), lam_n_step=steps[0],
                              lam_t1_step=steps[1], lam_t2_step=steps[2], articulated=ar is not None)
        return C, self.arrays, S, self._params(h), ap

    def restitution(self, model, state):
        """Bounce once per step: sequential impacts from the closing speeds
        (``engine.core.contacts.restitution_targets``)."""
        if not self.bouncy:
            return  # no row with restitution
        R = self.w.size
        loaded, bounce, held, loaded_free = (np.empty((R, 4), dtype=bool) for _ in range(4))
        first_target, undo_n, undo_t1, undo_t2 = (np.empty((R, 4)) for _ in range(4))
        free = np.empty(R, dtype=bool)
        any_bounce, any_held, any_free = kernels.restitution_targets(
            self.arrays, self.gravity_n, self.jointed, float(self.threshold), float(self.h), self.lam_n_step,
            self.lam_t1_step, self.lam_t2_step, loaded, bounce, first_target, held, free, loaded_free, undo_n,
            undo_t1, undo_t2)
        if not any_bounce:
            return
        if any_held:
            kernels.bounce_in_place(self.arrays, self.order, self.world_start, state.velocity,
                                    state.angular_velocity, held, first_target)
            if self.articulated is not None:
                self.articulated.bounce(state, self, held, first_target)
        if any_free:
            # The points that took load only in this step give back every
            # substep's impulse (Σ of the earlier substeps' λ and the last λ).
            kernels.impacts(self.arrays, self.order, self.world_start, state.velocity, state.angular_velocity,
                            free, loaded_free, bounce, first_target, undo_n, undo_t1, undo_t2, self.lam_n_start,
                            float(self.threshold))

    def project_positions(self, model, state):
        """The thesis's penetration resolution: move both bodies apart along the
        normal by the penetration depth, split by inverse mass."""
        kernels.project_positions(self.arrays, self.world_rows, self.row_start, float(self.slop), state.position,
                                  state.orientation)

    def store(self, state):
        """Keep the impulses for next step's warm start."""
        kernels.store(self.arrays, self.p, state.contact_normal_impulse, state.contact_friction_impulse)
