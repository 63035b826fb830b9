"""The substeps of a world's step, read top to bottom (``substeps``, for a
range of worlds one after the other).

Each substep of h = dt / substeps seconds (``engine.step`` prepares the step
before and finishes it after):

* the passive joint springs and dampers (on the last substep's constrained
  velocities, before this substep's forces);
* the integrator: symplectic (velocities from the forces, the implicit
  velocity effects, the biased solve, the positions, the relax solve),
  explicit Euler (the thesis's: positions and velocities from the substep's
  start, then the effects and both solves) or RK4 (the free motion, then the
  solves, the constraint impulses moving the positions by h Δv);
* a solve: with its bias, each constraint set's warm start first, then
  ``iterations`` sweeps over the constraint sets in their order; without,
  ``relax_iterations`` sweeps and ``free_relax_passes`` more over the
  contact rows of unjointed bodies. The contacts go first with the
  articulated contacts (their impulses already keep the joint rows, the
  joints' limits then hold exactly), the joints first otherwise;
* after the positions move, the joint rows take their frames, the bodies'
  world inverse inertias and the joint tree's metric afresh (contact rows
  keep the step's start, as in Box2D), and the tree's factors are rebuilt
  at the next solve.

A contact solve is the Gauss-Seidel sweep over the world's rows
(:mod:`engine.core.contacts`), then the articulated rows in contact space
(:mod:`engine.core.articulated`); a joint solve the Gauss-Seidel point and
lock rows, the tree solve (:mod:`engine.core.tree_solve`), then the
Gauss-Seidel limit rows (:mod:`engine.core.joint_rows`).

``ContactStep`` and ``JointStep`` hold what the step's preparation computed
(rows, softness, the per-world buffers the substeps write); a part a scene
lacks comes as empty arrays with its flag off, so every scene runs the same
compiled code.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.experimental import structref

from . import articulated as art
from . import contacts as con
from .effects import velocity_effects
from .integrate import (
    explicit_euler_world,
    free_positions,
    runge_kutta4_world,
    semi_implicit_velocities,
)
from .jit import allocating_kernel, jit_disabled, kernel
from .joint_rows import _add_load_world, _equality_world, _limits_world
from .joints import _geometry_world, _inertia_world, _passive_world
from .joints import _warm_start_world as _joint_warm_start
from .tree_solve import metric, metric_scratch, solve_work, solve_world
from .vec import quat_integrate

#: ``StepConstants.integrator`` codes.
SYMPLECTIC, EULER, RK4 = 0, 1, 2


class StepConstants(NamedTuple):
    """The constants of one step's substeps."""

    h: float  # s, the substep
    substeps: int
    iterations: int  # sweeps of the biased solve
    relax_iterations: int  # sweeps of the relax solve
    free_relax_passes: int  # more relax sweeps over the contact rows of unjointed bodies
    integrator: int  # SYMPLECTIC, EULER or RK4
    contacts_first: bool  # the contacts before the joints in every solve
    effects: bool  # stiff springs or damping: the implicit velocity effects run
    contacts: bool  # the contacts are a constraint set
    joints: bool  # the joints are a constraint set


class ContactStep(NamedTuple):
    """The step's contact rows (``engine.contact_solver.ContactRows``) and
    their articulated part (``engine.articulated_contacts``), beside their
    ``ContactRowArrays``, ``ArticulatedArrays``, ``SolverParams`` and
    ``SoftParams`` (travelling as arguments of their own: numba's compile
    time grows steeply with a tuple's fields; the articulated solve's
    ``ContactView`` of the rows is made inside the substeps)."""

    on: bool  # the step has rows
    order: np.ndarray  # (rows swept,) int64: the sweep order, world by world
    world_start: np.ndarray  # (W + 1,) int64: world w's swept rows are order[world_start[w]:world_start[w + 1]]
    world_rows: np.ndarray  # (R,) int64: every row, world by world
    row_start: np.ndarray  # (W + 1,) int64
    bouncy: bool  # some row has restitution: the substeps' impulses are summed
    lam_n_step: np.ndarray  # (R, 4) N s: Σ of the earlier substeps' normal impulses
    lam_t1_step: np.ndarray  # (R, 4)
    lam_t2_step: np.ndarray  # (R, 4)
    articulated: bool  # rows are solved in contact space


