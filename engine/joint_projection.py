"""Joint post-stabilisation: after the step, move the positions (not the
velocities) back onto the tree joints (Cline & Pai 2003, "Post-stabilization
for rigid body simulation with contact and constraints").

The velocity-level solve keeps the anchors of a joint together only to first
order: a link turning at ω drifts by about |ω|² h² |r| / 2 per substep, and the
soft joints of an articulation in contact stretch under load. Under random
maximum torques the humanoid's anchors opened by 13 cm with soft joints (9 mm
at ``ACCURATE``) and at a 100 m/s impact by 0.5 m. Each projection pass is
one Gauss-Newton step of C(q + Δq) = 0 over the tree, solved exactly with the
tree solver's factorisation:

    (J W⁻¹ Jᵀ) μ = -C,    Δq = W⁻¹ Jᵀ μ

where W is the metric the step is measured in: the bodies' mass matrices, plus
a stiff term k u uᵀ for every contact point near the ground, u = (n, r × n),
k = ``joint_projection_contact_weight`` × the body's mass (smoothly to 0 at
``CONTACT_RANGE``). Without that term the projection undid landings: it closed
the stretched ankle of a dropped ragdoll by turning the light foot, whose toe
went 13 cm into the ground (24 mm without projection); with it the ground
holds the foot and the leg moves instead (14 mm). A body the static contact
projection has just moved out of the ground (:mod:`engine.contact_projection`)
adds the term at every point of its manifold with it, at full weight (on top of
its rows' own terms), so the projection does not turn it back in.

Each pass turns no body by more than ``MAX_TURN``, and a pass that leaves a
world's error larger is taken back and tried again at half its step (up to
``MAX_HALVINGS`` times, each retry one of the passes): when the static contact
projection moved a forearm 9.4 cm out of the ground, the full step opened the
elbow from 9.2 to 9.6 cm, and stopping there left it 9.2 cm open; half of it
and two more passes closed it to the slop. A world
stops once its error beyond the slop is within ``TOLERANCE`` of the slop: the
passes converge linearly, about 50-70 times per pass under random maximum
torques (8.1e-2, 4.6e-3, 6.6e-5, 8.6e-7 m beyond the 4 cm slop), so
at a 4 cm slop two passes usually leave under 0.4 mm, where the four
that always ran before went on to 1e-8 m at nearly twice the projection's
time (five Jacobians and four factorisations against three and two).

Only errors beyond the slop are projected, back to the slop: a soft joint
carries its static load by its stretch, and taking that stretch away every
step made a resting ragdoll's foot chatter at 0.1-0.25 m/s (soft joints,
``SOFT_JOINTS``: 4 cm). The defaults' rigid joints are held at
``joint_projection_slop`` (0.2 mm) where their articulation touches
something or a motor drives it, and at ``free_joint_projection_slop`` (4 cm)
where it is passive in the air: the projection moves positions, not
velocities, and the next rigid solve takes out the velocity left off the
moved joints, which drained 16% of a swinging double pendulum's energy in
20 s at 0.2 mm. A world's passes stop at 1% of its smallest slop.
Loop-closing joints solved with the tree (``joint_loops`` "exact") are
projected with it, by the same Schur complement; articulations whose loop
rows are Gauss-Seidel are left to the velocity solve: the tree's projection
alone pushed the error into the loop rows (a 10x10 grid of ball joints
opened 82 mm instead of 38 mm).
"""

from __future__ import annotations

import numpy as np

from .core import joint_projection as kernels
from .core.joint_projection import (
    ANGULAR_SLOP_LEVER,
    CONTACT_RANGE,
    MAX_HALVINGS,
    MAX_TURN,
    TOLERANCE,
)
from .math3d import quat_exp_integrate
from .state import State

__all__ = ["ANGULAR_SLOP_LEVER", "CONTACT_RANGE", "MAX_HALVINGS", "MAX_OPENING_AFTER_MOVE", "MAX_TURN", "TOLERANCE",
           "project_joints", "undo_unfollowed_moves"]

#: m: a world whose joints the passes leave more than this beyond their slop
#: after the static contact projection moved one of its bodies is projected
#: again from before the move (``undo_unfollowed_moves``).
MAX_OPENING_AFTER_MOVE = 0.002


