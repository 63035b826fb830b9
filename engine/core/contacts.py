"""Contact rows in the soft-step solver, one world at a time (after Box2D v3
``src/contact_solver.c``).

A row is one pair's manifold of up to 4 points sharing a normal n (from body
a to body b). Per point, with lever arms r_a, r_b fixed for the step and
v_rel = (v_b + ω_b × r_b) - (v_a + ω_a × r_a):

* normal: Δλ = -m_n s_m (v_rel·n + bias) - s_i λ, λ ≥ 0. The current
  separation s = s₀ + n·(Δ(x_b + r_b) - Δ(x_a + r_a)) follows the bodies'
  displacement, so the narrow phase runs once per step. An open point (s > 0)
  is speculative: bias s/h, rigid (s_m = 1, s_i = 0). A penetrating one is
  soft in the biased solve (Catto's soft step: bias rate·min(s + slop, 0)
  capped at the push-out speed, mass and impulse scales s_m, s_i) and rigid
  with no bias in the relax solve.
* friction: two tangent rows, the accumulated impulse clamped to the disc
  |λ_t| ≤ μ λ_n (Coulomb).
* restitution, once per step after the substeps: the sequential impacts of
  Guendelman, Bridson & Fedkiw (2003) among free bodies, and, on bodies held
  by joints, a raise of each bouncing point's separating speed to its target.

Rows are swept in ``order``: by world, then by colour, then by row. Rows of
one colour share no body, so this gives the same result as sweeping a
colour's rows together. The arrays of all rows of a step are fields of a
:class:`ContactRowArrays`; the kernels run one world per ``prange`` iteration,
each on its own rows (``world_start``) and its own bodies.

The step's rows are gathered from the detection's (world, pair) manifolds
(``gather``), coloured world by world in row order or top down
(``color_rows``, ``color_in_order``: the rounds of Jones and Plassmann 1993)
and put in sweep order (``sweep_order``); at the step's end restitution's
targets (``restitution_targets``), the thesis's position projection
(``project_positions``) and the store of the impulses for the next warm
start (``store``) are kernels too.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .collide.world import gather_rows
from .jit import SERIAL_BELOW, SERIAL_ROWS_BELOW, allocating_kernel, kernel, parallel_kernel, prange
from .vec import add, cross, dot, load3, load4, mat3_vec, quat_to_matrix, rotate, rotate_inv, scale, sub

IMPACT_SWEEPS = 16  # at most this many sweeps of impacts (a row of n balls needs about n/2)
IMPACT_POINT_PASSES = 32  # at most this many passes over the points of a row in one impact
IMPACT_PASS_TOLERANCE = 1e-6  # stop the passes when no λ changed by more than this fraction of the largest
IMPACT_TOLERANCE = 1e-9  # m/s: a loaded point closing faster than this takes an impact
NORMAL_PASSES = 2  # Gauss-Seidel passes over the normal points of a row between two moving bodies


class ContactRowArrays(NamedTuple):
    """Every contact row of one step (R rows, 4 point slots each). Body
    indices are within the row's world ``w``; vectors are world-frame."""

    w: np.ndarray  # (R,) int64 world
    a: np.ndarray  # (R,) int64 body a
    b: np.ndarray  # (R,) int64 body b
    dyn_a: np.ndarray  # (R,) bool
    dyn_b: np.ndarray  # (R,) bool
    free: np.ndarray  # (R,) bool: neither body is held by a joint
    inv_ma: np.ndarray  # (R,) 1/kg
    inv_mb: np.ndarray  # (R,) 1/kg
    n: np.ndarray  # (R, 3) unit normal from a to b
    t1: np.ndarray  # (R, 3) unit tangent
    t2: np.ndarray  # (R, 3) unit tangent n × t1
    valid: np.ndarray  # (R, 4) bool
    xa0: np.ndarray  # (R, 3) m, body a's position at the step start
    xb0: np.ndarray  # (R, 3) m
    ra: np.ndarray  # (R, 4, 3) m, lever arms at the step start
    rb: np.ndarray  # (R, 4, 3) m
    la: np.ndarray  # (R, 4, 3) m, lever arms in body a's frame
    lb: np.ndarray  # (R, 4, 3) m
    sep0: np.ndarray  # (R, 4) m, separation at the step start (0 in empty slots)
    ia: np.ndarray  # (R, 3, 3) world inverse inertia of a at the step start, 1/(kg m²)
    ib: np.ndarray  # (R, 3, 3)
    mn: np.ndarray  # (R, 4) kg, normal effective masses (0 in empty slots)
    mt1: np.ndarray  # (R, 4) kg
    mt2: np.ndarray  # (R, 4) kg
    mu: np.ndarray  # (R, 4) friction coefficient of each point this step
    e: np.ndarray  # (R,) restitution
    lam_n: np.ndarray  # (R, 4) N s, accumulated normal impulse of the substep
    lam_t1: np.ndarray  # (R, 4) N s
    lam_t2: np.ndarray  # (R, 4) N s
    max_lam_n: np.ndarray  # (R, 4) N s, the largest λ_n of the step so far
    s_close: np.ndarray  # (R, 4) m, separation when the point first took load
    vn_close: np.ndarray  # (R, 4) m/s, normal speed just before the point first took load