class JointStep(NamedTuple):
    """The step's joints (``engine.joints.JointSet``) and joint tree
    (``engine.joint_tree``): their rows and softness, and the per-world
    buffers of the substeps (W worlds, N bodies, J joints, nj tree joints);
    beside it their ``JointArrays``, ``JointGeometry`` (kept at the current
    positions), ``TreeRows`` and ``TreeLayout``. Softness
    terms are (bias_rate 1/s, mass_scale, impulse_scale)."""

    inv_mass: np.ndarray  # (N,) 1/kg
    inv_inertia: np.ndarray  # (N, 3) 1/(kg m²), principal
    passive: bool
    passive_order: np.ndarray  # (joints,) int64
    stiffness: np.ndarray  # (J,) N m/rad
    damping: np.ndarray  # (J,) N m s/rad
    rest: np.ndarray  # (J, 3) rad
    warm_order: np.ndarray  # (J,) int64: the warm start's joint order
    breakable: bool
    lin_sum: np.ndarray  # (W, J, 3) N s: the step's summed point impulses
    ang_sum: np.ndarray  # (W, J) N m s
    relax: bool  # the equality rows run in the relax solve too
    thesis: bool  # the thesis's solver: the Gauss-Seidel equality rows take no bias
    max_push: float  # m/s
    max_angular_push: float  # rad/s
    eq_joints: np.ndarray  # (rows,) int64: the Gauss-Seidel equality rows' joints
    eq_kinds: np.ndarray  # (rows,) int64
    eq_soft: np.ndarray  # (3,): the Gauss-Seidel equality rows' softness in the biased solve
    gs_limit: np.ndarray  # (limits,) int64: the Gauss-Seidel limit rows' joints
    twist_row: np.ndarray  # (limits,) bool
    swing_row: np.ndarray  # (limits,) bool
    lower: np.ndarray  # (J,) rad
    upper: np.ndarray  # (J,) rad
    limit_soft: np.ndarray  # (3,): the Gauss-Seidel limit rows'
    zone_on: bool  # some limit rows are soft within the margin this step
    zone: np.ndarray  # (W, limits) bool
    no_zone: np.ndarray  # (W, 0) bool
    zone_soft: np.ndarray  # (3,): theirs within the margin
    margin: float  # rad
    tree: bool  # a joint tree is solved (tree joint solver, no exact loops)
    tree_soft: np.ndarray  # (3, W, nj): bias_rate, mass_scale, impulse_scale of each tree joint
    limits: bool  # the limit rows are in the tree solve
    schur: bool
    active_set_passes: int
    tree_metric: bool  # the tree's metric follows the positions (not with the thesis's solver)
    geometric: bool  # geometric stiffness in the metric
    geo_joint: np.ndarray  # (loaded,) int64
    geo_parent: np.ndarray  # (loaded,) int64
    geo_child: np.ndarray  # (loaded,) int64
    n_tree_loaded: int
    weight: np.ndarray  # (W, loaded)
    cap: float
    load_before: np.ndarray  # (W, J) N s: |λ| before the substep's solve
    rot: np.ndarray  # (W, N, 3, 3)
    iinv_raw: np.ndarray  # (W, N, 3, 3): the world inverse inertias
    iinv: np.ndarray  # (W, N, 3, 3): with the metric's geometric stiffness
    M: np.ndarray  # (W, nb, 6, 6)
    M_inv: np.ndarray  # (W, nb, 6, 6)


_MODEL_FIELDS = ("T", "layout", "J", "bodies", "gravitation", "springs", "motors", "damping")


@structref.register
class _ModelArraysType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class _ModelArraysRef(structref.StructRefProxy):
    pass


structref.define_proxy(_ModelArraysRef, _ModelArraysType, list(_MODEL_FIELDS))


class _ModelArraysTuple(NamedTuple):
    T: tuple
    layout: tuple
    J: tuple
    bodies: tuple
    gravitation: tuple
    springs: tuple
    motors: tuple
    damping: tuple


def model_arrays(T, layout, J, bodies, gravitation, springs, motors, damping):
    """The model's read-only arrays that the substeps take (``TreeRows``,
    ``TreeLayout``, ``JointArrays`` and the effects' tuples) as one argument
    with their fields: a numba structref, whose call dispatch costs one
    pointer instead of a type check of each array (0.15 us each), made once
    per model; a NamedTuple with the JIT disabled."""
    make = _ModelArraysTuple if jit_disabled() else _new_model_arrays
    return make(T, layout, J, bodies, gravitation, springs, motors, damping)


