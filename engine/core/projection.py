"""The static contact projection at a step's end, one world at a time
(:mod:`engine.contact_projection`: Cline & Pai 2003, post-stabilisation of
the contacts with static shapes).

For each world looked at, every pair of a dynamic and a static body (in pair
order) whose AABBs, each shrunk by depth / 2 on every side, overlap (only
there can the shapes be that deep) takes the exact narrow phase with an
unbounded margin (every point kept). A pair whose deepest point is more than
``MIN_MOVE`` beyond ``depth`` moves its dynamic body out along the normal
(away from the static shape), positions only: out of its static shapes one
after another in pair order, each move only what the moves before it left,
max(0, excess_i - d·n_i) n_i, so that a body deep in two coplanar shapes (a
floor of tiles) moves out once. Every valid point of a moving pair's manifold
is kept (world, body, lever arm in the body's frame, normal out of the shape)
for the joint projection's metric.

``find`` looks (nothing moves, one call when nothing is that deep);
``move`` then writes the points and moves the bodies, each world's points
at its offset of the flat outputs: by world, then pair, then slot. Units:
metres.
"""

from __future__ import annotations

import math

import numpy as np

from .collide.broadphase import body_bounds, boxes_overlap
from .collide.narrowphase import narrow_world
from .jit import SERIAL_BELOW, allocating_kernel, kernel, parallel_kernel, prange
from .vec import load3, load4, rotate_inv, sub

#: m: the least excess over the depth that moves a body (a body moved out
#: to the depth reads it again to a last bit).
MIN_MOVE = 1e-9


@kernel
def _find_world(k, w, pair_kind, pair_a, pair_b, shape_type, shape_params, position, orientation, depth, margin,
                keep, least, poly, normal, point, separation, valid, excess, deep, counts):
    """``find`` of world ``w``, the k-th looked at: scratch and outputs at k."""
    grow = 2.0 * (-0.5 * depth)  # boxes shrunk by depth / 2 on every side
    for p in range(pair_a.size):
        a, b = pair_a[p], pair_b[p]
        lo_a, hi_a = body_bounds(shape_type[a], load3(shape_params, a), load3(position[w], a),
                                 load4(orientation[w], a))
        lo_b, hi_b = body_bounds(shape_type[b], load3(shape_params, b), load3(position[w], b),
                                 load4(orientation[w], b))
        keep[k, p] = boxes_overlap(lo_a, hi_a, lo_b, hi_b, grow)
    # The exact narrow phase of the overlapping pairs (margin +inf); the others
    # get empty slots, separations +inf.
    narrow_world(0, pair_kind, pair_a, pair_b, position[w:w + 1], orientation[w:w + 1], shape_params, margin,
                 keep[k:k + 1], normal[k], point[k], separation[k], valid[k], least[k:k + 1], poly[k:k + 1])
    rows = 0
    points = 0
    for p in range(pair_a.size):
        s = separation[k, p, 0]
        for j in range(1, 4):
            v = separation[k, p, j]
            if not (s <= v or math.isnan(s)):  # np.minimum: NaN propagates
                s = v
        x = -s - depth  # m beyond the allowed depth
        excess[k, p] = x
        deep[k, p] = x > MIN_MOVE
        if deep[k, p]:
            rows += 1
            for j in range(4):
                if valid[k, p, j]:
                    points += 1
    counts[k, 0] = rows
    counts[k, 1] = points


@parallel_kernel
def find(worlds, pair_kind, pair_a, pair_b, shape_type, shape_params, position, orientation, depth, margin, keep,
         least, poly, normal, point, separation, valid, excess, deep, counts):
    """Which pairs of ``worlds`` (L,) (world indices of position (W, N, 3) and
    orientation (W, N, 4)) are deeper than ``depth`` (m) beyond ``MIN_MOVE``.

    pair_kind, pair_a, pair_b (P,): the pairs with a static body (kind codes,
    canonical order); shape_type (N,), shape_params (N, 3). Scratch: margin
    (1, P) +inf, keep and least (L, P), poly (L, 2, 8, 3). Outputs at k for
    worlds[k]: the manifolds normal (L, P, 3), point (L, P, 4, 3),
    separation (L, P, 4), valid (L, P, 4); excess (L, P) m beyond the depth;
    deep (L, P); counts (L, 2): the deep pairs and their valid points."""
    if worlds.size < SERIAL_BELOW:
        for k in range(worlds.size):
            _find_world(k, worlds[k], pair_kind, pair_a, pair_b, shape_type, shape_params, position, orientation,
                        depth, margin, keep, least, poly, normal, point, separation, valid, excess, deep, counts)
    else:
        for k in prange(worlds.size):
            _find_world(k, worlds[k], pair_kind, pair_a, pair_b, shape_type, shape_params, position, orientation,
                        depth, margin, keep, least, poly, normal, point, separation, valid, excess, deep, counts)


