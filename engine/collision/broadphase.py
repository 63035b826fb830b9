"""Broad phase: which body pairs may touch.

``candidate_pairs`` runs once when a model is compiled and lists every pair
that may ever collide; ``aabb`` and ``overlapping`` then cull that fixed list
each step with world-aligned bounding boxes, vectorised over worlds and pairs.
Units: metres.
"""

from __future__ import annotations

import numpy as np

from ..math3d import quat_to_matrix
from ..shapes import BOX, CAPSULE, NONE, PLANE, SPHERE
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
    shape_type = np.asarray(shape_type)
    params = np.asarray(params, dtype=float)
    kind = shape_type[:, None]
    r = params[:, 0:1]
    half = np.where(kind == SPHERE, np.broadcast_to(r, pos.shape), 0.0)
    turned = (kind == CAPSULE) | (kind == BOX)
    if turned.any():  # extents that turn with the body (spheres and planes have none)
        m = np.abs(quat_to_matrix(quat))  # (W, N, 3, 3); columns are the body axes
        capsule = r + params[:, 1:2] * m[..., :, 2]
        box = params[:, 0:1] * m[..., :, 0] + params[:, 1:2] * m[..., :, 1] + params[:, 2:3] * m[..., :, 2]
        half = np.where(kind == CAPSULE, capsule, np.where(kind == BOX, box, half))
    lo = pos - half
    hi = pos + half
    lo = np.where(kind == PLANE, -np.inf, np.where(kind == NONE, np.inf, lo))
    hi = np.where(kind == PLANE, np.inf, np.where(kind == NONE, -np.inf, hi))
    return lo, hi


def overlapping(lo, hi, pairs_a, pairs_b, margin):
    """(W, P) bool: the boxes of pairs_a and pairs_b, each grown by ``margin``
    metres on every side, overlap."""
    la, ha = lo[:, pairs_a], hi[:, pairs_a]
    lb, hb = lo[:, pairs_b], hi[:, pairs_b]
    m2 = 2.0 * margin
    ok = (la[..., 0] <= hb[..., 0] + m2) & (lb[..., 0] <= ha[..., 0] + m2)
    ok &= (la[..., 1] <= hb[..., 1] + m2) & (lb[..., 1] <= ha[..., 1] + m2)
    ok &= (la[..., 2] <= hb[..., 2] + m2) & (lb[..., 2] <= ha[..., 2] + m2)
    return ok