@allocating_kernel
def _new_model_arrays(T, layout, J, bodies, gravitation, springs, motors, damping):
    """The structref of ``model_arrays``, made by a cached kernel (the
    proxy's own constructor compiles in every process: a second)."""
    return _ModelArraysRef(T, layout, J, bodies, gravitation, springs, motors, damping)


class StateArrays(NamedTuple):
    """The state's and the control's arrays of W worlds."""

    x: np.ndarray  # (W, N, 3) m
    q: np.ndarray  # (W, N, 4)
    v: np.ndarray  # (W, N, 3) m/s
    w: np.ndarray  # (W, N, 3) rad/s
    broken: np.ndarray  # (W, J) bool
    lam_lin: np.ndarray  # (W, J, 3) N s
    lam_ang: np.ndarray  # (W, J, 3) N m s
    lam_limit: np.ndarray  # (W, J, 3) N m s
    spring_broken: np.ndarray  # (W, springs) bool
    cforce: np.ndarray  # (W, N, 3) or (W, 0, 3) N
    ctorque: np.ndarray  # (W, N, 3) or (W, 0, 3) N m
    motor: np.ndarray  # (W, A) or (W, 0) N m


# ------------------------------------------------------------------ the worlds
@allocating_kernel
def substeps(c, C, R, AS, p, ap, Jt, mdl, g, s, first, stop):
    """Every substep of the steps of worlds first..stop-1, one world after
    the other, in place on the state ``s``. Batches run ranges of worlds on
    several threads (``jit.over_worlds``), not a ``prange``: numba's
    parallel lowering of a loop whose body takes these many tuples of
    arrays took longer to compile than every other kernel together. The
    solve is written once, in a loop over its two phases (biased, relax):
    numba's compile time grows with each call site and function that passes
    these arguments on. The work buffers are allocated here, once a call,
    and the substeps themselves (``_substeps_of``) allocate nothing, so
    they count no references to the arrays they index. mdl: ``model_arrays``."""
    T, layout, J = mdl.T, mdl.layout, mdl.J
    bodies, gravitation, springs, motors, damping = mdl.bodies, mdl.gravitation, mdl.springs, mdl.motors, mdl.damping
    view = art.ContactView(R.a, R.b, R.n, R.xa0, R.xb0, R.ra, R.rb, R.la, R.lb, R.sep0, R.lam_n, R.lam_t1, R.lam_t2,
                           R.max_lam_n, R.s_close, R.vn_close)
    n = s.x.shape[1]
    nj = Jt.tree_soft.shape[2]
    unit = np.zeros((3, nj))  # the relax solve's softness terms (0, 1, 0)
    for j in range(nj):
        unit[1, j] = 1.0
    rk4 = c.integrator == RK4
    m = n if rk4 else 0
    force, torque = np.empty((n, 3)), np.empty((n, 3))
    lb = np.empty((n, 3))
    xs, vs, ws, sx, sv, sw = (np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)),
                              np.empty((m, 3)), np.empty((m, 3)))
    qs, sq = np.empty((m, 4)), np.empty((m, 4))
    v1, w1 = np.empty((m, 3)), np.empty((m, 3))
    # The tree solve's blocks and factors (``tree_solve.TreeScratch``): a world's
    # substeps run on one thread from start to end, so one set a thread.
    nj_t, n_t = T.joint.size, layout.order.size
    E, mask = np.empty((nj_t, 3, 3)), np.empty((nj_t, 6))
    Ja, Jb = np.empty((nj_t, 6, 6)), np.empty((nj_t, 6, 6))
    Dinv, L = np.empty((n_t, 6, 6)), np.empty((n_t, 6, 6))
    fw, bw, iw = solve_work(nj_t, n_t, n, T.cand_joint.size)
    afw, abw = art.solve_work(AS, first, stop)
    cscratch = np.empty((6, 4))
    I, G = metric_scratch(T.bodies.size, n)
    _substeps_of(c, C, R, view, AS, p, ap, Jt, J, T, layout, g, bodies, gravitation, springs, motors, damping, s,
                 first, stop, unit, force, torque, lb, xs, vs, ws, sx, sv, sw, qs, sq, v1, w1, E, mask, Ja, Jb, Dinv,
                 L, fw, bw, iw, afw, abw, cscratch, I, G)