class SolverParams(NamedTuple):
    """The constants of one solve. h: substep (s); bias_rate (1/s), mass_scale
    and impulse_scale: the contacts' softness; max_push_out: m/s; slop: m;
    load_cap: the largest load stiffening factor (1: off); g_mag: |g| (m/s²);
    bouncy: some row has restitution, so closing speeds are recorded; thesis:
    the thesis's solver (rigid rows, no bias but the speculative one)."""

    h: float
    bias_rate: float
    mass_scale: float
    impulse_scale: float
    max_push_out: float
    slop: float
    load_cap: float
    g_mag: float
    bouncy: bool
    thesis: bool


# ------------------------------------------------------------------ helpers
@kernel
def _max0(x):
    """max(x, 0) that keeps NaN, as np.maximum does."""
    if x > 0.0 or x != x:
        return x
    return 0.0


@kernel
def _lever(arm, r, j):
    return (arm[r, j, 0], arm[r, j, 1], arm[r, j, 2])


@kernel
def _v_rel(R, r, j, vel, angvel):
    """(v_b + ω_b × r_b) - (v_a + ω_a × r_a) at point j of row r."""
    a, b = R.a[r], R.b[r]
    vb = add(load3(vel, b), cross(load3(angvel, b), _lever(R.rb, r, j)))
    return sub(sub(vb, load3(vel, a)), cross(load3(angvel, a), _lever(R.ra, r, j)))


@kernel
def _apply(R, r, j, P, vel, angvel):
    """Impulse P (N s) at point j of row r: -P on body a, +P on body b."""
    if R.dyn_a[r]:
        a = R.a[r]
        va = sub(load3(vel, a), scale(R.inv_ma[r], P))
        wa = sub(load3(angvel, a), mat3_vec(R.ia, r, cross(_lever(R.ra, r, j), P)))
        vel[a, 0], vel[a, 1], vel[a, 2] = va
        angvel[a, 0], angvel[a, 1], angvel[a, 2] = wa
    if R.dyn_b[r]:
        b = R.b[r]
        vb = add(load3(vel, b), scale(R.inv_mb[r], P))
        wb = add(load3(angvel, b), mat3_vec(R.ib, r, cross(_lever(R.rb, r, j), P)))
        vel[b, 0], vel[b, 1], vel[b, 2] = vb
        angvel[b, 0], angvel[b, 1], angvel[b, 2] = wb


@kernel
def _coulomb_scale(t1, t2, limit):
    """Factor that brings the tangent impulse (t1, t2) into the disc |λ_t| ≤ limit."""
    mag = math.sqrt(t1 * t1 + t2 * t2)
    if mag > limit:
        return limit / max(mag, 1e-30)
    return 1.0


@kernel
def separation(R, r, j, pos, ori):
    """Current separation (m) of point j of row r from its bodies'
    displacement this step: s₀ + n·(Δ(x_b + r_b) - Δ(x_a + r_a))."""
    a, b = R.a[r], R.b[r]
    ra = rotate(load4(ori, a), _lever(R.la, r, j))
    rb = rotate(load4(ori, b), _lever(R.lb, r, j))
    d = add(sub(load3(pos, b), load3(R.xb0, r)), rb)
    d = sub(d, _lever(R.rb, r, j))
    d = sub(d, sub(load3(pos, a), load3(R.xa0, r)))
    d = add(sub(d, ra), _lever(R.ra, r, j))
    return R.sep0[r, j] + dot(d, load3(R.n, r))


# ------------------------------------------------------------------ one row
@kernel
def _warm_start_row(R, r, vel, angvel):
    n, t1, t2 = load3(R.n, r), load3(R.t1, r), load3(R.t2, r)
    for j in range(4):
        P = add(add(scale(R.lam_n[r, j], n), scale(R.lam_t1[r, j], t1)), scale(R.lam_t2[r, j], t2))
        _apply(R, r, j, P, vel, angvel)


