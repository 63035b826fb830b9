"""Broad phase: which body pairs may touch.

``candidate_pairs`` runs once when a model is compiled and lists every pair
that may ever collide; ``aabb`` and ``overlapping`` then cull that fixed list
each step with world-aligned bounding boxes. Those two are numpy-facing
wrappers of the kernels in :mod:`engine.core.collide.broadphase` (which the
step's detection, :mod:`engine.core.collide.world`, calls directly). Units:
metres.
"""

from __future__ import annotations

import numpy as np

from ..core.collide.broadphase import bounds_rows, overlap_rows
from ..shapes import NONE, PLANE
from .narrowphase import TYPE_ORDER


def candidate_pairs(shape_type, dynamic, group, mask, excluded=()):
    """All body pairs that may collide, as two int64 arrays (pairs_a, pairs_b).

    A pair (i, j) is listed when neither body has shape NONE, they are not both
    planes, at least one is dynamic, each one's collision group meets the
    other's mask ((group_i & mask_j) and (group_j & mask_i)), and neither
    (i, j) nor (j, i) is in ``excluded`` (e.g. bodies joined by a joint).

    Each pair is oriented for the narrow phase: pairs_a holds the shape that
    comes first in the canonical order plane, sphere, capsule, box (the lower
    body index on a tie), so the pair functions need no swap. Pairs come in
    the order of a loop over i < j. Build time only (a Python loop over bodies).
    """
    shape_type = np.asarray(shape_type)
    dynamic = np.asarray(dynamic, dtype=bool)
    group = np.asarray(group)
    mask = np.asarray(mask)
    excluded = {(int(a), int(b)) for a, b in excluded}
    n = len(shape_type)
    pa, pb = [], []
    for i in range(n):
        ti = int(shape_type[i])
        if ti == NONE:
            continue
        for j in range(i + 1, n):
            tj = int(shape_type[j])
            if tj == NONE or (ti == PLANE and tj == PLANE):
                continue
            if not (dynamic[i] or dynamic[j]):
                continue
            if not (int(group[i]) & int(mask[j])) or not (int(group[j]) & int(mask[i])):
                continue
            if (i, j) in excluded or (j, i) in excluded:
                continue
            if TYPE_ORDER[tj] < TYPE_ORDER[ti]:
                pa.append(j)
                pb.append(i)
            else:
                pa.append(i)
                pb.append(j)
    return np.array(pa, dtype=np.int64), np.array(pb, dtype=np.int64)


def aabb(shape_type, params, pos, quat):
    """World axis-aligned bounding boxes (lo, hi), each (W, N, 3), in metres.

    shape_type (N,), params (N, 3), pos (W, N, 3), quat (W, N, 4). Spheres:
    centre ± r; capsules: ± (r + half_length |axis|) per world axis; boxes:
    ± sum_j h_j |axis_j| per world axis (the rotated box's extent); planes
    are unbounded (±inf); bodies without a shape get an empty box
    (lo = +inf, hi = -inf) that overlaps nothing.
    """
    pos = np.asarray(pos, dtype=float)
    lead = pos.shape[:-1]
    kind = np.ascontiguousarray(np.broadcast_to(np.asarray(shape_type, dtype=np.int64), lead)).reshape(-1)
    rows = [np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), lead + (n,))).reshape(-1, n)
            for x, n in ((params, 3), (pos, 3), (quat, 4))]
    lo = np.empty((kind.size, 3))
    hi = np.empty((kind.size, 3))
    bounds_rows(kind, *rows, lo, hi)
    return lo.reshape(lead + (3,)), hi.reshape(lead + (3,))


def overlapping(lo, hi, pairs_a, pairs_b, margin):
    """(W, P) bool: the boxes of pairs_a and pairs_b, each grown by ``margin``
    metres on every side (a number, or one per (W, P)), overlap."""
    lo = np.ascontiguousarray(lo, dtype=float)
    hi = np.ascontiguousarray(hi, dtype=float)
    pairs_a = np.ascontiguousarray(pairs_a, dtype=np.int64)
    pairs_b = np.ascontiguousarray(pairs_b, dtype=np.int64)
    shape = (lo.shape[0], pairs_a.size)
    grow = np.ascontiguousarray(np.broadcast_to(2.0 * np.asarray(margin, dtype=float), shape))
    out = np.empty(shape, dtype=bool)
    overlap_rows(lo, hi, pairs_a, pairs_b, grow, out)
    return out