@kernel
def _substeps_of(c, C, R, view, AS, p, ap, Jt, J, T, layout, g, bodies, gravitation, springs, motors, damping, s,
                 first, stop, unit, force, torque, lb, xs, vs, ws, sx, sv, sw, qs, sq, v1, w1, E, mask, Ja, Jb, Dinv,
                 L, fw, bw, iw, afw, abw, cscratch, I, G):
    """The substeps of ``substeps`` on its work buffers."""
    n = s.x.shape[1]
    for wi in range(first, stop):
        x, q, v, w = s.x[wi], s.q[wi], s.v[wi], s.w[wi]
        sb, broken = s.spring_broken[wi], s.broken[wi]
        factored = False  # whether the tree's factors hold the current positions
        for sub in range(c.substeps):
            if c.joints and Jt.passive:
                _passive_world(J, Jt.passive_order, Jt.iinv[wi], g, wi, Jt.stiffness, Jt.damping, Jt.rest, broken,
                               w, c.h)
            for phase in range(2):
                use_bias = phase == 0
                moved = False  # the positions moved in this phase
                if use_bias:
                    # The integrator's motion before the biased solve.
                    if c.integrator == SYMPLECTIC:
                        semi_implicit_velocities(bodies, gravitation, springs, motors, x, q, v, w, sb, broken,
                                                 s.cforce[wi], s.ctorque[wi], s.motor[wi], force, torque, c.h)
                    elif c.integrator == EULER:
                        explicit_euler_world(bodies, gravitation, springs, motors, x, q, v, w, sb, broken,
                                             s.cforce[wi], s.ctorque[wi], s.motor[wi], force, torque, c.h)
                        moved = True
                    else:
                        runge_kutta4_world(bodies, gravitation, springs, motors, x, q, v, w, sb, broken,
                                           s.cforce[wi], s.ctorque[wi], s.motor[wi], force, torque, xs, qs, vs, ws,
                                           sx, sq, sv, sw, c.h)
                        moved = True
                        for i in range(n):
                            for k in range(3):
                                v1[i, k] = v[i, k]
                                w1[i, k] = w[i, k]
                    if c.effects:
                        velocity_effects(bodies, springs, damping, x, q, v, w, sb, c.h)
                elif c.integrator != EULER:
                    # The positions between the solves: the symplectic step's, or
                    # RK4's moved by h Δv of the constraint impulses beyond its flow.
                    if c.integrator == SYMPLECTIC:
                        free_positions(bodies, x, q, v, w, lb, c.h)
                    else:
                        for i in range(n):
                            for k in range(3):
                                x[i, k] = x[i, k] + c.h * (v[i, k] - v1[i, k])
                            qi = quat_integrate((q[i, 0], q[i, 1], q[i, 2], q[i, 3]),
                                                (w[i, 0] - w1[i, 0], w[i, 1] - w1[i, 1], w[i, 2] - w1[i, 2]), c.h)
                            for k in range(4):
                                q[i, k] = qi[k]
                    moved = True
                if moved and c.joints:
                    # The bodies moved and turned: the joint geometry, world inverse
                    # inertias and tree metric at the new positions, with geometric
                    # stiffness from the joints' load through the substep: once a warm
                    # start has recorded |λ| before the biased solve (after the first
                    # substep's, or in the relax phase), the smaller of that and |λ|.
                    # (The velocity effects above read none of these.)
                    warmed = sub > 0 or not use_bias
                    _geometry_world(J, x, q, g, wi)
                    _inertia_world(q, Jt.inv_inertia, Jt.rot[wi], Jt.iinv_raw[wi])
                    if Jt.tree_metric:
                        metric(T, Jt.rot[wi], Jt.iinv_raw[wi], Jt.geo_joint, Jt.geo_parent, Jt.geo_child,
                               Jt.n_tree_loaded, Jt.weight[wi], s.lam_lin[wi], Jt.load_before[wi],
                               Jt.geometric and warmed, g.ra[wi], g.rb[wi], c.h, Jt.cap, Jt.geometric, Jt.iinv[wi],
                               Jt.M[wi], Jt.M_inv[wi], I, G)
                    else:
                        _copy_inertias(Jt.iinv_raw[wi], Jt.iinv[wi])
                    factored = False
                if not (c.contacts or c.joints):
                    continue
                # The solve: with its bias, each set's warm start, then the sweeps
                # over the sets in their order; without, the relax sweeps and the
                # free bodies' extra contact passes. (The sets' code is written here
                # once, not in helpers: numba's compile time grows with each function
                # these tuples are passed on to.)
                if use_bias:
                    for part in range(2):
                        if (part == 0) == c.contacts_first:
                            if c.contacts and C.on:
                                # The impulses of the last substep summed into the step's
                                # (restitution takes them back), then applied again, the
                                # articulated rows' in contact space first.
                                if sub > 0 and C.bouncy:
                                    for k in range(C.row_start[wi], C.row_start[wi + 1]):
                                        r = C.world_rows[k]
                                        for j in range(4):
                                            C.lam_n_step[r, j] += R.lam_n[r, j]
                                            C.lam_t1_step[r, j] += R.lam_t1[r, j]
                                            C.lam_t2_step[r, j] += R.lam_t2[r, j]
                                if C.articulated and AS.row_start[wi + 1] > AS.row_start[wi]:
                                    art._warm_start_world(view, AS, wi, v, w, afw)
                                con._warm_start_world(R, C.order, C.world_start[wi], C.world_start[wi + 1], v, w)
                        elif c.joints:
                            # The last substep's impulses into the step's load (breaking),
                            # the load before this substep's solve (geometric stiffness),
                            # then every stored impulse applied again.
                            if sub > 0 and Jt.breakable:
                                _add_load_world(s.lam_lin[wi], s.lam_ang[wi], s.lam_limit[wi], Jt.lin_sum[wi],
                                                Jt.ang_sum[wi])
                            if Jt.tree and Jt.geometric:
                                lam = s.lam_lin[wi]
                                for j in range(lam.shape[0]):
                                    Jt.load_before[wi, j] = np.sqrt(lam[j, 0] * lam[j, 0] + lam[j, 1] * lam[j, 1]
                                                                    + lam[j, 2] * lam[j, 2])
                            _joint_warm_start(J, Jt.warm_order, Jt.iinv[wi], Jt.inv_mass, g, wi, s.lam_lin[wi],
                                              s.lam_ang[wi], s.lam_limit[wi], v, w)
                sweeps = c.iterations if use_bias else c.relax_iterations
                free_passes = 0 if use_bias or not c.contacts else c.free_relax_passes
                for it in range(sweeps + free_passes):
                    only_free = it >= sweeps
                    for part in range(2):
                        if (part == 0) == c.contacts_first:
                            if c.contacts and C.on:
                                # One sweep of the world's contact rows (only_free: those of unjointed
                                # bodies), then, unless only_free, its articulated rows.
                                con._solve_world(R, C.order, C.world_start[wi], C.world_start[wi + 1], x, q, v, w, p,
                                                 use_bias, only_free, cscratch)
                                if not only_free and C.articulated and AS.row_start[wi + 1] > AS.row_start[wi]:
                                    art._solve_world(view, AS, wi, x, q, v, w, ap, use_bias, afw, abw)
                        elif c.joints and not only_free and (use_bias or Jt.relax):
                            # The joints: the Gauss-Seidel equality rows, then the tree (its
                            # factors rebuilt once the positions moved), in the biased solve
                            # and, with relax, the relax solve.
                            if Jt.eq_joints.size:
                                soft = use_bias and not Jt.thesis
                                br = Jt.eq_soft[0] if soft else 0.0
                                ms = Jt.eq_soft[1] if soft else 1.0
                                isc = Jt.eq_soft[2] if soft else 0.0
                                _equality_world(J, Jt.eq_joints, Jt.eq_kinds, Jt.iinv[wi], Jt.inv_mass, g, wi, x, v,
                                                w, s.lam_lin[wi], s.lam_ang[wi], broken, br, ms, isc, Jt.max_push,
                                                Jt.max_angular_push)
                            if Jt.tree:
                                terms = Jt.tree_soft[:, wi] if use_bias else unit
                                solve_world(T, layout, g.fpw[wi], g.fcw[wi], g.ra[wi], g.rb[wi], g.jt[wi], g.twist[wi],
                                            g.js[wi], g.c_swing[wi], g.twist_defined[wi], broken, Jt.iinv[wi], Jt.M[wi],
                                            Jt.M_inv[wi], x, q, v, w, s.lam_lin[wi], s.lam_ang[wi], s.lam_limit[wi],
                                            terms[0], terms[1], terms[2], use_bias, c.h, Jt.max_push,
                                            Jt.max_angular_push, Jt.limits, Jt.schur, Jt.active_set_passes,
                                            not factored, E, mask, Ja, Jb, Dinv, L, fw, bw, iw)
                                factored = True
                        if (part == 0) != c.contacts_first and c.joints and not only_free and Jt.gs_limit.size:
                            # The Gauss-Seidel limit rows, in every solve.
                            br = Jt.limit_soft[0] if use_bias else 0.0
                            ms = Jt.limit_soft[1] if use_bias else 1.0
                            isc = Jt.limit_soft[2] if use_bias else 0.0
                            if use_bias and Jt.zone_on:
                                zone, zs = Jt.zone[wi], Jt.zone_soft
                            else:
                                zone, zs = Jt.no_zone[wi], Jt.limit_soft
                            _limits_world(J, Jt.gs_limit, Jt.twist_row, Jt.swing_row, Jt.lower, Jt.upper, Jt.iinv[wi],
                                          g, wi, w, s.lam_limit[wi], broken, c.h, use_bias, br, ms, isc, zone, zs[0],
                                          zs[1], zs[2], Jt.margin, Jt.max_angular_push)


