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

Here the rows of a step are prepared (lever arms, effective masses, friction
coefficients, the sweep order); the sweeps, the warm start and the impacts
are the kernels of :mod:`engine.core.contacts`, which take each world's rows
colour by colour (no body twice in a colour; the colouring:
``Settings.contact_coloring``), the 4 points of a row in sequence: the normal
points (twice, ``NORMAL_PASSES``, in a row between two moving bodies), then
the friction points once.
"""

from __future__ import annotations

import numpy as np

from .coloring import color_rows
from .core import contacts as kernels
from .math3d import dot
from .soft import make_soft

STICK_SPEED = 0.01  # m/s: below it a contact point uses static friction
CONTACT_HERTZ_CAP = 0.25  # contact stiffness at most this fraction of the substep rate (Box2D v3)


def _top_down_priority(point, valid, gravity):
    """Rows ranked by the mean height of their valid points against gravity,
    highest first (ties and no gravity: row order). Swept top down, a pile's
    weight reaches the rows under it within the sweep: with first-fit
    colours bottom up, a 100 kg box on a 1 kg box still moved at up to
    6.5 cm/s after 1 s (top down: 0.4 cm/s)."""
    mean = np.where(valid[..., None], point, 0.0).sum(axis=1) / np.maximum(valid.sum(axis=1), 1)[:, None]
    height = -(mean @ gravity)
    return np.argsort(np.argsort(-height, kind="stable"), kind="stable")


class ContactRows:
    """The contact rows of one step, with their impulses."""

    def __init__(self, model, state, contacts, w, p, a, b, normal, point, sep, valid, lam_n, lam_t, h):
        s = contacts.settings
        N = model.num_bodies
        self.w, self.p, self.a, self.b = w, p, a, b
        self.ka, self.kb = w * N + a, w * N + b  # flat (world, body) keys, for the colouring
        self.dyn_a, self.dyn_b = model.dynamic[a], model.dynamic[b]
        self.inv_ma, self.inv_mb = model.inv_mass[a], model.inv_mass[b]
        R = len(w)
        self.valid = valid
        self.h = h
        held = contacts.jointed & model.dynamic
        self.jointed = held[a] | held[b]  # rows touching a body held by a joint
        self.e = contacts.restitution[p]
        empty3, empty4 = (lambda: np.empty((R, 3))), (lambda: np.empty((R, 4)))
        # The step-constant fields are filled by the prepare kernel below.
        self.arrays = kernels.ContactRowArrays(
            w=w, a=a, b=b, dyn_a=self.dyn_a, dyn_b=self.dyn_b, free=~self.jointed,
            inv_ma=self.inv_ma, inv_mb=self.inv_mb, n=normal, t1=empty3(), t2=empty3(), valid=valid,
            xa0=empty3(), xb0=empty3(), ra=np.empty((R, 4, 3)), rb=np.empty((R, 4, 3)),
            la=np.empty((R, 4, 3)), lb=np.empty((R, 4, 3)), sep0=np.array(sep, dtype=float),
            ia=np.empty((R, 3, 3)), ib=np.empty((R, 3, 3)), mn=empty4(), mt1=empty4(), mt2=empty4(), mu=empty4(),
            e=self.e, lam_n=lam_n, lam_t1=empty4(), lam_t2=empty4(), max_lam_n=np.zeros((R, 4)),
            s_close=np.zeros((R, 4)), vn_close=empty4())
        kernels.prepare(self.arrays, p, point, lam_t, state.position, state.orientation, state.velocity,
                        state.angular_velocity, model.inv_inertia, contacts.mu_static, contacts.mu_kinetic,
                        STICK_SPEED)
        A = self.arrays
        self.n, self.t1, self.t2 = A.n, A.t1, A.t2
        self.xa0, self.xb0, self.ra, self.rb, self.la, self.lb = A.xa0, A.xb0, A.ra, A.rb, A.la, A.lb
        self.sep0, self.ia, self.ib = A.sep0, A.ia, A.ib
        self.mn, self.mt1, self.mt2, self.mu = A.mn, A.mt1, A.mt2, A.mu
        self.bouncy = bool((self.e > 0).any())
        self.threshold = s.restitution_threshold
        self.lam_n, self.lam_t1, self.lam_t2, self.max_lam_n = A.lam_n, A.lam_t1, A.lam_t2, A.max_lam_n
        self.lam_n_start = lam_n.copy()
        # Σ of earlier substeps' λ (each substep applies its λ once): the
        # impulses of the step, taken back by an impact (restitution).
        self.lam_n_step = np.zeros(lam_n.shape)
        self.lam_t1_step = np.zeros(lam_n.shape)
        self.lam_t2_step = np.zeros(lam_n.shape)
        self.warm_starts = 0
        self.vn_close, self.s_close = A.vn_close, A.s_close
        # Relative normal acceleration from uniform gravity (negative: closing).
        g = model.gravity if "gravity" in model.effects else np.zeros(3)
        self.gravity_n = dot(normal, g) * (self.dyn_b.astype(float) - self.dyn_a.astype(float))
        hertz = min(s.contact_hertz, CONTACT_HERTZ_CAP / h)
        self.soft = make_soft(hertz, s.contact_damping_ratio, h)
        self.thesis = s.solver == "thesis"
        self.max_push_out = s.max_push_out
        self.slop = s.linear_slop
        # Only with a relax solve to take back the stiffer bias's velocity: without one the
        # 10-box stack of benchmarks.accuracy sank 0.4 m (2.1 mm with the plain spring).
        self.load_stiffening = s.contact_load_stiffening if s.relax_iterations > 0 else 1.0
        self.g_mag = float(np.linalg.norm(g))
        if s.contact_coloring == "greedy":
            priority, first_fit = _top_down_priority(point, valid, g), True
        else:
            priority, first_fit = np.arange(w.size), False
        self.colors = color_rows(self.ka, self.kb, self.dyn_a, self.dyn_b, state.num_worlds * N, priority, first_fit)
        self.num_worlds = state.num_worlds
        self.articulated = None  # ArticulatedContacts of this step's rows on articulations, if attached
        self._order()

    # ------------------------------------------------------------------------
    def _order(self):
        """The sweep order: rows by world, then colour, then row index (rows of
        one colour share no body, so a world's colours in turn give what a
        simultaneous sweep of each colour gives); ``world_start`` (W + 1,)."""
        color = np.full(self.w.size, -1, dtype=np.int64)
        for k, rows in enumerate(self.colors):
            color[rows] = k
        swept = np.flatnonzero(color >= 0)
        self.order = swept[np.lexsort((swept, color[swept], self.w[swept]))]
        self.world_start = np.searchsorted(self.w[self.order], np.arange(self.num_worlds + 1))

    def _params(self, h):
        return kernels.SolverParams(
            h=float(h), bias_rate=float(self.soft.bias_rate), mass_scale=float(self.soft.mass_scale),
            impulse_scale=float(self.soft.impulse_scale), max_push_out=float(self.max_push_out),
            slop=float(self.slop), load_cap=float(self.load_stiffening), g_mag=self.g_mag,
            bouncy=self.bouncy, thesis=self.thesis)

    def warm_start(self, model, state):
        if self.warm_starts and self.bouncy:  # only restitution takes them back
            self.lam_n_step += self.lam_n
            self.lam_t1_step += self.lam_t1
            self.lam_t2_step += self.lam_t2
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
        taken = np.zeros(self.w.size, dtype=bool)
        taken[articulated.rows] = True
        self.colors = [r for r in (rows[~taken[rows]] for rows in self.colors) if r.size]
        self._order()

    def restitution(self, model, state):
        """Bounce once per step: sequential impacts from the closing speeds."""
        # The speculative row took load while the gap s_c was still open; under
        # uniform gravity the speed at touch-down follows from energy:
        # v_impact² = v_c² + 2 |a_n| s_c (a_n: relative normal acceleration).
        closing_acc = np.maximum(-self.gravity_n, 0.0)[:, None]
        v_imp = -np.sqrt(self.vn_close ** 2 + 2.0 * closing_acc * np.maximum(self.s_close, 0.0))
        v_imp = np.where(self.vn_close < 0, v_imp, self.vn_close)
        loaded = (self.max_lam_n > 0) & self.valid
        e = self.e[:, None]
        bounce = (v_imp < -self.threshold) & loaded & (e > 0)
        if not bounce.any():
            return
        # Semi-implicit Euler's velocity is staggered half a substep from its
        # position, so a free flight under a_n returns to the surface |a_n|·h
        # slower than it left (its invariant is ½v² - a_n x - ½ a_n h v). The
        # first bounce gets that kick back, so the next impact is e·v_i.
        first_target = np.where(bounce, -e * v_imp + closing_acc * self.h, 0.0)
        held = bounce & self.jointed[:, None]
        if held.any():
            kernels.bounce_in_place(self.arrays, self.order, self.world_start, state.velocity,
                                    state.angular_velocity, held, first_target)
            if self.articulated is not None:
                self.articulated.bounce(state, self, held, first_target)
        free = bounce.any(axis=1) & ~self.jointed
        if free.any():
            # The points that took load only in this step give back every
            # substep's impulse (Σ of the earlier substeps' λ and the last λ).
            kernels.impacts(self.arrays, self.order, self.world_start, state.velocity, state.angular_velocity,
                            free, loaded & ~self.jointed[:, None], bounce, first_target,
                            self.lam_n_step + self.lam_n, self.lam_t1_step + self.lam_t1,
                            self.lam_t2_step + self.lam_t2, self.lam_n_start, float(self.threshold))

    def project_positions(self, model, state):
        """The thesis's penetration resolution: move both bodies apart along the
        normal by the penetration depth, split by inverse mass."""
        rows = np.arange(self.w.size)
        sep = np.where(self.valid, self.separation_of(state, rows), np.inf).min(axis=1)
        depth = np.maximum(-(sep + self.slop), 0.0)
        total = np.maximum(self.inv_ma + self.inv_mb, 1e-30)
        pos = state.position.reshape(-1, 3)
        np.add.at(pos, self.ka, -(depth * self.inv_ma / total)[:, None] * self.n)
        np.add.at(pos, self.kb, (depth * self.inv_mb / total)[:, None] * self.n)

    def store(self, state):
        """Keep the impulses for next step's warm start."""
        state.contact_normal_impulse[self.w, self.p] = self.lam_n
        state.contact_friction_impulse[self.w, self.p] = (self.lam_t1[..., None] * self.t1[:, None]
                                                          + self.lam_t2[..., None] * self.t2[:, None])
