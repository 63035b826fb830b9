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

from .math3d import cross, inverse_or_nan, quat_exp_integrate, quat_rotate
from .state import State

#: m: contact points closer than this to touching add to the projection's metric.
CONTACT_RANGE = 0.01
#: m: the lever arm that turns the linear slop into the lock rows' angular slop (rad).
ANGULAR_SLOP_LEVER = 0.25
#: rad: the most a pass may turn a body. Far from the manifold the linear step
#: overshoots: with the contact term a grounded foot is cheap to turn about its
#: contact, and at 2 substeps (benchmarks.accuracy's ragdoll) passes turned
#: links by 3 rad and left the anchors 0.34 m apart; with this cap 4 cm, the
#: slop. At 0.5 rad the 100 m/s ragdoll's first step could not close 0.5 m.
MAX_TURN = 1.0
#: A pass that left a world's error larger is retried at half its step at most
#: this many times (each retry one of the passes); then the world stops.
MAX_HALVINGS = 3
#: A world's passes stop once its error beyond the slop (the 2-norm over its
#: joints, angular rows at ANGULAR_SLOP_LEVER) is at most this fraction of the
#: slop; a joint must exceed the slop by more than it to start a projection.
TOLERANCE = 0.01
#: m: a world whose joints the passes leave more than this beyond their slop
#: after the static contact projection moved one of its bodies is projected
#: again from before the move (``undo_unfollowed_moves``).
MAX_OPENING_AFTER_MOVE = 0.002


def project_joints(js, model, state, worlds=None, moved=False):
    """Project the tree joints of ``js`` in place (see the module docstring);
    worlds with no error beyond the slop keep their state bit for bit.
    ``worlds``: only these (ascending; None: all). ``moved``: the points the
    static contact projection moved (``ProjectedPoints``) or None; by
    default ``model.contacts.projected``."""
    tree = js.tree
    keep = ~tree.loop_touched[tree.component]
    if not keep.any():
        return
    slop = _slops(js)
    need = _worlds_beyond_slop(js, tree, state, keep, [tuple(x * (1.0 + TOLERANCE) for x in sl) for sl in slop])
    if worlds is not None:
        need &= np.isin(np.arange(state.num_worlds), worlds)
    if not need.any():
        return  # the usual step: no Jacobians built
    # Only the worlds beyond the slop are projected, on a copy of their
    # positions (each world's arithmetic is its own, so the same bits as in a
    # projection of every world); the rest cost nothing more.
    worlds = np.flatnonzero(need)
    if moved is False:
        moved = model.contacts.projected if model.contacts is not None else None
    sub = _worlds_of(state, worlds)
    _project(js, tree, sub, keep, _slops_of(slop, worlds),
             _metric(tree, model, state, js.settings.joint_projection_contact_weight, worlds, moved),
             js.settings.joint_projection_passes)
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
    keep = ~tree.loop_touched[tree.component]
    if not keep.any():
        return
    slop = _slops(js)
    err = _merit(js, tree, _worlds_of(state, moved.worlds), keep, _slops_of(slop, moved.worlds))[2]
    redo = err > MAX_OPENING_AFTER_MOVE
    if not redo.any():
        return
    again = moved.worlds[redo]
    unmoved = State({"position": state.position.copy(), "orientation": state.orientation.copy(),
                     "joint_broken": state.joint_broken.copy()})
    unmoved.position[again] = moved.position_before[redo]
    unmoved.orientation[again] = moved.orientation_before[redo]
    unmoved.joint_broken[again] = broken[redo]
    project_joints(js, model, unmoved, again, moved=None)
    alt_err = _merit(js, tree, _worlds_of(unmoved, again), keep, _slops_of(slop, again))[2]
    back = again[alt_err < err[redo]]
    if back.size:
        state.position[back] = unmoved.position[back]
        state.orientation[back] = unmoved.orientation[back]
    js.positions_moved()


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
    lin = np.where(tight, s.joint_projection_slop, s.free_joint_projection_slop)
    loop = np.where(tight.any(axis=1, keepdims=True), s.joint_projection_slop, s.free_joint_projection_slop)
    return [(lin, lin / ANGULAR_SLOP_LEVER), (loop, loop / ANGULAR_SLOP_LEVER)]