@kernel
def _copy_inertias(src, dst):
    """dst (N, 3, 3) = src."""
    for i in range(src.shape[0]):
        for r in range(3):
            for k in range(3):
                dst[i, r, k] = src[i, r, k]


# ------------------------------------------------------------------ the finite check
@kernel
def nonfinite(x, q, v, w, bad):
    """bad (W,) bool: the worlds with a NaN or infinite position,
    orientation, velocity or angular velocity (x, q, v, w (W, N, ...))."""
    for wi in range(x.shape[0]):
        ok = True
        for i in range(x.shape[1]):
            for k in range(3):
                if not (math.isfinite(x[wi, i, k]) and math.isfinite(v[wi, i, k]) and math.isfinite(w[wi, i, k])):
                    ok = False
            for k in range(4):
                if not math.isfinite(q[wi, i, k]):
                    ok = False
        bad[wi] = not ok


# ------------------------------------------------------------------ absent parts
def contact_row_arrays(R):
    """``ContactRowArrays`` of R rows, uninitialised (the step's rows, to be filled)."""
    e = np.empty
    return con.ContactRowArrays(
        w=e(R, dtype=np.int64), a=e(R, dtype=np.int64), b=e(R, dtype=np.int64), dyn_a=e(R, dtype=bool),
        dyn_b=e(R, dtype=bool), free=e(R, dtype=bool), inv_ma=e(R), inv_mb=e(R), n=e((R, 3)), t1=e((R, 3)),
        t2=e((R, 3)), valid=e((R, 4), dtype=bool), xa0=e((R, 3)), xb0=e((R, 3)), ra=e((R, 4, 3)), rb=e((R, 4, 3)),
        la=e((R, 4, 3)), lb=e((R, 4, 3)), sep0=e((R, 4)), ia=e((R, 3, 3)), ib=e((R, 3, 3)), mn=e((R, 4)),
        mt1=e((R, 4)), mt2=e((R, 4)), mu=e((R, 4)), e=e(R), lam_n=e((R, 4)), lam_t1=e((R, 4)), lam_t2=e((R, 4)),
        max_lam_n=e((R, 4)), s_close=e((R, 4)), vn_close=e((R, 4)))