def project_joints(js, model, state, worlds=None, moved=False):
    """Project the tree joints of ``js`` in place (see the module docstring);
    worlds with no error beyond the slop keep their state bit for bit.
    ``worlds``: only these (ascending; None: all). ``moved``: the points the
    static contact projection moved (``ProjectedPoints``) or None; by
    default ``model.contacts.projected``. Each world is projected by one
    kernel call (:mod:`engine.core.joint_projection`), so a world projects
    bit for bit the same alone or in a batch; models with loop-closing joints
    solved with the tree (``joint_loops`` "exact") take the numpy passes of
    ``_project_with_loops`` on the same metric."""
    tree = js.tree
    keep = _keep(tree)
    if not keep.any():
        return
    slop = _slops(js)
    cand = (np.arange(state.num_worlds, dtype=np.int64) if worlds is None
            else np.ascontiguousarray(worlds, dtype=np.int64))
    need = _beyond_slop_worlds(js, tree, state, keep, slop, cand)
    if not need.any():
        return  # the usual step: no Jacobians built
    worlds = cand[need]
    if moved is False:
        moved = model.contacts.projected if model.contacts is not None else None
    weight = float(js.settings.joint_projection_contact_weight)
    terms = _contact_terms(model, state, weight, moved)
    passes = int(js.settings.joint_projection_passes)
    if js.loop_rows is None:
        kernels.project_batch(tree.arrays, tree.layout, js.arrays, worlds, keep, slop[0][0], state.position,
                              state.orientation, state.joint_broken, tree.M, model.mass, weight, *terms, passes,
                              np.empty(worlds.size))
    else:
        N = state.position.shape[1]
        M, M_inv = np.empty((worlds.size, tree.t.n_bodies, 6, 6)), np.empty((worlds.size, N, 6, 6))
        kernels.metric_batch(tree.arrays, worlds, state.orientation, tree.M, model.mass, weight, *terms, M, M_inv)
        sub = _worlds_of(state, worlds)
        _project_with_loops(js, tree, sub, keep, _slops_of(slop, worlds), (M, M_inv), passes)
        state.position[worlds] = sub.position
        state.orientation[worlds] = sub.orientation
    js.positions_moved()


def undo_unfollowed_moves(js, model, state, moved, broken):
    """After the last round of the static contact projection and this
    projection: where the contact projection moved a body (``moved``, its
    ``ProjectedPoints``) and the joints are left more than
    ``MAX_OPENING_AFTER_MOVE`` beyond their slop, project the world again
    from its positions before the move (``broken``: its joints' broken flags
    then), without the moved points in the metric: the step without the
    contact projection, bit for bit; and keep whichever of the two leaves
    the smaller error."""
    tree = js.tree
    keep = _keep(tree)
    if not keep.any():
        return
    slop = _slops(js)
    err = _merits(js, tree, state, np.ascontiguousarray(moved.worlds, dtype=np.int64), keep, slop)
    redo = err > MAX_OPENING_AFTER_MOVE
    if not redo.any():
        return
    again = np.ascontiguousarray(moved.worlds[redo], dtype=np.int64)
    unmoved = State({"position": state.position.copy(), "orientation": state.orientation.copy(),
                     "joint_broken": state.joint_broken.copy()})
    unmoved.position[again] = moved.position_before[redo]
    unmoved.orientation[again] = moved.orientation_before[redo]
    unmoved.joint_broken[again] = broken[redo]
    project_joints(js, model, unmoved, again, moved=None)
    alt_err = _merits(js, tree, unmoved, again, keep, slop)
    back = again[alt_err < err[redo]]
    if back.size:
        state.position[back] = unmoved.position[back]
        state.orientation[back] = unmoved.orientation[back]
    js.positions_moved()


def _keep(tree):
    """(tree joints,) bool: the joints projected, those of articulations
    without Gauss-Seidel loop rows."""
    return np.ascontiguousarray(~tree.loop_touched[tree.component])


def _beyond_slop_worlds(js, tree, state, keep, slop, worlds):
    """(len(worlds),) bool: the worlds in which an unbroken projected joint
    (or loop-closing joint solved with the tree) is beyond its slop widened
    by TOLERANCE (``engine.core.joint_projection.beyond_slop``)."""
    need = np.zeros(worlds.size, dtype=bool)
    kernels.beyond_slop_batch(tree.arrays, js.arrays, worlds, keep, slop[0][0], state.position, state.orientation,
                              state.joint_broken, need)
    loops = js.loop_rows
    if loops is not None:
        nl = loops.joints.size
        lin = np.ascontiguousarray(np.broadcast_to(slop[1][0], (state.num_worlds, nl)))
        more = np.zeros(worlds.size, dtype=bool)
        kernels.beyond_slop_batch(loops.arrays, js.arrays, worlds, np.ones(nl, dtype=bool), lin, state.position,
                                  state.orientation, state.joint_broken, more)
        need |= more
    return need