@kernel
def _move_world(k, w, offset, pair_a, pair_b, dynamic, position, orientation, normal, point, valid, excess, deep,
                shift, moved, out_world, out_body, out_lever, out_normal):
    """``move`` of world ``w``, the k-th looked at; its points from ``offset``."""
    pos, ori = position[w], orientation[w]
    N = pos.shape[0]
    for i in range(N):
        moved[i] = False
        for c in range(3):
            shift[i, c] = 0.0
    o = offset
    for p in range(pair_a.size):
        if not deep[k, p]:
            continue
        # The normal points from a to b: b moves along it, a against it.
        b = pair_b[p]
        if dynamic[b]:
            body, n = b, (normal[k, p, 0], normal[k, p, 1], normal[k, p, 2])
        else:
            body, n = pair_a[p], (-normal[k, p, 0], -normal[k, p, 1], -normal[k, p, 2])
        x, q = load3(pos, body), load4(ori, body)
        for j in range(4):
            if valid[k, p, j]:
                lever = rotate_inv(q, sub((point[k, p, j, 0], point[k, p, j, 1], point[k, p, j, 2]), x))
                out_world[o] = w
                out_body[o] = body
                for c in range(3):
                    out_lever[o, c] = lever[c]
                    out_normal[o, c] = n[c]
                o += 1
        # Only what the moves before it left: max(0, excess - d·n).
        d = shift[body, 0] * n[0] + shift[body, 1] * n[1] + shift[body, 2] * n[2]
        left = excess[k, p] - d
        if not (left >= 0.0 or math.isnan(left)):  # np.maximum(left, 0)
            left = 0.0
        for c in range(3):
            shift[body, c] += left * n[c]
        moved[body] = True
    for i in range(N):
        if moved[i]:
            for c in range(3):
                pos[i, c] += shift[i, c]


@allocating_kernel
def _move_worlds(lo, hi, ks, worlds, offsets, pair_a, pair_b, dynamic, position, orientation, normal, point, valid,
                 excess, deep, out_world, out_body, out_lever, out_normal):
    N = position.shape[1]
    shift = np.empty((N, 3))
    moved = np.empty(N, dtype=np.bool_)
    for i in range(lo, hi):
        k = ks[i]
        _move_world(k, worlds[k], offsets[i], pair_a, pair_b, dynamic, position, orientation, normal, point, valid,
                    excess, deep, shift, moved, out_world, out_body, out_lever, out_normal)


@parallel_kernel
def move(ks, worlds, offsets, pair_a, pair_b, dynamic, position, orientation, normal, point, valid, excess, deep,
         out_world, out_body, out_lever, out_normal):
    """Move the dynamic bodies of the deep pairs found by ``find`` out, in
    place, in the worlds worlds[ks] (``ks`` (M,): the indices of ``find``'s
    worlds with a deep pair), and write their points from ``offsets`` (M,)
    on: out_world, out_body (K,), out_lever (K, 3) m from the body's centre
    in its frame, out_normal (K, 3) out of the static shape."""
    M = ks.size
    if M < SERIAL_BELOW:
        _move_worlds(0, M, ks, worlds, offsets, pair_a, pair_b, dynamic, position, orientation, normal, point, valid,
                     excess, deep, out_world, out_body, out_lever, out_normal)
    else:
        for i in prange(M):
            _move_worlds(i, i + 1, ks, worlds, offsets, pair_a, pair_b, dynamic, position, orientation, normal, point,
                         valid, excess, deep, out_world, out_body, out_lever, out_normal)


@allocating_kernel
def merge(first_world, first_body, first_lever, first_normal, then_world, then_body, then_lever, then_normal,
          num_bodies):
    """The points of two rounds of moves as one, each sorted by world: a
    (world, body) moved again keeps only the later round's points; world by
    world, the earlier round's points kept, then the later round's. Returns
    (world, body, lever, normal)."""
    nf, nt = first_world.size, then_world.size
    top = 0
    for i in range(nf):
        top = max(top, first_world[i] + 1)
    for i in range(nt):
        top = max(top, then_world[i] + 1)
    again = np.zeros(top * num_bodies, dtype=np.bool_)
    for i in range(nt):
        again[then_world[i] * num_bodies + then_body[i]] = True
    kept = 0
    for i in range(nf):
        if not again[first_world[i] * num_bodies + first_body[i]]:
            kept += 1
    K = kept + nt
    world = np.empty(K, dtype=np.int64)
    body = np.empty(K, dtype=np.int64)
    lever = np.empty((K, 3))
    normal = np.empty((K, 3))
    i = j = o = 0
    while i < nf or j < nt:
        w = first_world[i] if i < nf else then_world[j]
        if j < nt and then_world[j] < w:
            w = then_world[j]
        while i < nf and first_world[i] == w:
            if not again[w * num_bodies + first_body[i]]:
                world[o], body[o] = w, first_body[i]
                for c in range(3):
                    lever[o, c] = first_lever[i, c]
                    normal[o, c] = first_normal[i, c]
                o += 1
            i += 1
        while j < nt and then_world[j] == w:
            world[o], body[o] = w, then_body[j]
            for c in range(3):
                lever[o, c] = then_lever[j, c]
                normal[o, c] = then_normal[j, c]
            o += 1
            j += 1
    return world, body, lever, normal


__all__ = ["MIN_MOVE", "find", "merge", "move"]
