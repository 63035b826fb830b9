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

Rows are swept colour by colour (no (world, body) twice in a colour; the
colouring: ``Settings.contact_coloring``), the 4 points of a row in
sequence: the normal points (twice, ``NORMAL_PASSES``, in a row between two
moving bodies), then the friction points once.
"""

from __future__ import annotations

import numpy as np

from .coloring import color_rows
from .math3d import cross, dot, mat_vec, normalize, quat_rotate, quat_rotate_inv, world_inv_inertia
from .soft import make_soft

STICK_SPEED = 0.01  # m/s: below it a contact point uses static friction
IMPACT_SWEEPS = 16  # at most this many sweeps of impacts (a row of n balls needs about n/2)
IMPACT_POINT_PASSES = 32  # at most this many passes over the points of a row in one impact
IMPACT_PASS_TOLERANCE = 1e-6  # stop the passes when no λ changed by more than this fraction of the largest
IMPACT_TOLERANCE = 1e-9  # m/s: a loaded point closing faster than this takes an impact
CONTACT_HERTZ_CAP = 0.25  # contact stiffness at most this fraction of the substep rate (Box2D v3)
NORMAL_PASSES = 2  # Gauss-Seidel passes over the normal points of a row between moving bodies (see solve)


def _coulomb_scale(t1, t2, limit):
    """Factor that brings the tangent impulse (t1, t2) into the disc |λ_t| <= limit."""
    mag = np.sqrt(t1 * t1 + t2 * t2)
    return np.where(mag > limit, limit / np.maximum(mag, 1e-30), 1.0)


def _tangents(n):
    """Two unit tangents (K, 3) perpendicular to the unit normals n."""
    helper = np.where((np.abs(n[:, 0]) < 0.57)[:, None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    t1 = normalize(cross(n, helper))
    return t1, cross(n, t1)


def _top_down_priority(point, valid, gravity):
    """Rows ranked by the mean height of their valid points against gravity,
    highest first (ties and no gravity: row order). Swept top down, a pile's
    weight reaches the rows under it within the sweep: with first-fit
    colours bottom up, a 100 kg box on a 1 kg box still moved at up to
    6.5 cm/s after 1 s (top down: 0.4 cm/s)."""
    mean = np.where(valid[..., None], point, 0.0).sum(axis=1) / np.maximum(valid.sum(axis=1), 1)[:, None]
    height = -(mean @ gravity)
    return np.argsort(np.argsort(-height, kind="stable"), kind="stable")


class _Block:
    """The step-constant data of a set of rows (one colour), gathered once:
    lever arms (R, P, 3), world inverse inertias (R, 3, 3), inverse masses
    (R, 1), normal and tangents (R, 3), effective masses and friction
    coefficients (R, P), validity; views of these replace a gather per point
    and pass in the sweeps."""

    def __init__(self, cr, rows):
        self.rows = rows  # held, so that id(rows), the cache key, is not reused within the step
        self.ra, self.rb = cr.ra[rows], cr.rb[rows]
        self.ia, self.ib = cr.ia[rows, 0], cr.ib[rows, 0]
        self.inv_ma, self.inv_mb = cr.inv_ma[rows][:, None], cr.inv_mb[rows][:, None]
        self.n, self.t1, self.t2 = cr.n[rows], cr.t1[rows], cr.t2[rows]
        self.mn, self.mt1, self.mt2, self.mu = cr.mn[rows], cr.mt1[rows], cr.mt2[rows], cr.mu[rows]
        self.valid = cr.valid[rows]
        self.paired = cr.dyn_a[rows] & cr.dyn_b[rows]
        self.free = ~cr.jointed[rows]  # rows whose bodies carry no joint
        self.any_free = bool(self.free.any())
        self.ka, self.kb = cr.ka[rows], cr.kb[rows]
        self.dyn_a, self.dyn_b = cr.dyn_a[rows], cr.dyn_b[rows]
        # For the current separation: body-local lever arms, start positions and separations.
        self.la, self.lb = cr.la[rows], cr.lb[rows]
        self.xa0, self.xb0 = cr.xa0[rows], cr.xb0[rows]
        self.sep0 = cr.sep0[rows]


def _separation(state, c):
    """Current separation (R, 4) of the rows of block ``c`` from their bodies'
    displacement this step: s₀ + n·(Δ(x_b + r_b) - Δ(x_a + r_a))."""
    pa = state.position.reshape(-1, 3).take(c.ka, 0)
    pb = state.position.reshape(-1, 3).take(c.kb, 0)
    qa = state.orientation.reshape(-1, 4).take(c.ka, 0)
    qb = state.orientation.reshape(-1, 4).take(c.kb, 0)
    ra = quat_rotate(qa[:, None], c.la)
    rb = quat_rotate(qb[:, None], c.lb)
    d = (pb - c.xb0)[:, None] + rb - c.rb - (pa - c.xa0)[:, None] - ra + c.ra
    return c.sep0 + dot(d, c.n[:, None])


class ContactRows:
    """The contact rows of one step, with their impulses."""

    def __init__(self, model, state, contacts, w, p, a, b, normal, point, sep, valid, lam_n, lam_t, h):
        s = contacts.settings
        N = model.num_bodies
        self.w, self.p, self.a, self.b = w, p, a, b
        self.ka, self.kb = w * N + a, w * N + b
        self.dyn_a, self.dyn_b = model.dynamic[a], model.dynamic[b]
        # Rows whose body a is static (ground contacts) get exact zero changes
        # on that side, and _scatter writes back only dynamic bodies.
        self.a_moves = bool(self.dyn_a.any())
        self.inv_ma, self.inv_mb = model.inv_mass[a], model.inv_mass[b]
        self.n = normal
        self.t1, self.t2 = _tangents(normal)
        self.valid = valid
        self.h = h
        xa, xb = state.position[w, a], state.position[w, b]
        qa, qb = state.orientation[w, a], state.orientation[w, b]
        self.xa0, self.xb0 = xa, xb
        ra = point - xa[:, None]
        rb = point - xb[:, None]
        self.ra, self.rb = ra, rb
        self.la = quat_rotate_inv(qa[:, None], ra)  # body-local lever arms
        self.lb = quat_rotate_inv(qb[:, None], rb)
        self.sep0 = np.where(valid, sep, 0.0)
        # World inverse inertias (step start), as in Box2D's prepare stage.
        self.ia = world_inv_inertia(qa, model.inv_inertia[a])[:, None]
        self.ib = world_inv_inertia(qb, model.inv_inertia[b])[:, None]
        base = (self.inv_ma + self.inv_mb)[:, None]
        nn = normal[:, None]

        def eff_mass(d):
            ran, rbn = cross(ra, d), cross(rb, d)
            k = base + dot(ran, mat_vec(self.ia, ran)) + dot(rbn, mat_vec(self.ib, rbn))
            return np.where(valid, 1.0 / np.maximum(k, 1e-30), 0.0)

        self.mn = eff_mass(nn)
        self.mt1 = eff_mass(self.t1[:, None])
        self.mt2 = eff_mass(self.t2[:, None])
        va, vb = state.velocity[w, a], state.velocity[w, b]
        wa, wb = state.angular_velocity[w, a], state.angular_velocity[w, b]
        vrel = vb[:, None] + cross(wb[:, None], rb) - va[:, None] - cross(wa[:, None], ra)
        self.vn0 = dot(vrel, nn)
        vt = vrel - self.vn0[..., None] * nn
        sticking = dot(vt, vt) < STICK_SPEED ** 2
        self.mu = np.where(sticking, contacts.mu_static[p][:, None], contacts.mu_kinetic[p][:, None])
        self.e = contacts.restitution[p]
        self.bouncy = bool((self.e > 0).any())
        held = contacts.jointed & model.dynamic
        self.jointed = held[a] | held[b]  # rows touching a body held by a joint
        self.threshold = s.restitution_threshold
        self.lam_n = lam_n
        self.lam_t1 = dot(lam_t, self.t1[:, None])
        self.lam_t2 = dot(lam_t, self.t2[:, None])
        self.max_lam_n = np.zeros(lam_n.shape)
        self.lam_n_start = lam_n.copy()
        # Σ of earlier substeps' λ (each substep applies its λ once): the
        # impulses of the step, taken back by an impact (restitution).
        self.lam_n_step = np.zeros(lam_n.shape)
        self.lam_t1_step = np.zeros(lam_n.shape)
        self.lam_t2_step = np.zeros(lam_n.shape)
        self.warm_starts = 0
        self.lam_n_store = None  # λ_n to warm-start the next step with (set by restitution)
        self.vn_close = self.vn0.copy()
        self.s_close = np.zeros(self.vn0.shape)
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
        self._free_colors = None
        self.articulated = None  # ArticulatedContacts of this step's rows on articulations, if attached
        self._blocks = {}  # id(rows) -> _Block of the colours (and free colours) of this step

    # ------------------------------------------------------------------------
    def _block(self, rows, cache=True):
        """The ``_Block`` of ``rows``: cached for the step's colours."""
        if not cache:
            return _Block(self, rows)
        block = self._blocks.get(id(rows))
        if block is None:
            block = self._blocks[id(rows)] = _Block(self, rows)
        return block

    def _gather(self, state, c):
        v = state.velocity.reshape(-1, 3)
        w = state.angular_velocity.reshape(-1, 3)
        return v.take(c.ka, 0), w.take(c.ka, 0), v.take(c.kb, 0), w.take(c.kb, 0)

    def _scatter(self, state, c, va, wa, vb, wb):
        v = state.velocity.reshape(-1, 3)
        w = state.angular_velocity.reshape(-1, 3)
        da, db = c.dyn_a, c.dyn_b
        v[c.ka[da]], w[c.ka[da]] = va[da], wa[da]
        v[c.kb[db]], w[c.kb[db]] = vb[db], wb[db]

    def _apply(self, c, j, P, va, wa, vb, wb):
        """Impulse P (R, 3) at point j of the rows of block c: -P on a, +P on b."""
        if self.a_moves:
            va = va - P * c.inv_ma
            wa = wa - mat_vec(c.ia, cross(c.ra[:, j], P))
        vb = vb + P * c.inv_mb
        wb = wb + mat_vec(c.ib, cross(c.rb[:, j], P))
        return va, wa, vb, wb

    def warm_start(self, model, state):
        if self.warm_starts and self.bouncy:  # only restitution takes them back
            self.lam_n_step += self.lam_n
            self.lam_t1_step += self.lam_t1
            self.lam_t2_step += self.lam_t2
        self.warm_starts += 1
        lam = self.lam_n[..., None] * self.n[:, None] + self.lam_t1[..., None] * self.t1[:, None] \
            + self.lam_t2[..., None] * self.t2[:, None]
        if self.articulated is not None:
            self.articulated.warm_start(state, self)
        if not lam.any():
            return
        for rows in self.colors:
            c = self._block(rows)
            va, wa, vb, wb = self._gather(state, c)
            lam_c = lam[rows]
            for j in range(self.valid.shape[1]):
                va, wa, vb, wb = self._apply(c, j, lam_c[:, j], va, wa, vb, wb)
            self._scatter(state, c, va, wa, vb, wb)

    def _separation(self, state, rows):
        """Current separation (R, 4) from the bodies' displacement this step."""
        return _separation(state, self._block(rows, cache=False))

    def separation(self, state):
        """Current separation (rows, points) of every row, m."""
        return self._separation(state, np.arange(self.w.size))

    def free_colors(self):
        """The colours restricted to rows whose two bodies are static or carry
        no joint (``~jointed``), empty colours dropped; computed once per step."""
        if self._free_colors is None:
            free = ~self.jointed
            self._free_colors = [r for r in (rows[free[rows]] for rows in self.colors) if r.size]
        return self._free_colors

    def solve(self, model, state, h, use_bias, colors=None):
        """One sweep over ``colors`` (default: every row), in colour order."""
        for rows in self.colors if colors is None else colors:
            self._solve_block(state, rows, self._block(rows), h, use_bias)
        if colors is None and self.articulated is not None:
            self.articulated.solve(state, self, h, use_bias)

    def attach(self, articulated):
        """Hand the rows of ``articulated`` (an ``ArticulatedContacts``) to it:
        they leave the colours, and the warm start and every sweep end with
        its contact-space solve."""
        if articulated.empty:
            return
        self.articulated = articulated
        taken = np.zeros(self.w.size, dtype=bool)
        taken[articulated.rows] = True
        self.colors = [r for r in (rows[~taken[rows]] for rows in self.colors) if r.size]

    def _bias_rate(self, c, lam_n, h):
        """Position-bias rate (1/s) of each point of block ``c``: the soft
        contact's, raised for points between bodies without joints that carry
        more than the weight of their own effective mass.

        A soft point rests where its spring m_n ω² (m_n its effective mass)
        holds its load F: at F / (m_n ω²), as deep as the load is heavy next
        to m_n, and a column of light boxes sags at every contact and slowly
        buckles (the stack of 20 of 1 kg boxes: its bottom 4.4 mm deep). The
        bias rate, which sets that spring, is multiplied by the load factor
        F / (m_n g) (F = λ_n / h from the impulse the point holds), clipped
        to [1, ``contact_load_stiffening``]: a box alone on the ground keeps
        1 (its four corners each carry about the weight of their m_n)."""
        rate = self.soft.bias_rate
        cap = self.load_stiffening
        if cap <= 1.0 or self.g_mag == 0.0 or not c.any_free:
            return rate
        load = lam_n / (h * self.g_mag * np.maximum(c.mn, 1e-30))
        return rate * np.where(c.free[:, None], np.clip(load, 1.0, cap), 1.0)

    def _solve_block(self, state, rows, c, h, use_bias):
        """One Gauss-Seidel sweep over the rows of one colour: normal points,
        then friction points. Per point, with Ċ = v_rel·n and s the current
        separation: Δλ = -m_n ms (Ċ + bias) - isc λ, λ >= 0, where an open
        point (s > 0) is speculative (bias s/h, ms 1, isc 0) and a penetrating
        one soft (bias rate·min(s + slop, 0) capped at max_push_out, soft
        mass and impulse scales; the relax solve and the thesis: rigid, no
        bias)."""
        soft = self.soft
        va, wa, vb, wb = self._gather(state, c)
        n, t1, t2 = c.n, c.t1, c.t2
        # Rows on a static body that stands still (the ground): its side of
        # v_rel is zero and left out.
        a_still = not (c.dyn_a.any() or va.any() or wa.any())

        def v_rel(j):
            """Relative velocity (R, 3) at point j: (v_b + ω_b × r_b) - (v_a + ω_a × r_a)."""
            if a_still:
                return vb + cross(wb, c.rb[:, j])
            return vb + cross(wb, c.rb[:, j]) - va - cross(wa, c.ra[:, j])

        sep = _separation(state, c)
        valid = c.valid
        P = valid.shape[1]
        open_ = sep > 0
        # The rows' impulses, gathered once and written back after the sweep.
        lam_n, max_lam_n = self.lam_n.take(rows, 0), self.max_lam_n.take(rows, 0)
        if use_bias and not self.thesis:
            pen = np.minimum(sep + self.slop, 0.0)
            bias = np.where(open_, sep / h, np.maximum(self._bias_rate(c, lam_n, h) * pen, -self.max_push_out))
            gain = -c.mn * np.where(open_, 1.0, soft.mass_scale)
            isc = np.where(open_, 0.0, soft.impulse_scale)
        else:
            bias = np.where(open_, sep / h, 0.0)
            gain, isc = -c.mn, None
        s_close = self.s_close.take(rows, 0)
        # Closing speeds at the row's start, before its own points'
        # impulses (a face landing flat records one speed at all four),
        # for restitution: only while a point may still first take load.
        record = self.bouncy and bool(((max_lam_n == 0) & valid).any())
        if record:
            vn_close = self.vn_close.take(rows, 0)
            vn_row = np.stack([dot(v_rel(j), n) for j in range(P)], axis=1)
        # Rows between two moving bodies take NORMAL_PASSES passes over their
        # normal points: one pass in the fixed order 0..3 leaves the earlier
        # points' residual speed in a pattern fixed by that order, a torque
        # bias on both boxes that made a stack of 5 circle at 0.08 m/s at the
        # defaults (at rest with 2 passes). Rows on a static body keep one
        # pass: a second one there changed the standing PD's falls under the
        # Balance pushes (feet on the ground) from 14 to 21 of 200 episodes.
        paired = c.paired
        passes = NORMAL_PASSES if paired.any() else 1
        if passes > 1:
            ok_later = valid & paired[:, None]  # later passes: paired rows solve ...
            keep_later = valid & ~paired[:, None]  # ... the others keep their impulse
        for k in range(passes):
            news = []
            for j in range(P):
                vn = dot(v_rel(j), n)
                lam = lam_n[:, j]
                d = gain[:, j] * (vn + bias[:, j])
                if isc is not None:
                    d = d - isc[:, j] * lam
                if not (lam.any() or (d > 0.0).any()):
                    news.append(lam)  # no point holds or takes an impulse: λ stays 0
                    continue
                if k == 0:
                    new = np.where(valid[:, j], np.maximum(lam + d, 0.0), 0.0)
                else:
                    new = np.where(ok_later[:, j], np.maximum(lam + d, 0.0), np.where(keep_later[:, j], lam, 0.0))
                news.append(new)
                va, wa, vb, wb = self._apply(c, j, (new - lam)[:, None] * n, va, wa, vb, wb)
            # Each point reads only its own impulse, so the pass's bookkeeping
            # is done for all its points at once. Closing speed for
            # restitution: the normal velocity just before the point first
            # takes load in this step.
            new = np.stack(news, axis=1)
            first = (max_lam_n == 0) & (new > 0)
            if record:
                vn_close = np.where(first, vn_row, vn_close)
            s_close = np.where(first, sep, s_close)
            lam_n = new
            max_lam_n = np.maximum(max_lam_n, new)
        lam_t1, lam_t2 = self.lam_t1.take(rows, 0), self.lam_t2.take(rows, 0)
        limit = c.mu * lam_n
        for j in range(P):
            l1, l2 = lam_t1[:, j], lam_t2[:, j]
            if not (limit[:, j].any() or l1.any() or l2.any()):
                continue  # no normal impulse and no friction impulse: the disc is a point
            vrel = v_rel(j)
            n1 = l1 - c.mt1[:, j] * dot(vrel, t1)
            n2 = l2 - c.mt2[:, j] * dot(vrel, t2)
            scale = _coulomb_scale(n1, n2, limit[:, j])
            n1 = np.where(valid[:, j], n1 * scale, 0.0)
            n2 = np.where(valid[:, j], n2 * scale, 0.0)
            impulse = (n1 - l1)[:, None] * t1 + (n2 - l2)[:, None] * t2
            lam_t1[:, j], lam_t2[:, j] = n1, n2
            va, wa, vb, wb = self._apply(c, j, impulse, va, wa, vb, wb)
        self._scatter(state, c, va, wa, vb, wb)
        self.lam_n[rows], self.max_lam_n[rows], self.s_close[rows] = lam_n, max_lam_n, s_close
        self.lam_t1[rows], self.lam_t2[rows] = lam_t1, lam_t2
        if record:
            self.vn_close[rows] = vn_close

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
            self._bounce_in_place(state, held, first_target)
            if self.articulated is not None:
                self.articulated.bounce(state, self, held, first_target)
        free = bounce.any(axis=1) & ~self.jointed
        if free.any():
            self._impacts(state, free, loaded & ~self.jointed[:, None], bounce, first_target)

    def _bounce_in_place(self, state, bounce, target):
        """Rows on jointed bodies: the impact was already solved with the
        joints; add to each bouncing point's impulse until its separating
        speed is the target (λ_n ≥ 0)."""
        for rows in self.colors:
            if not bounce[rows].any():
                continue
            c = self._block(rows)
            va, wa, vb, wb = self._gather(state, c)
            n = c.n
            for j in range(self.valid.shape[1]):
                ok = bounce[rows, j]
                vn = dot(vb + cross(wb, c.rb[:, j]) - va - cross(wa, c.ra[:, j]), n)
                lam = self.lam_n[rows, j]
                d = -c.mn[:, j] * (vn - target[rows, j])
                new = np.where(ok, np.maximum(lam + d, 0.0), lam)
                d = new - lam
                self.lam_n[rows, j] = new
                va, wa, vb, wb = self._apply(c, j, d[:, None] * n, va, wa, vb, wb)
            self._scatter(state, c, va, wa, vb, wb)

    def _impacts(self, state, seed_rows, loaded, bounce, first_target):
        """Free bodies: take the step's impulses of newly touching points back
        and give the impacts in sequence (Guendelman et al. 2003)."""
        rows_on = self._impact_cluster(state, seed_rows, loaded.any(axis=1))
        # Undo: the points that took load only in this step get their whole
        # step's normal and friction impulses back (λ of every substep), so the
        # impacts below start from the velocities before the collision.
        undo = loaded & (self.lam_n_start == 0) & rows_on[:, None]
        self._sweep(state, rows_on, -np.where(undo, self.lam_n_step + self.lam_n, 0.0),
                    -np.where(undo, self.lam_t1_step + self.lam_t1, 0.0),
                    -np.where(undo, self.lam_t2_step + self.lam_t2, 0.0))
        # Impact impulses are not warm-started: the next step starts from the
        # load the points carried before the impacts.
        self.lam_n = np.where(undo, 0.0, self.lam_n)
        self.lam_t1 = np.where(undo, 0.0, self.lam_t1)
        self.lam_t2 = np.where(undo, 0.0, self.lam_t2)
        self.lam_n_store = self.lam_n.copy()
        pending = bounce & rows_on[:, None]  # first impacts not yet given
        for _ in range(IMPACT_SWEEPS):
            hit = False
            for rows in self.colors:
                rows = rows[rows_on[rows]]
                if rows.size:
                    hit |= self._impact(state, rows, loaded[rows], pending, first_target)
            if not hit:
                break

    def _impact_cluster(self, state, seed_rows, loaded_rows):
        """Rows reached from ``seed_rows`` through loaded rows sharing a
        dynamic body (a row of touching balls, a stack under a falling box):
        the rows an impact can pass through. Static bodies do not connect."""
        rows_on = seed_rows.copy()
        marked = np.zeros(state.num_worlds * state.position.shape[1], dtype=bool)
        for _ in range(IMPACT_SWEEPS):
            marked[self.ka[rows_on & self.dyn_a]] = True
            marked[self.kb[rows_on & self.dyn_b]] = True
            reach = loaded_rows & ~rows_on & ((marked[self.ka] & self.dyn_a) | (marked[self.kb] & self.dyn_b))
            if not reach.any():
                break
            rows_on |= reach
        return rows_on

    def _sweep(self, state, rows_on, lam_n, lam_t1, lam_t2):
        """Apply point impulses λ_n n + λ_t1 t1 + λ_t2 t2 (R, 4) to the rows with rows_on."""
        lam = lam_n[..., None] * self.n[:, None] + lam_t1[..., None] * self.t1[:, None] \
            + lam_t2[..., None] * self.t2[:, None]
        for rows in self.colors:
            rows = rows[rows_on[rows]]
            if not rows.size:
                continue
            c = self._block(rows, cache=False)
            va, wa, vb, wb = self._gather(state, c)
            lam_c = lam[rows]
            for j in range(self.valid.shape[1]):
                va, wa, vb, wb = self._apply(c, j, lam_c[:, j], va, wa, vb, wb)
            self._scatter(state, c, va, wa, vb, wb)

    def _impact(self, state, rows, loaded, pending, first_target):
        """One impact on each row of ``rows`` with an approaching loaded point:
        targets v_n' = e·|v_n| (v_n at the impact's start; a point's first
        impact: from its closing speed), λ ≥ 0 per point. Returns whether any
        row had an impact."""
        c = self._block(rows, cache=False)
        va, wa, vb, wb = self._gather(state, c)
        n = c.n
        P = self.valid.shape[1]

        def normal_speed(j):
            return dot(vb + cross(wb, c.rb[:, j]) - va - cross(wa, c.ra[:, j]), n)

        vn = np.stack([normal_speed(j) for j in range(P)], axis=1)
        approach = loaded & (vn < -IMPACT_TOLERANCE)
        event = approach.any(axis=1)
        if not event.any():
            return False
        e = self.e[rows][:, None]
        first = pending[rows]
        speed_bounce = (vn < -self.threshold) & (e > 0)
        target = np.where(first, first_target[rows], np.where(speed_bounce, -e * vn, 0.0))
        on = event[:, None] & loaded
        done = ~event
        target = np.maximum(target, 0.0)
        # Normal rows to the targets, then Coulomb friction bounded by μ times
        # the impact's normal impulse, the row's points in sequence.
        t1, t2 = c.t1, c.t2
        lam, l1, l2 = np.zeros(vn.shape), np.zeros(vn.shape), np.zeros(vn.shape)
        # Each row passes until its own impulses settle (a row's result must not
        # depend on the other worlds' rows).
        for _ in range(IMPACT_POINT_PASSES):
            live = ~done
            change = 0.0
            for j in range(P):
                d = -c.mn[:, j] * (normal_speed(j) - target[:, j])
                new = np.where(on[:, j] & live, np.maximum(lam[:, j] + d, 0.0), lam[:, j])
                d = new - lam[:, j]
                change = np.maximum(change, np.abs(d))
                lam[:, j] = new
                va, wa, vb, wb = self._apply(c, j, d[:, None] * n, va, wa, vb, wb)
            for j in range(P):
                vrel = vb + cross(wb, c.rb[:, j]) - va - cross(wa, c.ra[:, j])
                n1 = l1[:, j] - c.mt1[:, j] * dot(vrel, t1)
                n2 = l2[:, j] - c.mt2[:, j] * dot(vrel, t2)
                scale = _coulomb_scale(n1, n2, c.mu[:, j] * lam[:, j])
                n1 = np.where(live, n1 * scale, l1[:, j])
                n2 = np.where(live, n2 * scale, l2[:, j])
                change = np.maximum(change, np.maximum(np.abs(n1 - l1[:, j]), np.abs(n2 - l2[:, j])))
                P_t = (n1 - l1[:, j])[:, None] * t1 + (n2 - l2[:, j])[:, None] * t2
                l1[:, j], l2[:, j] = n1, n2
                va, wa, vb, wb = self._apply(c, j, P_t, va, wa, vb, wb)
            done = done | (change <= IMPACT_PASS_TOLERANCE * lam.max(axis=1))
            if done.all():
                break
        self._scatter(state, c, va, wa, vb, wb)
        pending[rows] &= ~event[:, None]
        return True

    def project_positions(self, model, state):
        """The thesis's penetration resolution: move both bodies apart along the
        normal by the penetration depth, split by inverse mass."""
        rows = np.arange(self.w.size)
        sep = np.where(self.valid, self._separation(state, rows), np.inf).min(axis=1)
        depth = np.maximum(-(sep + self.slop), 0.0)
        total = np.maximum(self.inv_ma + self.inv_mb, 1e-30)
        pos = state.position.reshape(-1, 3)
        np.add.at(pos, self.ka, -(depth * self.inv_ma / total)[:, None] * self.n)
        np.add.at(pos, self.kb, (depth * self.inv_mb / total)[:, None] * self.n)

    def store(self, state):
        """Keep the impulses for next step's warm start."""
        state.contact_normal_impulse[self.w, self.p] = self.lam_n if self.lam_n_store is None else self.lam_n_store
        state.contact_friction_impulse[self.w, self.p] = (self.lam_t1[..., None] * self.t1[:, None]
                                                          + self.lam_t2[..., None] * self.t2[:, None])