@kernel
def _solve_row(R, r, pos, ori, vel, angvel, p, use_bias, scratch):
    """One Gauss-Seidel sweep over row r: its normal points (twice in a row
    between two moving bodies: one pass in the fixed order 0..3 leaves the
    earlier points' residual speed in a fixed pattern, a torque bias on both
    bodies), then its friction points."""
    h = p.h
    n = load3(R.n, r)
    sep, bias, gain, isc, vn_row, new = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4], scratch[5]
    isc[:] = 0.0
    soft = use_bias and not p.thesis
    load_stiff = soft and p.load_cap > 1.0 and p.g_mag != 0.0 and R.free[r]
    for j in range(4):
        s = separation(R, r, j, pos, ori)
        sep[j] = s
        if soft:
            if s > 0.0:
                bias[j], gain[j] = s / h, -R.mn[r, j]
            else:
                rate = p.bias_rate
                if load_stiff:
                    # A soft point rests where its spring m_n ω² holds its load F:
                    # the rate is raised by the load factor F / (m_n g), F = λ_n / h,
                    # clipped to [1, load_cap], so that a column of light bodies
                    # does not sag at every contact.
                    load = R.lam_n[r, j] / (h * p.g_mag * max(R.mn[r, j], 1e-30))
                    rate = rate * min(max(load, 1.0), p.load_cap)
                bias[j] = max(rate * min(s + p.slop, 0.0), -p.max_push_out)
                gain[j] = -R.mn[r, j] * p.mass_scale
                isc[j] = p.impulse_scale
        else:
            bias[j] = s / h if s > 0.0 else 0.0
            gain[j] = -R.mn[r, j]
    # Closing speeds at the row's start, before its own impulses (a face
    # landing flat records one speed at all four points), for restitution.
    record = False
    if p.bouncy:
        for j in range(4):
            if R.max_lam_n[r, j] == 0.0 and R.valid[r, j]:
                record = True
    if record:
        for j in range(4):
            vn_row[j] = dot(_v_rel(R, r, j, vel, angvel), n)
    passes = NORMAL_PASSES if (R.dyn_a[r] and R.dyn_b[r]) else 1
    for _ in range(passes):
        for j in range(4):
            lam = R.lam_n[r, j]
            vn = dot(_v_rel(R, r, j, vel, angvel), n)
            d = gain[j] * (vn + bias[j])
            if soft:
                d = d - isc[j] * lam
            value = _max0(lam + d) if R.valid[r, j] else 0.0
            new[j] = value
            if value != lam:
                _apply(R, r, j, scale(value - lam, n), vel, angvel)
        # Each point reads only its own impulse: the bookkeeping after the pass.
        for j in range(4):
            first = R.max_lam_n[r, j] == 0.0 and new[j] > 0.0
            if first:
                if record:
                    R.vn_close[r, j] = vn_row[j]
                R.s_close[r, j] = sep[j]
            R.lam_n[r, j] = new[j]
            if new[j] > R.max_lam_n[r, j]:
                R.max_lam_n[r, j] = new[j]
    t1, t2 = load3(R.t1, r), load3(R.t2, r)
    for j in range(4):
        limit = R.mu[r, j] * R.lam_n[r, j]
        l1, l2 = R.lam_t1[r, j], R.lam_t2[r, j]
        if limit == 0.0 and l1 == 0.0 and l2 == 0.0:
            continue  # no normal and no friction impulse: the disc is a point
        vrel = _v_rel(R, r, j, vel, angvel)
        n1 = l1 - R.mt1[r, j] * dot(vrel, t1)
        n2 = l2 - R.mt2[r, j] * dot(vrel, t2)
        if R.valid[r, j]:
            c = _coulomb_scale(n1, n2, limit)
            n1, n2 = n1 * c, n2 * c
        else:
            n1, n2 = 0.0, 0.0
        R.lam_t1[r, j], R.lam_t2[r, j] = n1, n2
        _apply(R, r, j, add(scale(n1 - l1, t1), scale(n2 - l2, t2)), vel, angvel)


@kernel
def _bounce_row(R, r, vel, angvel, held, target):
    """A row on jointed bodies: its impact was solved with the joints; each
    bouncing point's impulse grows until its separating speed is the target."""
    n = load3(R.n, r)
    for j in range(4):
        if not held[r, j]:
            continue
        vn = dot(_v_rel(R, r, j, vel, angvel), n)
        lam = R.lam_n[r, j]
        value = _max0(lam - R.mn[r, j] * (vn - target[r, j]))
        R.lam_n[r, j] = value
        _apply(R, r, j, scale(value - lam, n), vel, angvel)


@allocating_kernel
def _impact_row(R, r, vel, angvel, loaded, pending, first_target, threshold):
    """One impact on row r if a loaded point approaches: targets
    v_n' = e |v_n| (a point's first impact: from its closing speed before
    it took load), λ ≥ 0 per point, then Coulomb friction bounded by μ times
    the impact's normal impulse, passes over the row's points until its
    impulses settle. ``pending`` (4,): the points whose first impact is
    still to come. Returns whether the row had an impact."""
    n, t1, t2 = load3(R.n, r), load3(R.t1, r), load3(R.t2, r)
    vn = np.empty(4)
    event = False
    for j in range(4):
        vn[j] = dot(_v_rel(R, r, j, vel, angvel), n)
        if loaded[r, j] and vn[j] < -IMPACT_TOLERANCE:
            event = True
    if not event:
        return False
    e = R.e[r]
    target = np.empty(4)
    for j in range(4):
        if pending[j]:
            t = first_target[r, j]
        elif vn[j] < -threshold and e > 0.0:
            t = -e * vn[j]
        else:
            t = 0.0
        target[j] = max(t, 0.0)
    lam = np.zeros(4)
    l1 = np.zeros(4)
    l2 = np.zeros(4)
    for _ in range(IMPACT_POINT_PASSES):
        change = 0.0
        for j in range(4):
            if not loaded[r, j]:
                continue
            d = -R.mn[r, j] * (dot(_v_rel(R, r, j, vel, angvel), n) - target[j])
            value = _max0(lam[j] + d)
            d = value - lam[j]
            change = max(change, abs(d))
            lam[j] = value
            _apply(R, r, j, scale(d, n), vel, angvel)
        for j in range(4):
            vrel = _v_rel(R, r, j, vel, angvel)
            n1 = l1[j] - R.mt1[r, j] * dot(vrel, t1)
            n2 = l2[j] - R.mt2[r, j] * dot(vrel, t2)
            c = _coulomb_scale(n1, n2, R.mu[r, j] * lam[j])
            n1, n2 = n1 * c, n2 * c
            change = max(change, max(abs(n1 - l1[j]), abs(n2 - l2[j])))
            _apply(R, r, j, add(scale(n1 - l1[j], t1), scale(n2 - l2[j], t2)), vel, angvel)
            l1[j], l2[j] = n1, n2
        largest = max(max(lam[0], lam[1]), max(lam[2], lam[3]))
        if change <= IMPACT_PASS_TOLERANCE * largest:
            break
    pending[:] = False
    return True