@functools.cache
def no_columns():
    """(S, ap) without an articulated column: arrays of size 0 (and the
    starts' single 0) that no kernel writes, made once."""
    z = np.zeros
    S = art.ArticulatedArrays(
        held=z(0, dtype=np.int64), pt_start=z(1, dtype=np.int64), pt_row=z(0, dtype=np.int64),
        pt_slot=z(0, dtype=np.int64), row_start=z(1, dtype=np.int64), rows=z(0, dtype=np.int64),
        tree_bodies=z(0, dtype=np.int64), node=z(0, dtype=np.int64), order=z(0, dtype=np.int64),
        parent=z(0, dtype=np.int64), factors=z(0, dtype=np.int64), Dinv=z((0, 0, 6, 6)), L=z((0, 0, 6, 6)),
        M=z((0, 0, 6, 6)), body=z(0, dtype=np.int64), J=z((0, 6)), A=z(0), a_start=z(1, dtype=np.int64), m=z(0),
        mu=z(0), finite=z(0, dtype=bool))
    ap = art.SoftParams(h=0.0, bias_rate=0.0, mass_scale=1.0, impulse_scale=0.0, slop=0.0, max_push_out=0.0,
                        thesis=False, sweeps=0)
    return S, ap


@functools.cache
def no_contacts():
    """The contact arguments (C, R, S, p, ap) of a step without contact
    rows: arrays of size 0 that no kernel writes, made once."""
    R = contact_row_arrays(0)
    S, ap = no_columns()
    i0 = np.zeros(0, dtype=np.int64)
    p = con.SolverParams(h=0.0, bias_rate=0.0, mass_scale=1.0, impulse_scale=0.0, max_push_out=0.0, slop=0.0,
                         load_cap=1.0, g_mag=0.0, bouncy=False, thesis=False)
    C = ContactStep(on=False, order=i0, world_start=np.zeros(1, dtype=np.int64), world_rows=i0,
                    row_start=np.zeros(1, dtype=np.int64), bouncy=False, lam_n_step=np.zeros((0, 4)),
                    lam_t1_step=np.zeros((0, 4)), lam_t2_step=np.zeros((0, 4)), articulated=False)
    return C, R, S, p, ap


