"""Joint post-stabilisation: after the step, move the positions (not the
velocities) back onto the tree joints (Cline & Pai 2003, "Post-stabilization
for rigid body simulation with contact and constraints").

The velocity-level solve keeps the anchors of a joint together only to first
order: a link turning at ω drifts by about |ω|² h² |r| / 2 per substep, and the
soft joints of an articulation in contact stretch under load. Under random
maximum torques the humanoid's anchors opened by 9 cm and at a 100 m/s impact
by 0.5 m. Each projection pass is one Gauss-Newton step of C(q + Δq) = 0 over
the tree, solved exactly with the tree solver's factorisation:

    (J W⁻¹ Jᵀ) μ = -C,    Δq = W⁻¹ Jᵀ μ

where W is the metric the step is measured in: the bodies' mass matrices, plus
a stiff term k u uᵀ for every contact point near the ground, u = (n, r × n),
k = ``joint_projection_contact_weight`` × the body's mass (smoothly to 0 at
``CONTACT_RANGE``). Without that term the projection undid landings: it closed
the stretched ankle of a dropped ragdoll by turning the light foot, whose toe
went 13 cm into the ground (24 mm without projection); with it the ground
holds the foot and the leg moves instead (14 mm).

Only errors beyond ``joint_projection_slop`` are projected, back to the slop:
a soft joint carries its static load by its stretch, and taking that stretch
away every step made a resting ragdoll's foot chatter at 0.1-0.25 m/s.
Articulations with loop-closing joints are left to the velocity solve: the
tree's projection pushed the error into the loop rows (a 10x10 grid of ball
joints opened 82 mm instead of 38 mm).
"""

from __future__ import annotations

import numpy as np

from .math3d import cross, quat_exp_integrate

#: m: contact points closer than this to touching add to the projection's metric.
CONTACT_RANGE = 0.01
#: m: the lever arm that turns the linear slop into the lock rows' angular slop (rad).
ANGULAR_SLOP_LEVER = 0.25


def project_joints(js, model, state):
    """Project the tree joints of ``js`` in place (see the module docstring);
    worlds with no error beyond the slop keep their state bit for bit."""
    tree = js.tree
    s = js.settings
    keep = ~tree.loop_touched[tree.component]
    if not keep.any():
        return
    slop = (s.joint_projection_slop, s.joint_projection_slop / ANGULAR_SLOP_LEVER)
    metric = None
    for _ in range(s.joint_projection_passes):
        a, b, Ja, Jb, mask, C = tree.jacobians(js, state, True, 1.0, velocity=False,
                                               max_push_out=np.inf, max_angular_push_out=np.inf)
        C *= keep[:, None]
        _beyond_slop(C, slop)
        worlds = np.abs(C).max(axis=(1, 2)) > 0.0
        if not worlds.any():
            return
        if metric is None:
            metric = _metric(tree, model, state, s.joint_projection_contact_weight)
        M, M_inv = metric
        mask *= keep[:, None]
        mu = -tree._substitute(tree._factor(Ja, Jb, mask, M), C)
        d = np.matmul(M_inv, tree._body_impulses(Ja, Jb, mu)[..., None])[..., 0]
        dx, dtheta = d[..., :3], d[..., 3:]
        w = worlds[:, None, None]
        state.position[...] = np.where(w, state.position + dx, state.position)
        state.orientation[...] = np.where(w, quat_exp_integrate(state.orientation, dtheta, 1.0), state.orientation)
        js.positions_moved()


def _beyond_slop(C, slop):
    """Shrink each joint's linear (rows 0-2) and angular (rows 3-5) error by
    its slop, in place: what is left is the error beyond the slop."""
    for rows, allowed in ((slice(0, 3), slop[0]), (slice(3, 6), slop[1])):
        norm = np.sqrt((C[..., rows] ** 2).sum(axis=-1, keepdims=True))
        C[..., rows] *= np.maximum(0.0, 1.0 - allowed / np.maximum(norm, 1e-300))


def _metric(tree, model, state, weight):
    """The projection's metric on the tree's bodies (W, tree bodies, 6, 6) and
    its inverse on every body (W, N, 6, 6), zero for bodies outside the tree.
    Every world takes the same arithmetic whether or not another world has
    contacts, so a world projects bit for bit the same alone or in a batch."""
    W, N = state.position.shape[:2]
    P = np.zeros((W, N, 6, 6))
    rows = model.contacts.rows if model.contacts is not None and weight > 0 else None
    if rows is not None:
        _add_contact_metric(P, rows, model, state, weight)
    M = tree.M + P[:, tree.t.bodies]
    M_inv = np.zeros((W, N, 6, 6))
    M_inv[:, tree.t.bodies] = np.linalg.inv(M)
    return M, M_inv


def _add_contact_metric(P, rows, model, state, weight):
    """Add k u uᵀ, u = (n, r × n), for every contact point within
    CONTACT_RANGE of touching to its dynamic bodies' blocks of P (W, N, 6, 6)."""
    sep = rows.separation(state)
    near = rows.valid & (sep < CONTACT_RANGE)
    ramp = np.clip((CONTACT_RANGE - sep) / CONTACT_RANGE, 0.0, 1.0)
    for moves, body, lever in ((rows.dyn_b, rows.b, rows.rb), (rows.dyn_a, rows.a, rows.ra)):
        for j in range(near.shape[1]):
            on = near[:, j] & moves
            if not on.any():
                continue
            u = np.concatenate((rows.n[on], cross(lever[on, j], rows.n[on])), axis=-1)
            k = weight * model.mass[body[on]] * ramp[on, j]
            np.add.at(P, (rows.w[on], body[on]), k[:, None, None] * u[:, :, None] * u[:, None, :])