# ------------------------------------------------------------------ batches
# Each prange body is one call of a kernel of one world (or row): numba's
# parallel lowering is kept to the loop itself. Below SERIAL_BELOW worlds
# (SERIAL_ROWS_BELOW rows) the loop runs on the calling thread: waking the
# workers costs more.
@parallel_kernel
def warm_start(R, order, world_start, vel, angvel):
    """Apply every row's accumulated impulses (the last substep's) again."""
    if world_start.size - 1 < SERIAL_BELOW:
        for w in range(world_start.size - 1):
            _warm_start_world(R, order, world_start[w], world_start[w + 1], vel[w], angvel[w])
    else:
        for w in prange(world_start.size - 1):
            _warm_start_world(R, order, world_start[w], world_start[w + 1], vel[w], angvel[w])


@kernel
def _warm_start_world(R, order, lo, hi, vel, angvel):
    for k in range(lo, hi):
        _warm_start_row(R, order[k], vel, angvel)


@parallel_kernel
def solve(R, order, world_start, pos, ori, vel, angvel, p, use_bias, only_free):
    """One sweep over every row (``only_free``: the rows of free bodies)."""
    if world_start.size - 1 < SERIAL_BELOW:
        scratch = np.empty((6, 4))
        for w in range(world_start.size - 1):
            _solve_world(R, order, world_start[w], world_start[w + 1], pos[w], ori[w], vel[w], angvel[w], p, use_bias,
                         only_free, scratch)
    else:
        for w in prange(world_start.size - 1):
            _solve_world(R, order, world_start[w], world_start[w + 1], pos[w], ori[w], vel[w], angvel[w], p, use_bias,
                         only_free, np.empty((6, 4)))


@kernel
def _solve_world(R, order, lo, hi, pos, ori, vel, angvel, p, use_bias, only_free, scratch):
    """One sweep over the rows order[lo:hi] of one world (``only_free``: those
    of free bodies); scratch (6, 4): the rows' work."""
    for k in range(lo, hi):
        r = order[k]
        if only_free and not R.free[r]:
            continue
        _solve_row(R, r, pos, ori, vel, angvel, p, use_bias, scratch)


@parallel_kernel
def separations(R, rows, pos, ori, out):
    """Current separations (m) of the points of ``rows`` into out (len(rows), 4)."""
    if rows.size < SERIAL_ROWS_BELOW:
        for k in range(rows.size):
            _separations_row(R, rows[k], pos, ori, out, k)
    else:
        for k in prange(rows.size):
            _separations_row(R, rows[k], pos, ori, out, k)


@kernel
def _separations_row(R, r, pos, ori, out, k):
    w = R.w[r]
    for j in range(4):
        out[k, j] = separation(R, r, j, pos[w], ori[w])


@parallel_kernel
def bounce_in_place(R, order, world_start, vel, angvel, held, target):
    """Rows on jointed bodies: raise the bouncing points' separating speeds."""
    if world_start.size - 1 < SERIAL_BELOW:
        for w in range(world_start.size - 1):
            _bounce_world(R, order, world_start[w], world_start[w + 1], vel[w], angvel[w], held, target)
    else:
        for w in prange(world_start.size - 1):
            _bounce_world(R, order, world_start[w], world_start[w + 1], vel[w], angvel[w], held, target)


@kernel
def _bounce_world(R, order, lo, hi, vel, angvel, held, target):
    for k in range(lo, hi):
        _bounce_row(R, order[k], vel, angvel, held, target)


@kernel
def _mark(R, r, marked):
    if R.dyn_a[r]:
        marked[R.a[r]] = True
    if R.dyn_b[r]:
        marked[R.b[r]] = True


@allocating_kernel
def _impacts_world(R, order, lo, hi, vel, angvel, seed, loaded, bounce, first_target, undo_n, undo_t1, undo_t2,
                   lam_n_start, threshold, num_bodies):
    """Free bodies of one world: the rows an impact can reach from the
    ``seed`` rows, through loaded rows sharing a dynamic body (a row of
    touching balls; static bodies do not connect); the step's impulses of
    their newly touching points taken back (``undo_*``: what each substep
    applied, λ included), then the impacts in sequence."""
    on = np.zeros(hi - lo, dtype=np.bool_)
    any_loaded = np.zeros(hi - lo, dtype=np.bool_)
    any_on = False
    for k in range(lo, hi):
        r = order[k]
        on[k - lo] = seed[r]
        any_on = any_on or seed[r]
        for j in range(4):
            if loaded[r, j]:
                any_loaded[k - lo] = True
    if not any_on:
        return
    marked = np.zeros(num_bodies, dtype=np.bool_)
    for _ in range(IMPACT_SWEEPS):
        for k in range(lo, hi):
            if on[k - lo]:
                _mark(R, order[k], marked)
        grew = False
        for k in range(lo, hi):
            r = order[k]
            if any_loaded[k - lo] and not on[k - lo] and (
                    (R.dyn_a[r] and marked[R.a[r]]) or (R.dyn_b[r] and marked[R.b[r]])):
                on[k - lo] = True
                grew = True
        if not grew:
            break
    # Undo: the points that took load only in this step get their whole
    # step's impulses back, so the impacts start from the velocities before
    # the collision; impact impulses are not warm-started.
    for k in range(lo, hi):
        if not on[k - lo]:
            continue
        r = order[k]
        n, t1, t2 = load3(R.n, r), load3(R.t1, r), load3(R.t2, r)
        for j in range(4):
            if loaded[r, j] and lam_n_start[r, j] == 0.0:
                P = add(add(scale(-undo_n[r, j], n), scale(-undo_t1[r, j], t1)), scale(-undo_t2[r, j], t2))
                _apply(R, r, j, P, vel, angvel)
                R.lam_n[r, j] = 0.0
                R.lam_t1[r, j] = 0.0
                R.lam_t2[r, j] = 0.0
    pending = np.zeros((hi - lo, 4), dtype=np.bool_)  # first impacts not yet given
    for k in range(lo, hi):
        if on[k - lo]:
            r = order[k]
            for j in range(4):
                pending[k - lo, j] = bounce[r, j]
    for _ in range(IMPACT_SWEEPS):
        hit = False
        for k in range(lo, hi):
            if on[k - lo] and _impact_row(R, order[k], vel, angvel, loaded, pending[k - lo], first_target,
                                          threshold):
                hit = True
        if not hit:
            break