def _project(js, tree, state, keep, slop, metric, passes):
    """At most ``passes`` Gauss-Newton passes on ``state`` (positions,
    orientations and broken flags of the worlds being projected); ``slop`` as
    ``_slops`` gives it, for those worlds. Returns each world's error beyond
    the slop at the end (the merit below, m)."""
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
        a, b, Ja, Jb, mask, C = rows
        back = np.zeros(state.num_worlds, dtype=bool)
        if before is not None:
            # A pass that left a world's error larger is taken back: the
            # linearisation does not hold that far out. The next pass tries
            # half that step from the same start (backtracking), up to
            # MAX_HALVINGS times, after which the world stops.
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
            if loops is None:
                mu = -tree._factor_solve(Ja, Jb, mask, C, M, M_inv=M_inv_tree)
                d = np.matmul(M_inv, tree._body_impulses(Ja, Jb, mu)[..., None])[..., 0]
            else:
                # Loop-closing joints (solved exactly with the tree): the coupled solve in the same metric.
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
    """(tree rows, loop rows or None, merit (W,) m) of ``state``: the rows'
    errors beyond the slop (in place of C), and the merit, the 2-norm of
    those errors, the angular rows at the slop's lever."""
    loops = js.loop_rows
    rows = tree.jacobians(js, state, True, 1.0, velocity=False, max_push_out=np.inf, max_angular_push_out=np.inf)
    C = rows[5]
    C *= keep[:, None]
    _beyond_slop(C, slop[0])
    err = _squared_error(C)
    lrows = None
    if loops is not None:
        lrows = tree.jacobians(js, state, True, 1.0, velocity=False, max_push_out=np.inf,
                               max_angular_push_out=np.inf, rows=loops)
        _beyond_slop(lrows[5], slop[1])
        err = err + _squared_error(lrows[5])
    return rows, lrows, np.sqrt(err)


def _worlds_beyond_slop(js, tree, state, keep, slop):
    """(W,) bool: worlds in which an active projected joint's anchor error
    exceeds its linear slop or its lock rows' angular error its angular one
    (``slop`` as ``_slops`` gives it). A
    hinge's error a_p × a_c is normal to a_p, so its two lock rows hold all of
    it; a fixed joint's rows are the whole vector; a ball joint has no lock rows."""
    need = np.zeros(state.num_worlds, dtype=bool)
    for rows, use, (lin_slop, ang_slop) in ((tree, keep, slop[0]), (js.loop_rows, True, slop[1])):
        if rows is None:
            continue
        idx = rows.joints
        a, b, fpw, fcw, ra, rb = js.frames(state, idx)
        lin, ang = rows._position_errors(state, a, b, fpw, fcw, ra, rb)
        locked = rows.ang_mask.any(axis=1)
        beyond = ((np.sqrt((lin ** 2).sum(axis=-1)) > lin_slop)
                  | (locked & (np.sqrt((ang ** 2).sum(axis=-1)) > ang_slop)))
        need |= (beyond & use & (js._active(state, idx) > 0)).any(axis=1)
    return need


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


def _metric(tree, model, state, weight, worlds, moved):
    """The projection's metric on the tree's bodies (len(worlds), tree bodies,
    6, 6) and its inverse on every body (len(worlds), N, 6, 6), zero for bodies
    outside the tree, for the given worlds of ``state``; ``moved``: the points
    the static contact projection moved out (``ProjectedPoints``) or None.
    Every world takes the same arithmetic whether or not another world has
    contacts, so a world projects bit for bit the same alone or in a batch."""
    W, N = state.position.shape[:2]
    P = np.zeros((W, N, 6, 6))
    rows = model.contacts.rows if model.contacts is not None and weight > 0 else None
    if rows is not None:
        _add_contact_metric(P, rows, model, state, weight)
    if moved is not None and weight > 0:
        # The points the static contact projection just moved out (engine.contact_projection), at full weight.
        lever = quat_rotate(state.orientation[moved.world, moved.body], moved.lever)
        _add_point_stiffness(P, moved.world, moved.body, lever, moved.normal, weight * model.mass[moved.body])
    M = tree.M[worlds] + P[worlds][:, tree.t.bodies]
    # A world already diverging gets the identity: its projection is garbage,
    # and it is reported non-finite after the step instead of stopping the batch.
    bad = ~np.isfinite(M).all(axis=(1, 2, 3))
    if bad.any():
        M[bad] = np.eye(6)
    M_inv = np.zeros((worlds.size, N, 6, 6))
    M_inv[:, tree.t.bodies] = inverse_or_nan(M)
    return M, M_inv


def _add_contact_metric(P, rows, model, state, weight):
    """Add k u uᵀ, u = (n, r × n), for every contact point within
    CONTACT_RANGE of touching to its dynamic bodies' blocks of P (W, N, 6, 6)."""
    sep = rows.separation(state)
    near = rows.valid & (sep < CONTACT_RANGE)
    ramp = np.clip((CONTACT_RANGE - sep) / CONTACT_RANGE, 0.0, 1.0)
    for moves, body, local in ((rows.dyn_b, rows.b, rows.lb), (rows.dyn_a, rows.a, rows.la)):
        for j in range(near.shape[1]):
            on = near[:, j] & moves
            if not on.any():
                continue
            lever = quat_rotate(state.orientation[rows.w[on], body[on]], local[on, j])  # at the current orientation
            _add_point_stiffness(P, rows.w[on], body[on], lever, rows.n[on], weight * model.mass[body[on]] * ramp[on, j])


def _add_point_stiffness(P, world, body, lever, normal, k):
    """Add k u uᵀ, u = (n, r × n), to P's (world, body) blocks: a spring of
    stiffness k against moving the point at lever r along n."""
    u = np.concatenate((normal, cross(lever, normal)), axis=-1)
    np.add.at(P, (world, body), k[:, None, None] * u[:, :, None] * u[:, None, :])