def _merits(js, tree, state, worlds, keep, slop):
    """The merit (len(worlds),) m of the given worlds of ``state``: the
    2-norm of the errors beyond the slop, angular rows at ANGULAR_SLOP_LEVER."""
    if js.loop_rows is not None:
        return _merit(js, tree, _worlds_of(state, worlds), keep, _slops_of(slop, worlds))[2]
    err = np.empty(worlds.size)
    kernels.merit_batch(tree.arrays, js.arrays, worlds, keep, slop[0][0], state.position, state.orientation,
                        state.joint_broken, err)
    return err


_NO_ROWS = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=bool), np.zeros(0, dtype=bool), np.zeros((0, 4, 3)), np.zeros((0, 4, 3)),
            np.zeros((0, 3)), np.zeros((0, 4), dtype=bool), np.zeros((0, 4)))
_NO_POINTS = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)))


def _contact_terms(model, state, weight, moved):
    """The contact inputs of the projection's metric for the kernels
    (``engine.core.joint_projection.metric``): the step's contact rows
    (``ContactRows``) grouped by world, in row order within a world, with
    their separations at ``state``; and the points the static contact
    projection moved (``moved``, ``ProjectedPoints``, or None), by world.
    Nothing with ``weight`` 0."""
    W = state.num_worlds
    rows = model.contacts.rows if model.contacts is not None and weight > 0 else None
    if rows is None or rows.w.size == 0:
        row_start = np.zeros(W + 1, dtype=np.int64)
        row_terms = _NO_ROWS
    else:
        # The rows world by world, in row order within a world (ContactRows' counting sort).
        row_start = rows.row_start
        c = np.ascontiguousarray
        row_terms = (rows.world_rows, c(rows.a, dtype=np.int64), c(rows.b, dtype=np.int64), c(rows.dyn_a, dtype=bool),
                     c(rows.dyn_b, dtype=bool), c(rows.la, dtype=float), c(rows.lb, dtype=float),
                     c(rows.n, dtype=float), c(rows.valid, dtype=bool), c(rows.separation(state), dtype=float))
    if moved is None or weight <= 0:
        m_start = np.zeros(W + 1, dtype=np.int64)
        points = _NO_POINTS
    else:
        m_start = np.searchsorted(moved.world, np.arange(W + 1)).astype(np.int64)
        c = np.ascontiguousarray
        points = (c(moved.body, dtype=np.int64), c(moved.lever, dtype=float), c(moved.normal, dtype=float))
    return (row_start,) + row_terms + (m_start,) + points


def _worlds_of(state, worlds):
    """A state of the given worlds' positions, orientations and joints'
    broken flags (copies): what the projection reads and moves."""
    return State({k: state.arrays[k][worlds] for k in ("position", "orientation", "joint_broken")})


def _slops_of(slop, worlds):
    """``_slops``' arrays for the given worlds."""
    return [tuple(x[worlds] for x in sl) for sl in slop]


def _slops(js):
    """[(linear m, angular rad) for the tree rows, each (W, tree joints); the
    same for the loop rows, each (W, 1)]: ``joint_projection_slop`` for the
    joints of articulations touching something or driven by a motor this
    step (``JointSet.components_held_tight``), ``free_joint_projection_slop``
    for the others. A loop row takes the tighter slop in a world where any
    articulation is held tight."""
    s, tree = js.settings, js.tree
    tight = js.components_held_tight[:, tree.component]
    lin = np.ascontiguousarray(np.where(tight, s.joint_projection_slop, s.free_joint_projection_slop), dtype=float)
    loop = np.where(tight.any(axis=1, keepdims=True), s.joint_projection_slop, s.free_joint_projection_slop)
    return [(lin, lin / ANGULAR_SLOP_LEVER), (loop, loop / ANGULAR_SLOP_LEVER)]