@parallel_kernel
def impacts(R, order, world_start, vel, angvel, seed, loaded, bounce, first_target, undo_n, undo_t1, undo_t2,
            lam_n_start, threshold):
    """The sequential impacts of every world's free bodies (see ``_impacts_world``)."""
    N = vel.shape[1]
    if world_start.size - 1 < SERIAL_BELOW:
        for w in range(world_start.size - 1):
            _impacts_world(R, order, world_start[w], world_start[w + 1], vel[w], angvel[w], seed, loaded, bounce,
                           first_target, undo_n, undo_t1, undo_t2, lam_n_start, threshold, N)
    else:
        for w in prange(world_start.size - 1):
            _impacts_world(R, order, world_start[w], world_start[w + 1], vel[w], angvel[w], seed, loaded, bounce,
                           first_target, undo_n, undo_t1, undo_t2, lam_n_start, threshold, N)


# ------------------------------------------------------------------ prepare
@kernel
def tangents(n):
    """Two unit tangents perpendicular to the unit normal n: t1 = n × e
    normalised, with e the x axis unless n is near it (then y), and t2 = n × t1."""
    e = (1.0, 0.0, 0.0) if abs(n[0]) < 0.57 else (0.0, 1.0, 0.0)
    c = cross(n, e)
    length = max(math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), 1e-12)
    t1 = (c[0] / length, c[1] / length, c[2] / length)
    return t1, cross(n, t1)


@kernel
def world_inv_inertia(q, inv_inertia_body, out, r):
    """out[r] = R diag(I_b⁻¹) Rᵀ, the world inverse inertia of a body turned
    by the unit quaternion q (1/(kg m²))."""
    c0, c1, c2 = quat_to_matrix(q)  # columns of R
    d0, d1, d2 = inv_inertia_body
    for i in range(3):
        ri = (c0[i], c1[i], c2[i])
        for j in range(i, 3):
            rj = (c0[j], c1[j], c2[j])
            v = ri[0] * d0 * rj[0] + ri[1] * d1 * rj[1] + ri[2] * d2 * rj[2]
            out[r, i, j] = v
            out[r, j, i] = v


@kernel
def _effective_mass(inv_mass_sum, ia, ib, r, ra, rb, d):
    """1 / (1/m_a + 1/m_b + (r_a × d)·I_a⁻¹(r_a × d) + (r_b × d)·I_b⁻¹(r_b × d)), kg."""
    ran, rbn = cross(ra, d), cross(rb, d)
    k = inv_mass_sum + dot(ran, mat3_vec(ia, r, ran)) + dot(rbn, mat3_vec(ib, r, rbn))
    return 1.0 / max(k, 1e-30)


@parallel_kernel
def prepare(R, p, point, lam_t, pos, ori, vel, angvel, inv_inertia, mu_static, mu_kinetic, stick_speed):
    """Fill the step-constant fields of every row of ``R`` from its manifold
    (``R.n``, ``point`` (R, 4, 3), ``R.sep0`` holding the separations,
    ``R.valid``) at the step's start state: lever arms in the world and body
    frames, world inverse inertias, tangents, effective masses, the friction
    coefficient of each point (static while it sticks: tangential speed
    under ``stick_speed`` m/s, else kinetic), the tangent parts of the
    warm-start impulses ``lam_t`` (R, 4, 3), and the normal speeds (``R.vn_close``)."""
    if R.w.size < SERIAL_ROWS_BELOW:
        for r in range(R.w.size):
            _prepare_row(R, r, p, point, lam_t, pos, ori, vel, angvel, inv_inertia, mu_static, mu_kinetic,
                         stick_speed)
    else:
        for r in prange(R.w.size):
            _prepare_row(R, r, p, point, lam_t, pos, ori, vel, angvel, inv_inertia, mu_static, mu_kinetic,
                         stick_speed)


