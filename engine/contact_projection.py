"""Static contact post-stabilisation: after the step, a body that ends deeper
than ``static_contact_projection_depth`` in a static shape (the ground, a
fixed box) is moved back out to that depth along the contact normal:
positions only, velocities as the solve left them (Cline & Pai 2003,
"Post-stabilization for rigid body simulation with contact and
constraints", here for the contacts with the world only).

The velocity solve holds contacts only as well as its rows see them within
the step, and under extreme motion they do not see everything:

* a row's separation follows a material point of its body with the step's
  start normal; a point on a fast-spun capsule's surface turns away from the
  ground while the capsule's end does not (a forearm read 2.4 cm deep while
  it was 11.1 cm deep);
* a box's manifold is its 4 deepest corners at the step's start; a foot
  tilted more than about 17° on its heel has the heel's 4 there and its toe,
  slapping down within the step, in no row;
* the joint limits are solved after the contacts, and a foot held down by
  its ankle limit is pushed into the ground by them.

Under random maximum torques on every joint of the humanoid (16 worlds x 500
steps of ``benchmarks.scenes.ragdoll_max_torque``, seed 0) limbs went 10.4
cm deep; exact narrow phase at the step's end and this projection at 2 cm
(the default) leave 2.4 cm at worst.

The move opens the body's joints; the joint projection that follows
(:mod:`engine.joint_projection`) closes them again, with the moved points in
its metric as stiff contact points (``ProjectedPoints``), so that it moves the
rest of the chain rather than the body back into the ground. Closing them
can still turn another body of the chain in (a shin 5.4 cm deep after its
foot was moved out), so the two projections take ``ROUNDS`` turns, each
round only in the worlds the one before moved something in, the metric
holding every point moved so far. A world whose joints the passes cannot
close after a move (a foot moved 8.2 cm out left its ankle 7.7 cm open) is
projected again from before the move, as without this projection
(``joint_projection.MAX_OPENING_AFTER_MOVE``). Only contacts
with static bodies are projected: between two moving bodies the solve's
impulses are the only arbiter of who moves.

Its trials on by default before these rounds and that fallback reached
failures of other parts in the long maximum-torque runs, fixed since: the
ball joints' limit rows grew without bound near a swing of pi
(``joints.TWIST_LIMIT_MAX_SWING``), and the joint projection stopped at a
pass that overshot (it now halves the step).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .collision import aabb, collide_rows, overlapping
from .math3d import quat_rotate_inv
from .scatter import occurrence_rank

#: Rounds of the static contact projection and the joint projection in turn
#: at a step's end (``engine.step``): the joints' closing can move another body
#: of the chain into the ground, which the next round moves out again.
ROUNDS = 3
#: m: the least excess over the depth that moves a body.
MIN_MOVE = 1e-9


class ProjectedPoints(NamedTuple):
    """The contact points of the bodies moved by ``project_static_contacts``:
    every point of their manifolds with the static shapes they were moved out
    of; and the worlds they are in, with those worlds' positions and
    orientations from before the move, so that a world whose joints cannot
    follow the move can be put back."""

    world: np.ndarray   # (K,) world index
    body: np.ndarray    # (K,) dynamic body index
    lever: np.ndarray   # (K, 3) m, from the body's centre to the point, in the body's frame
    normal: np.ndarray  # (K, 3) unit normal, out of the static shape
    worlds: np.ndarray              # (M,) the worlds with a moved body, ascending
    position_before: np.ndarray     # (M, N, 3) m, their body positions before the move
    orientation_before: np.ndarray  # (M, N, 4) their orientations then


def project_static_contacts(contacts, model, state, depth: float, worlds=None) -> ProjectedPoints | None:
    """Move the dynamic body of every (world, static pair) deeper than
    ``depth`` (m) back out to ``depth``, in place; returns the points of the
    moved bodies' manifolds with the shapes they were moved out of, or None
    when nothing moved. ``worlds``: ascending indices of the worlds to look
    at (None: all). Each world's arithmetic is its own (a world moves the
    same alone or in a batch), and worlds with nothing that deep keep their
    positions bit for bit."""
    idx = contacts.static_pairs
    if idx.size == 0 or not np.isfinite(depth):
        return None
    pos, quat = state.position, state.orientation
    if worlds is None:
        lo, hi = aabb(model.shape_type, model.shape_params, pos, quat)
    else:
        lo, hi = aabb(model.shape_type, model.shape_params, pos[worlds], quat[worlds])
    # Boxes shrunk by depth / 2 on every side overlap only where the shapes may be that deep.
    over = overlapping(lo, hi, contacts.pair_a[idx], contacts.pair_b[idx], -0.5 * depth)
    s_idx, w_idx = np.nonzero(over.T)  # sorted by pair, then world
    if worlds is not None:
        w_idx = worlds[w_idx]
    if w_idx.size == 0:
        return None
    p_idx = idx[s_idx]
    a, b = contacts.pair_a[p_idx], contacts.pair_b[p_idx]
    # Exact narrow phase of those rows, every point kept (the margin is unbounded).
    m = collide_rows(contacts.pair_kind[p_idx], pos[w_idx, a], quat[w_idx, a], model.shape_params[a],
                     pos[w_idx, b], quat[w_idx, b], model.shape_params[b], np.inf)
    normal, point, sep, valid = m.normal, m.point, m.separation, m.valid
    excess = -sep.min(axis=1) - depth  # m beyond the allowed depth
    # Not 0: a body moved out to the depth reads it again to a last bit.
    deep = excess > MIN_MOVE
    if not deep.any():
        return None
    w, a, b, n = w_idx[deep], a[deep], b[deep], normal[deep]
    # The normal points from a to b: b moves along it, a against it.
    moves_b = model.dynamic[b]
    body = np.where(moves_b, b, a)
    out = np.where(moves_b, 1.0, -1.0)[:, None] * n
    # Every point of a moved body's manifold, however far (the margin is
    # unbounded), goes to the metric: pinned along the normal at the points
    # that hold it up (3 or more for a box), the body can only slide and
    # turn in the plane, so closing its joints cannot turn another corner in.
    k_row, k_slot = np.nonzero(valid[deep])
    wk, bk = w[k_row], body[k_row]
    moved = np.unique(w)
    points = ProjectedPoints(wk, bk, quat_rotate_inv(quat[wk, bk], point[deep][k_row, k_slot] - pos[wk, bk]),
                             out[k_row], moved, pos[moved], quat[moved])
    shift = _moves(w, body, excess[deep], out, pos.shape)
    pos[w, body] += shift[w, body]
    return points


def merged(first, then):
    """The points of two rounds of moves as one: a body moved again keeps
    only the later round's points; the worlds and their state before are the
    first round's (a round looks only at worlds the one before moved)."""
    if first is None:
        return then
    n = first.position_before.shape[1]
    keep = ~np.isin(first.world * n + first.body, then.world * n + then.body)
    return ProjectedPoints(*(np.concatenate((x[keep], y)) for x, y in zip(first[:4], then[:4])), *first[4:])


def _moves(w, body, excess, out, shape):
    """Each (world, body)'s translation (shape of the positions, m): out of
    its static shapes one after another in pair order, each move only what the
    moves before it left, max(0, excess_i - d·n_i) n_i, so a body deep in two
    coplanar shapes (a floor of tiles) moves out once, not twice."""
    shift = np.zeros(shape)
    rank = occurrence_rank(w * shape[1] + body)  # the rows are in pair order
    for r in range(int(rank.max()) + 1):  # rows of one rank have distinct (world, body)
        k = rank == r
        wk, bk, nk = w[k], body[k], out[k]
        left = np.maximum(excess[k] - (shift[wk, bk] * nk).sum(axis=-1), 0.0)
        shift[wk, bk] += left[:, None] * nk
    return shift