@functools.cache
def no_tree(num_bodies):
    """(T, layout) of a scene without a joint tree (made once per body count)."""
    from .tree import TreeLayout
    from .tree_solve import TreeRows

    i0, b0, f0 = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), np.zeros(0)
    T = TreeRows(joint=i0, a=i0, b=i0, hinge=b0, fixed=b0, ball=b0, ang_mask=np.zeros((0, 3)),
                 eq_mask=np.zeros((0, 6)), lo=f0, hi=f0, lo_finite=b0, hi_finite=b0,
                 limit_exists=np.zeros((0, 2), dtype=bool), cand_joint=i0, cand_slot=i0, bodies=i0, mass=f0,
                 inertia=np.zeros((0, 3)), inv_mass=np.zeros(num_bodies))
    layout = TreeLayout(order=i0, parent=i0, n_bodies=0, leaf=b0, ball=b0, child_is_b=b0, joint_child=i0)
    return T, layout


@functools.cache
def _no_joint_arrays():
    """``JointArrays`` of no joint (made once)."""
    from .joints import JointArrays

    i0 = np.zeros(0, dtype=np.int64)
    return JointArrays(kind=i0, parent=i0, child=i0, frame_p=np.zeros((0, 4)), frame_c=np.zeros((0, 4)),
                       anchor_p=np.zeros((0, 3)), anchor_c=np.zeros((0, 3)), cone=np.zeros((0, 2)))


def no_joints(num_worlds, num_bodies, inv_mass, inv_inertia):
    """The joint arguments (Jt, J, T, layout, g) of a scene without joints."""
    from .joints import empty_geometry

    W, N = num_worlds, num_bodies
    i0, b0, f0 = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), np.zeros(0)
    J = _no_joint_arrays()
    T, layout = no_tree(N)
    unit = np.array([0.0, 1.0, 0.0])
    Jt = JointStep(
        inv_mass=inv_mass, inv_inertia=inv_inertia, passive=False, passive_order=i0, stiffness=f0, damping=f0,
        rest=np.zeros((0, 3)), warm_order=i0, breakable=False, lin_sum=np.zeros((W, 0, 3)), ang_sum=np.zeros((W, 0)),
        relax=False, thesis=False, max_push=0.0, max_angular_push=0.0, eq_joints=i0, eq_kinds=i0, eq_soft=unit,
        gs_limit=i0, twist_row=b0, swing_row=b0, lower=f0, upper=f0, limit_soft=unit, zone_on=False,
        zone=np.zeros((W, 0), dtype=bool), no_zone=np.zeros((W, 0), dtype=bool), zone_soft=unit, margin=0.0,
        tree=False, tree_soft=np.zeros((3, W, 0)), limits=False, schur=False, active_set_passes=0, tree_metric=False,
        geometric=False, geo_joint=i0, geo_parent=i0, geo_child=i0, n_tree_loaded=0, weight=np.zeros((W, 0)),
        cap=0.0, load_before=np.zeros((W, 0)), rot=np.zeros((W, 0, 3, 3)), iinv_raw=np.zeros((W, 0, 3, 3)),
        iinv=np.zeros((W, 0, 3, 3)), M=np.zeros((W, 0, 6, 6)), M_inv=np.zeros((W, 0, 6, 6)))
    return Jt, J, T, layout, empty_geometry(W, 0)