@kernel
def _prepare_row(R, r, p, point, lam_t, pos, ori, vel, angvel, inv_inertia, mu_static, mu_kinetic, stick_speed):
    """``prepare`` of row r."""
    w, a, b = R.w[r], R.a[r], R.b[r]
    xa, xb = load3(pos[w], a), load3(pos[w], b)
    qa, qb = load4(ori[w], a), load4(ori[w], b)
    R.xa0[r, 0], R.xa0[r, 1], R.xa0[r, 2] = xa
    R.xb0[r, 0], R.xb0[r, 1], R.xb0[r, 2] = xb
    world_inv_inertia(qa, load3(inv_inertia, a), R.ia, r)
    world_inv_inertia(qb, load3(inv_inertia, b), R.ib, r)
    n = load3(R.n, r)
    t1, t2 = tangents(n)
    R.t1[r, 0], R.t1[r, 1], R.t1[r, 2] = t1
    R.t2[r, 0], R.t2[r, 1], R.t2[r, 2] = t2
    base = R.inv_ma[r] + R.inv_mb[r]
    va, vb = load3(vel[w], a), load3(vel[w], b)
    wa, wb = load3(angvel[w], a), load3(angvel[w], b)
    for j in range(4):
        x = (point[r, j, 0], point[r, j, 1], point[r, j, 2])
        ra, rb = sub(x, xa), sub(x, xb)
        for k in range(3):
            R.ra[r, j, k] = ra[k]
            R.rb[r, j, k] = rb[k]
        la, lb = rotate_inv(qa, ra), rotate_inv(qb, rb)
        for k in range(3):
            R.la[r, j, k] = la[k]
            R.lb[r, j, k] = lb[k]
        valid = R.valid[r, j]
        if not valid:
            R.sep0[r, j] = 0.0
        R.mn[r, j] = _effective_mass(base, R.ia, R.ib, r, ra, rb, n) if valid else 0.0
        R.mt1[r, j] = _effective_mass(base, R.ia, R.ib, r, ra, rb, t1) if valid else 0.0
        R.mt2[r, j] = _effective_mass(base, R.ia, R.ib, r, ra, rb, t2) if valid else 0.0
        vrel = sub(sub(add(vb, cross(wb, rb)), va), cross(wa, ra))
        vn = dot(vrel, n)
        R.vn_close[r, j] = vn
        vt = sub(vrel, scale(vn, n))
        R.mu[r, j] = mu_static[p[r]] if dot(vt, vt) < stick_speed * stick_speed else mu_kinetic[p[r]]
        lt = (lam_t[r, j, 0], lam_t[r, j, 1], lam_t[r, j, 2])
        R.lam_t1[r, j] = dot(lt, t1)
        R.lam_t2[r, j] = dot(lt, t2)



# ------------------------------------------------------------------ the step's rows
@kernel
def gather(keep, normal, point, separation, valid, normal_impulse, friction_impulse, pair_a, pair_b, dynamic,
           inv_mass, held, restitution, gravity, R, p_out, point_out, lam_t_out, jointed, gravity_n):
    """The rows of a step from its detection (:func:`engine.core.collide.detect`):
    the (world, pair) rows with ``keep`` (W, P) set, sorted by pair then world
    (:func:`engine.core.collide.gather_rows`), into the fields of ``R`` that
    depend on the manifold and the model alone: world, bodies, whether each
    moves, inverse masses (1/kg), normal, valid slots, separations (m),
    restitution, the warm-start normal impulses (N s) of the valid slots,
    zero ``max_lam_n`` and ``s_close``; ``p_out`` the pair, ``point_out``
    (R, 4, 3) the points (m), ``lam_t_out`` (R, 4, 3) the warm-start friction
    impulses, ``jointed`` (R,) whether the row touches a moving body ``held``
    by a joint (``R.free`` its negation), ``gravity_n`` (R,) the relative
    normal acceleration uniform ``gravity`` (m/s²) gives the bodies,
    (n·g)(moves_b - moves_a). The state's impulses are zeroed after they are
    read: a pair without a row this step restarts at 0. Returns whether some
    row has restitution."""
    gather_rows(keep, normal, point, separation, valid, normal_impulse, friction_impulse, R.w, p_out, R.n, point_out,
                R.sep0, R.valid, R.lam_n, lam_t_out)
    g = (gravity[0], gravity[1], gravity[2])
    bouncy = False
    for r in range(R.w.size):
        p = p_out[r]
        a, b = pair_a[p], pair_b[p]
        R.a[r], R.b[r] = a, b
        da, db = dynamic[a], dynamic[b]
        R.dyn_a[r], R.dyn_b[r] = da, db
        R.inv_ma[r], R.inv_mb[r] = inv_mass[a], inv_mass[b]
        on_joint = held[a] or held[b]
        jointed[r] = on_joint
        R.free[r] = not on_joint
        e = restitution[p]
        R.e[r] = e
        if e > 0.0:
            bouncy = True
        gravity_n[r] = dot(load3(R.n, r), g) * ((1.0 if db else 0.0) - (1.0 if da else 0.0))
        for j in range(4):
            R.max_lam_n[r, j] = 0.0
            R.s_close[r, j] = 0.0
    normal_impulse[...] = 0.0
    friction_impulse[...] = 0.0
    return bouncy


@allocating_kernel
def rows_by_world(w, num_worlds):
    """The rows grouped by world, each world's in row order, and where each
    world's rows start ((num_worlds + 1,)): a stable counting sort."""
    start = np.zeros(num_worlds + 1, dtype=np.int64)
    for r in range(w.size):
        start[w[r] + 1] += 1
    for k in range(num_worlds):
        start[k + 1] += start[k]
    fill = start[:num_worlds].copy()
    rows = np.empty(w.size, dtype=np.int64)
    for r in range(w.size):
        rows[fill[w[r]]] = r
        fill[w[r]] += 1
    return rows, start