def _project_with_loops(js, tree, state, keep, slop, metric, passes):
    """The passes of ``engine.core.joint_projection.project`` for a model
    with loop-closing joints solved with the tree (``js.loop_rows``), in
    numpy: the tree rows and the loop rows solved together in the metric
    (``tree.solve_coupled``), the merit over both. ``state``: positions,
    orientations and broken flags of the worlds being projected; ``slop`` as
    ``_slops`` gives it, for those worlds; ``metric``: (M, M_inv) of those
    worlds (``engine.core.joint_projection.metric``). Returns each world's
    merit at the end (m)."""
    tree_slop = slop[0]
    stop = TOLERANCE * np.where(keep, tree_slop[0], np.inf).min(axis=1)  # m, per world (projected joints)
    M, M_inv = metric
    M_inv_tree = M_inv[:, tree.t.bodies]  # the leaf bodies' pivots
    loops = js.loop_rows
    done = np.zeros(state.num_worlds, dtype=bool)
    halvings = np.zeros(state.num_worlds, dtype=int)
    before = moved = last = None
    for k in range(passes + 1):
        rows, lrows, err = _merit(js, tree, state, keep, slop)
        _, _, Ja, Jb, mask, _ = rows
        back = np.zeros(state.num_worlds, dtype=bool)
        if before is not None:
            # A pass that left a world's error larger is taken back and tried
            # at half its step (as in the kernel).
            worse = moved & (err > before[0])
            halvings = np.where(worse, halvings + 1, np.where(moved, 0, halvings))
            if worse.any():
                w = worse[:, None, None]
                state.position[...] = np.where(w, before[1], state.position)
                state.orientation[...] = np.where(w, before[2], state.orientation)
                err = np.where(worse, before[0], err)
                done |= worse & (halvings > MAX_HALVINGS)
                back = worse & ~done
        worlds = (err > stop) & ~done
        if k == passes or not worlds.any():
            return err
        if (worlds & ~back).any():
            mask *= keep[:, None]
            mu, mu_l = tree.solve_coupled(rows, lrows, loops, lambda v, w: np.matmul(M_inv[w], v), M, M_inv_tree)
            imp = tree._body_impulses(Ja, Jb, -mu) + tree._body_impulses(lrows[2], lrows[3], -mu_l, loops)
            d = np.matmul(M_inv, imp[..., None])[..., 0]
            # At most MAX_TURN rad for any body per pass, the whole world's step scaled alike.
            turn = np.sqrt((d[..., 3:] ** 2).sum(axis=-1)).max(axis=1)
            d *= (MAX_TURN / np.maximum(turn, MAX_TURN))[:, None, None]
        else:
            d = np.zeros_like(last)
        if back.any():
            d = np.where(back[:, None, None], 0.5 * last, d)
        before = (err, state.position.copy(), state.orientation.copy())
        moved, last = worlds, d
        # Only bodies that move are touched (a renormalised quaternion can differ in its last bit).
        body = worlds[:, None] & (d != 0.0).any(axis=-1)
        state.position[...] = np.where(body[..., None], state.position + d[..., :3], state.position)
        state.orientation[...] = np.where(body[..., None], quat_exp_integrate(state.orientation, d[..., 3:], 1.0),
                                          state.orientation)


def _merit(js, tree, state, keep, slop):
    """(tree rows, loop rows, merit (W,) m) of ``state`` for a model with
    loop rows solved with the tree: the rows' errors beyond the slop (in
    place of C), and the merit, the 2-norm of those errors over both, the
    angular rows at the slop's lever."""
    loops = js.loop_rows
    rows = tree.jacobians(js, state, True, 1.0, velocity=False, max_push_out=np.inf, max_angular_push_out=np.inf)
    C = rows[5]
    C *= keep[:, None]
    _beyond_slop(C, slop[0])
    lrows = tree.jacobians(js, state, True, 1.0, velocity=False, max_push_out=np.inf,
                           max_angular_push_out=np.inf, rows=loops)
    _beyond_slop(lrows[5], slop[1])
    return rows, lrows, np.sqrt(_squared_error(C) + _squared_error(lrows[5]))


def _squared_error(C):
    """Σ of the squared rows (W,), the angular rows (3-5) at ANGULAR_SLOP_LEVER (m²)."""
    return (C[..., :3] ** 2).sum(axis=(1, 2)) + ANGULAR_SLOP_LEVER ** 2 * (C[..., 3:] ** 2).sum(axis=(1, 2))


def _beyond_slop(C, slop):
    """Shrink each joint's linear (rows 0-2) and angular (rows 3-5) error
    (C: (W, joints, 6)) by its slop ((W, joints) or (W, 1) each), in place:
    what is left is the error beyond the slop."""
    for rows, allowed in ((slice(0, 3), slop[0]), (slice(3, 6), slop[1])):
        norm = np.sqrt((C[..., rows] ** 2).sum(axis=-1, keepdims=True))
        C[..., rows] *= np.maximum(0.0, 1.0 - allowed[..., None] / np.maximum(norm, 1e-300))
