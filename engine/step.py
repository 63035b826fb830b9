"""One step of W worlds: the pipeline assembled from the effects a scene declares.

::

    step(model, state, control) -> state
      collide      contact candidates and manifolds, once per step (if contacts)
      prepare      constraint anchors and effective masses (if joints/contacts);
                   with articulated_contacts, the contact-space response of
                   the articulations on static bodies
      substeps     integrate velocities (force effects); implicit velocity effects;
                   warm start + biased solve (joints, then contacts; contacts
                   first with articulated_contacts); integrate positions; relax solve
                   (and further relax passes over the contacts of unjointed bodies)
      restitution  once, from the closing velocities before the solve
      end of step  static contact projection (bodies deeper than
                   static_contact_projection_depth, 2 cm by default, in a
                   static shape moved back out to it, positions only);
                   joint post-stabilisation (positions back onto the joints
                   beyond a slop: 0.2 mm for articulations touching something
                   or driven by a motor, 4 cm for the others by default);
                   where the contact projection moved something, more
                   rounds of both (contact_projection.ROUNDS in all),
                   breaking springs and joints, events,
                   non-finite check

The state is advanced in place and returned. Nothing here loops over worlds,
bodies, contacts or constraints of one colour; a batch larger than
``Settings.world_chunk`` goes through in slices of that many worlds, which
bounds the step's temporaries without changing a bit of any trajectory.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from . import contact_projection
from .articulated_contacts import ArticulatedContacts
from .control import Control
from .core import world
from .core.jit import over_worlds
from .errors import SimulationError
from .integrators import (
    _control_arrays,
    explicit_euler,
    integrate_positions,
    integrate_velocities,
    runge_kutta4,
    velocity_effects,
)
from .math3d import quat_integrate


def _check_control(model, state, control):
    if control is None:
        return None
    if not isinstance(control, Control):
        raise ValueError(f"control must be an engine.Control or None, got {type(control).__name__}")
    control.validate(model, state.num_worlds)
    return control


def _check_state(model, state):
    shape = state.position.shape
    if shape[1:] != (model.num_bodies, 3):
        raise ValueError(f"state has {shape[1]} bodies per world but the model has {model.num_bodies}: "
                         f"a state of another model?")


def step(model, state, control: Control | None = None):
    """Advance every world of ``state`` by ``model.settings.dt`` seconds, in place.

    control: motor torques and applied forces for this step (validated before
    anything changes: a wrong shape, NaN or infinity raises ValueError).
    Events of this step (broken springs and joints) are in ``state.events``.
    Raises SimulationError naming world, body and step when a world's state
    turns non-finite and ``settings.check_finite`` is set.
    """
    _check_state(model, state)
    control = _check_control(model, state, control)
    W, chunk = state.num_worlds, model.settings.world_chunk
    if chunk and W > chunk:
        # Slices of the world axis are views: each pass advances its worlds in place.
        events = []
        for lo in range(0, W, chunk):
            hi = min(lo + chunk, W)
            part = state.worlds(lo, hi)
            _advance(model, part, None if control is None else control.worlds(lo, hi))
            events += shift_worlds(part.events, lo)
        state.events = events
    else:
        _advance(model, state, control)
    if model.settings.check_finite:
        bad = state.nonfinite_worlds()
        if bad.size:
            raise _nonfinite_error(model, state, bad)
    return state


def shift_worlds(events, lo):
    """``events`` of a slice of worlds starting at ``lo``, renumbered to the whole batch."""
    return [replace(e, world=e.world + lo) for e in events]


def _advance(model, state, control):
    """The step of ``step`` on checked inputs, without the non-finite check."""
    s = model.settings
    h = s.dt / s.substeps
    events = []
    joints, contacts = (c if c is not None and c.has_constraints else None for c in (model.joints, model.contacts))
    # Without articulated contacts (SOFT_JOINTS): joints, then contacts, so the
    # contacts have the last word and nothing sinks.
    # With articulated contacts (the default) the contact impulses already keep the joint
    # rows (not the limits: they are not in the response), so the joints go
    # last and their limits hold exactly; the soft contacts take the small
    # velocity error up in the next sweep. The order is the scene's: rows that
    # keep the body-by-body solve (between two moving bodies, articulations
    # with loops) go first too. With the joints first, a limb resting on the
    # ground against its limit was pushed into it by every contact solve and
    # out of it by the next joint solve: 5 of 8 random drops
    # (ragdoll_drops_random, CLOSED_JOINTS) twitched at 3-8 cm/s to the end.
    order = (contacts, joints) if s.contacts_articulated else (joints, contacts)
    constraints = [c for c in order if c is not None]
    passive = model.joints is not None and model.joints.has_passive
    # The contacts' begin_step first: the joints choose their softness from the bodies in contact.
    touching = None
    if contacts is not None:
        contacts.begin_step(model, state, h)
        touching = contacts.bodies_in_contact(state)
    if joints is not None:
        joints.begin_step(model, state, h, touching, None if control is None else control.motor)
        if s.contacts_articulated and contacts is not None and contacts.rows is not None:
            contacts.rows.attach(ArticulatedContacts(model, state, contacts.rows, joints))
    if joints is None or joints.loop_rows is None:
        _compiled_substeps(model, state, control, joints, contacts, h, s.contacts_articulated)
    else:
        _substeps(model, state, control, constraints, h, passive)
    # Before the constraints' end_step: the joints' projection closes the
    # joints this move opens, and the contacts' restitution, which comes
    # first, takes the joint frames of the moved positions.
    moved = None if model.contacts is None else model.contacts.project_static(model, state)
    if moved is not None and model.joints is not None:
        model.joints.positions_moved()
    rounds = moved is not None and joints is not None and joints.projects_tree
    if rounds:
        broken = state.joint_broken[moved]  # before the joints' end_step breaks any
    for c in constraints:
        c.end_step(model, state, h, events)
    if rounds:
        _further_projection_rounds(model, state, moved, broken)
    if contacts is not None and contacts.rows is not None:
        contacts.rows.articulated = None  # its response matrices served this step only
    for effect in model.end_hooks:
        effect.end_of_step(model, state, events)
    state.step += 1
    state.events = events


_INTEGRATORS = {"symplectic": world.SYMPLECTIC, "euler": world.EULER, "rk4": world.RK4}


def _compiled_substeps(model, state, control, joints, contacts, h, contacts_first):
    """Every substep of every world in one kernel call (``engine.core.world``)."""
    s = model.settings
    W, N = state.num_worlds, model.num_bodies
    fx = model.effect_arrays
    rows = None if contacts is None else contacts.rows
    contact_args = world.no_contacts() if rows is None else rows.substep_arrays(h)
    joint_args = (world.no_joints(W, N, np.ascontiguousarray(model.inv_mass, dtype=float),
                                  np.ascontiguousarray(model.inv_inertia, dtype=float))
                  if joints is None else joints.substep_arrays(model, state))
    c = world.StepConstants(h=float(h), substeps=int(s.substeps), iterations=int(s.iterations),
                            relax_iterations=int(s.relax_iterations),
                            free_relax_passes=int(s.free_contact_relax_passes),
                            integrator=_INTEGRATORS[s.integrator], contacts_first=bool(contacts_first),
                            effects=bool(fx.springs.stiff.size or fx.damping.linear.size),
                            contacts=contacts is not None, joints=joints is not None)
    force, torque, motor = _control_arrays(control, W)
    broken = state.arrays.get("joint_broken")
    empty3 = np.zeros((W, 0, 3))  # a state without joints has no joint impulses
    arrays = world.StateArrays(
        x=state.position, q=state.orientation, v=state.velocity, w=state.angular_velocity,
        broken=np.zeros((W, 0), dtype=bool) if broken is None else broken,
        lam_lin=state.arrays.get("joint_linear_impulse", empty3),
        lam_ang=state.arrays.get("joint_angular_impulse", empty3),
        lam_limit=state.arrays.get("joint_limit_impulse", empty3), spring_broken=state.spring_broken,
        cforce=force, ctorque=torque, motor=motor)
    Jt, J, T, layout, g = joint_args
    over_worlds(world.substeps, (c, *contact_args, Jt, _model_arrays(model, J, T, layout), g, arrays), W)
    if rows is not None:
        rows.warm_starts = c.substeps
    if joints is not None:
        joints.finish_substeps(state, joint_args[0], c.substeps)


def _model_arrays(model, J, T, layout):
    """``engine.core.world.model_arrays`` of the model's joint, tree and
    effect arrays, made once and kept on the model while they are the same
    objects."""
    fx = model.effect_arrays
    key = (J, T, layout, fx)
    kept = getattr(model, "_substep_model_arrays", None)
    if kept is None or any(a is not b for a, b in zip(kept[0], key)):
        kept = (key, world.model_arrays(T, layout, J, fx.bodies, fx.gravitation, fx.springs, fx.motors, fx.damping))
        model._substep_model_arrays = kept
    return kept[1]


def _substeps(model, state, control, constraints, h, passive):
    """The substeps stage by stage (the loop rows' coupled solve is not compiled yet)."""
    s = model.settings
    for _ in range(s.substeps):
        if passive:
            # Passive joint springs and dampers act on the constrained velocities of
            # the last substep, before this substep's forces: applied after the motor
            # torques, an implicit damper on a light bone held by a contact (a foot
            # on the ground) took back most of the motor's torque before the contact
            # could answer it (an ankle passed 28% of its torque to the ground).
            model.joints.passive(model, state, h)
        if s.integrator == "symplectic":
            integrate_velocities(model, state, control, h)
            velocity_effects(model, state, h)
            _solve(model, state, constraints, h, use_bias=True)
            integrate_positions(model, state, h)
            _positions_moved(model, state, constraints)
            _solve(model, state, constraints, h, use_bias=False)
        elif s.integrator == "euler":
            explicit_euler(model, state, control, h)
            _positions_moved(model, state, constraints)
            velocity_effects(model, state, h)
            _solve(model, state, constraints, h, use_bias=True)
            _solve(model, state, constraints, h, use_bias=False)
        else:
            runge_kutta4(model, state, control, h)
            _positions_moved(model, state, constraints)
            v1, w1 = state.velocity.copy(), state.angular_velocity.copy()
            velocity_effects(model, state, h)
            _solve(model, state, constraints, h, use_bias=True)
            # Constraint impulses move the positions by h Δv beyond the RK4 flow.
            state.position += h * (state.velocity - v1)
            state.orientation[...] = quat_integrate(state.orientation, state.angular_velocity - w1, h)
            _positions_moved(model, state, constraints)
            _solve(model, state, constraints, h, use_bias=False)


def _further_projection_rounds(model, state, moved, broken):
    """Closing the joints that the static contact projection opened can turn
    another body of the chain into the ground (a shin 5.4 cm deep after its
    foot was moved out, benchmarks.scenes ragdoll_max_torque): up to
    ``contact_projection.ROUNDS`` rounds of both projections in turn, each
    round only in the worlds the one before moved something in, the joint
    projection's metric holding the points moved so far; then a world whose
    joints are still open is put back as without the contact projection
    (``joint_projection.undo_unfollowed_moves``; ``moved``: the worlds of the
    first round, ``broken``: their joints' broken flags before the step's
    end)."""
    worlds = moved
    for _ in range(contact_projection.ROUNDS - 1):
        worlds = model.contacts.project_static(model, state, worlds)
        if worlds is None:
            break
        model.joints.positions_moved()
        model.joints.project_positions(model, state, worlds)
    model.joints.undo_unfollowed_moves(model, state, model.contacts.projected, broken)


def _positions_moved(model, state, constraints):
    """The bodies moved and turned: the joint rows take their frames and world
    inverse inertias afresh. Contact rows keep the step's start (lever arms
    and inertias together, as in Box2D): refreshing their inertias alone or
    with their lever arms opened a ragdoll hitting the ground at 100 m/s by
    7 and 34 cm instead of 4 (benchmarks.stability ragdoll_impact_100)."""
    if model.joints is not None and model.joints in constraints:
        model.joints.positions_moved(model, state)


def _solve(model, state, constraints, h, use_bias):
    if not constraints:
        return
    if use_bias:
        for c in constraints:
            c.warm_start(model, state)
    iterations = model.settings.iterations if use_bias else model.settings.relax_iterations
    for _ in range(iterations):
        for c in constraints:
            c.solve(model, state, h, use_bias)
    if not use_bias and model.contacts in constraints:
        for _ in range(model.settings.free_contact_relax_passes):
            model.contacts.relax_free_bodies(model, state, h)


def _nonfinite_error(model, state, bad_worlds):
    w = int(bad_worlds[0])
    per_body = np.zeros(model.num_bodies, dtype=bool)
    for k in ("position", "orientation", "velocity", "angular_velocity"):
        a = state.arrays[k][w]
        per_body |= ~np.isfinite(a).all(axis=-1)
    if (per_body & model.dynamic).any():
        # Static bodies turn non-finite only by 0 · NaN from a moving one: name the moving ones.
        per_body &= model.dynamic
    bodies = [model.body_names[i] for i in np.flatnonzero(per_body)]
    step_no = int(state.step[w])
    return SimulationError(
        f"world {w} turned non-finite at step {step_no} (t = {step_no * model.settings.dt:.6g} s) "
        f"in bodies {bodies}; {bad_worlds.size} world(s) affected: {bad_worlds[:10].tolist()}",
        worlds=bad_worlds.tolist(), bodies=bodies, step=step_no,
    )


def simulate(model, state, steps: int, control=None):
    """Step ``steps`` times with the same control; returns the state."""
    for _ in range(int(steps)):
        step(model, state, control)
    return state