@allocating_kernel
def color_in_order(seq, key_a, key_b, dyn_a, dyn_b, num_keys, first_fit, color):
    """Colour the rows ``seq`` (row indices in priority order, first first)
    so that no two rows of a colour share a moving key (a (world, body));
    static keys are shared freely. color[r] for r in seq is written.

    The colours of Jones and Plassmann's rounds (1993), taken in priority
    order: a row's round is one more than the latest round at its moving
    keys (0 if none), i.e. the round in which every row before it at its
    keys has been taken, so sweeping the rounds in turn sweeps the rows in
    priority order wherever they share a body. ``first_fit``: the rows,
    round by round, then each take the lowest colour not yet used at their
    keys (at most Δ + 1 colours, Δ the most rows a row shares a body with,
    as in Box2D v3's greedy graph colouring); rows of one round share no
    key, so their order within the round does not matter."""
    n = seq.size
    last = np.full(num_keys, -1, dtype=np.int64)
    for i in range(n):
        r = seq[i]
        c = -1
        if dyn_a[r]:
            c = max(c, last[key_a[r]])
        if dyn_b[r]:
            c = max(c, last[key_b[r]])
        c += 1
        color[r] = c
        if dyn_a[r]:
            last[key_a[r]] = c
        if dyn_b[r]:
            last[key_b[r]] = c
    if not first_fit or n == 0:
        return
    # The rows by round (stable), then first fit; a row's first free colour
    # is below the number of rows.
    rounds = 0
    for i in range(n):
        rounds = max(rounds, color[seq[i]] + 1)
    start = np.zeros(rounds + 1, dtype=np.int64)
    for i in range(n):
        start[color[seq[i]] + 1] += 1
    for k in range(rounds):
        start[k + 1] += start[k]
    by_round = np.empty(n, dtype=np.int64)
    for i in range(n):
        k = color[seq[i]]
        by_round[start[k]] = seq[i]
        start[k] += 1
    used = np.zeros((num_keys, n + 1), dtype=np.bool_)
    for i in range(n):
        r = by_round[i]
        da, db = dyn_a[r], dyn_b[r]
        ka, kb = key_a[r], key_b[r]
        c = 0
        while (da and used[ka, c]) or (db and used[kb, c]):
            c += 1
        color[r] = c
        if da:
            used[ka, c] = True
        if db:
            used[kb, c] = True


@kernel
def _point_or_zero(point, valid, r, j):
    if valid[r, j]:
        return (point[r, j, 0], point[r, j, 1], point[r, j, 2])
    return (0.0, 0.0, 0.0)


@allocating_kernel
def _height_order(rows, lo, hi, point, valid, gravity):
    """The rows rows[lo:hi] highest first against ``gravity`` (their valid
    points' mean height; ties in row order)."""
    n = hi - lo
    depth = np.empty(n)  # -height: the mean point along gravity (m² / s²)
    g = (gravity[0], gravity[1], gravity[2])
    for i in range(n):
        r = rows[lo + i]
        # Σ of the valid points (0 in the others), slot by slot from slot 0.
        s = _point_or_zero(point, valid, r, 0)
        count = 1 if valid[r, 0] else 0
        for j in range(1, 4):
            s = add(s, _point_or_zero(point, valid, r, j))
            if valid[r, j]:
                count += 1
        c = float(max(count, 1))
        depth[i] = dot((s[0] / c, s[1] / c, s[2] / c), g)
    idx = np.argsort(depth, kind="mergesort")
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        out[i] = rows[lo + idx[i]]
    return out


@allocating_kernel
def _color_world(R, rows, lo, hi, point, gravity, num_bodies, greedy, color):
    """Colour world's rows rows[lo:hi] (keys: the bodies of the world): in
    row order, or with ``greedy`` top down and first fit."""
    if greedy:
        color_in_order(_height_order(rows, lo, hi, point, R.valid, gravity), R.a, R.b, R.dyn_a, R.dyn_b, num_bodies,
                       True, color)
    else:
        color_in_order(rows[lo:hi], R.a, R.b, R.dyn_a, R.dyn_b, num_bodies, False, color)


@parallel_kernel
def color_rows(R, num_worlds, num_bodies, point, gravity, greedy, color):
    """Colour every world's rows (``_color_world``; color (R,)); returns the
    rows by world and the worlds' starts (``rows_by_world``)."""
    rows, start = rows_by_world(R.w, num_worlds)
    if R.w.size < SERIAL_ROWS_BELOW:
        for k in range(num_worlds):
            _color_world(R, rows, start[k], start[k + 1], point, gravity, num_bodies, greedy, color)
    else:
        for k in prange(num_worlds):
            _color_world(R, rows, start[k], start[k + 1], point, gravity, num_bodies, greedy, color)
    return rows, start


@allocating_kernel
def sweep_order(w, color, num_worlds):
    """The sweep order of the rows with a colour (color ≥ 0): by world, then
    colour, then row; and where each world's rows start in it ((W + 1,))."""
    rows, start = rows_by_world(w, num_worlds)
    order = np.empty(w.size, dtype=np.int64)
    world_start = np.zeros(num_worlds + 1, dtype=np.int64)
    k = 0
    for v in range(num_worlds):
        world_start[v] = k
        lo, hi = start[v], start[v + 1]
        colors = 0
        for i in range(lo, hi):
            colors = max(colors, color[rows[i]] + 1)
        if colors == 0:
            continue
        count = np.zeros(colors + 1, dtype=np.int64)
        for i in range(lo, hi):
            c = color[rows[i]]
            if c >= 0:
                count[c + 1] += 1
        for c in range(colors):
            count[c + 1] += count[c]
        for i in range(lo, hi):
            r = rows[i]
            c = color[r]
            if c >= 0:
                order[k + count[c]] = r
                count[c] += 1
        k += count[colors - 1]
    world_start[num_worlds] = k
    return order[:k], world_start


# ------------------------------------------------------------------ end of step
@kernel
def _np_max(a, b):
    """np.maximum(a, b): a when a ≥ b or a is NaN."""
    if a >= b or math.isnan(a):
        return a
    return b


