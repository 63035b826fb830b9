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

The arithmetic is the kernels' of :mod:`engine.core.projection`, one world
at a time.

Its trials on by default before these rounds and that fallback reached
failures of other parts in the long maximum-torque runs, fixed since: the
ball joints' limit rows grew without bound near a swing of pi
(``joints.TWIST_LIMIT_MAX_SWING``), and the joint projection stopped at a
pass that overshot (it now halves the step).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .core import projection as kernels

#: Rounds of the static contact projection and the joint projection in turn
#: at a step's end (``engine.step``): the joints' closing can move another body
#: of the chain into the ground, which the next round moves out again.
ROUNDS = 3
#: m: the least excess over the depth that moves a body.
MIN_MOVE = kernels.MIN_MOVE


class ProjectedPoints(NamedTuple):
    """The contact points of the bodies moved by ``project_static_contacts``:
    every point of their manifolds with the static shapes they were moved out
    of, sorted by world (within a world: by round, pair, then slot); and the
    worlds they are in, with those worlds' positions and orientations from
    before the move, so that a world whose joints cannot follow the move can
    be put back."""

    world: np.ndarray   # (K,) world index, ascending
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
    looked = (np.arange(pos.shape[0], dtype=np.int64) if worlds is None
              else np.ascontiguousarray(worlds, dtype=np.int64))
    L, P = looked.size, idx.size
    normal, point = np.empty((L, P, 3)), np.empty((L, P, 4, 3))
    excess, valid, deep = np.empty((L, P)), np.empty((L, P, 4), dtype=bool), np.empty((L, P), dtype=bool)
    counts = np.empty((L, 2), dtype=np.int64)
    pa, pb = contacts.static_pair_a, contacts.static_pair_b
    kernels.find(looked, contacts.static_pair_kind, pa, pb, contacts._shape_type, contacts._shape_params, pos, quat,
                 float(depth), contacts.unbounded_margin, np.empty((L, P), dtype=bool), np.empty((L, P)),
                 np.empty((L, 2, 8, 3)), normal, point, np.empty((L, P, 4)), valid, excess, deep, counts)
    ks = np.flatnonzero(counts[:, 0])
    if ks.size == 0:
        return None
    moved = looked[ks]
    before = ProjectedPoints(None, None, None, None, moved, pos[moved], quat[moved])
    offsets = np.zeros(ks.size, dtype=np.int64)
    np.cumsum(counts[ks[:-1], 1], out=offsets[1:])
    K = int(counts[ks, 1].sum())
    world, body = np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64)
    lever, out = np.empty((K, 3)), np.empty((K, 3))
    kernels.move(ks, looked, offsets, pa, pb, model.dynamic, pos, quat, normal, point, valid, excess, deep, world,
                 body, lever, out)
    return before._replace(world=world, body=body, lever=lever, normal=out)


def merged(first, then):
    """The points of two rounds of moves as one: a body moved again keeps
    only the later round's points; the worlds and their state before are the
    first round's (a round looks only at worlds the one before moved)."""
    if first is None:
        return then
    n = first.position_before.shape[1]
    return ProjectedPoints(*kernels.merge(*first[:4], *then[:4], n), *first[4:])