@kernel
def add_step_impulses(R, lam_n_step, lam_t1_step, lam_t2_step):
    """Σ of the substeps' impulses: the last substep's λ added to the sums."""
    for r in range(R.w.size):
        for j in range(4):
            lam_n_step[r, j] += R.lam_n[r, j]
            lam_t1_step[r, j] += R.lam_t1[r, j]
            lam_t2_step[r, j] += R.lam_t2[r, j]


@kernel
def restitution_targets(R, gravity_n, jointed, threshold, h, lam_n_step, lam_t1_step, lam_t2_step, loaded, bounce,
                        first_target, held, free, loaded_free, undo_n, undo_t1, undo_t2):
    """Which points bounce, and their targets (m/s), from the closing speeds.

    A row that took load while its gap s_c was still open (speculative) hit
    at v_i = -sqrt(v_c² + 2 |a_n| s_c) under the closing part a_n of the
    uniform gravity (``gravity_n``); a point bounces when it took load and
    v_i < -``threshold`` on a row with restitution e > 0. Its first target
    is -e v_i + |a_n| h: semi-implicit Euler's velocity trails its position
    by half a substep, so a free flight under a_n returns to the surface
    |a_n| h slower than it left, and the kick makes the next impact e v_i.
    Outputs (R, 4): ``loaded``, ``bounce``, ``first_target``, ``held`` (the
    bouncing points of rows on jointed bodies), ``loaded_free`` (loaded
    points of rows on free bodies), the step's impulses λ_step + λ
    (``undo_*``); (R,): ``free`` (rows on free bodies with a bouncing point).
    Returns (any bounce, any held, any free)."""
    any_bounce = any_held = any_free = False
    for r in range(R.w.size):
        closing_acc = _np_max(-gravity_n[r], 0.0)
        e = R.e[r]
        row_bounce = False
        for j in range(4):
            vc = R.vn_close[r, j]
            v_imp = -math.sqrt(vc * vc + 2.0 * closing_acc * _np_max(R.s_close[r, j], 0.0))
            if not vc < 0.0:
                v_imp = vc
            ld = R.max_lam_n[r, j] > 0.0 and R.valid[r, j]
            bn = v_imp < -threshold and ld and e > 0.0
            loaded[r, j] = ld
            bounce[r, j] = bn
            first_target[r, j] = -e * v_imp + closing_acc * h if bn else 0.0
            held[r, j] = bn and jointed[r]
            loaded_free[r, j] = ld and not jointed[r]
            undo_n[r, j] = lam_n_step[r, j] + R.lam_n[r, j]
            undo_t1[r, j] = lam_t1_step[r, j] + R.lam_t1[r, j]
            undo_t2[r, j] = lam_t2_step[r, j] + R.lam_t2[r, j]
            row_bounce = row_bounce or bn
        free[r] = row_bounce and not jointed[r]
        any_bounce = any_bounce or row_bounce
        any_held = any_held or (row_bounce and jointed[r])
        any_free = any_free or free[r]
    return any_bounce, any_held, any_free


@allocating_kernel
def _project_world(R, rows, lo, hi, slop, pos, ori):
    """``project_positions`` of one world's rows rows[lo:hi] (row order): every
    row's depth from the positions before any move, then the a sides' moves
    in row order, then the b sides'."""
    depth = np.empty(hi - lo)
    for i in range(lo, hi):
        r = rows[i]
        s = math.inf
        for j in range(4):
            if R.valid[r, j]:
                v = separation(R, r, j, pos, ori)
                if v < s or math.isnan(v):
                    s = v
            if math.isnan(s):
                break
        depth[i - lo] = _np_max(-(s + slop), 0.0)
    for i in range(lo, hi):
        r = rows[i]
        total = _np_max(R.inv_ma[r] + R.inv_mb[r], 1e-30)
        d = -(depth[i - lo] * R.inv_ma[r] / total)
        a = R.a[r]
        for c in range(3):
            pos[a, c] += d * R.n[r, c]
    for i in range(lo, hi):
        r = rows[i]
        total = _np_max(R.inv_ma[r] + R.inv_mb[r], 1e-30)
        d = depth[i - lo] * R.inv_mb[r] / total
        b = R.b[r]
        for c in range(3):
            pos[b, c] += d * R.n[r, c]


@parallel_kernel
def project_positions(R, rows, start, slop, pos, ori):
    """The thesis's penetration resolution: each row's bodies moved apart along
    the normal by its penetration beyond ``slop`` (m; its least current
    separation over the valid points), split by inverse mass; ``rows``,
    ``start``: the rows by world (``rows_by_world``)."""
    if start.size - 1 < SERIAL_BELOW:
        for w in range(start.size - 1):
            _project_world(R, rows, start[w], start[w + 1], slop, pos[w], ori[w])
    else:
        for w in prange(start.size - 1):
            _project_world(R, rows, start[w], start[w + 1], slop, pos[w], ori[w])


@kernel
def store(R, p, normal_impulse, friction_impulse):
    """Each row's impulses into its (world, pair) of the state, for the next
    step's warm start: λ_n (W, P, 4) and the friction impulse λ_t1 t1 + λ_t2 t2
    (W, P, 4, 3), N s."""
    for r in range(R.w.size):
        w, q = R.w[r], p[r]
        for j in range(4):
            normal_impulse[w, q, j] = R.lam_n[r, j]
            l1, l2 = R.lam_t1[r, j], R.lam_t2[r, j]
            for c in range(3):
                friction_impulse[w, q, j, c] = l1 * R.t1[r, c] + l2 * R.t2[r, c]
