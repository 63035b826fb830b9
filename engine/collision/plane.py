"""Plane against sphere, capsule and box (the plane is always shape a).

A plane's surface passes through its body's position with outward normal
along the body's local +z axis; it is solid below. The contact normal is the
plane normal (from the plane to the other shape). Each candidate point's
separation is its signed height above the plane minus the shape's radius.
Units: metres.
"""

from __future__ import annotations

import numpy as np

from ..math3d import dot, quat_to_matrix
from .geometry import local_z
from .manifold import Manifold, assemble

#: Box corner sign patterns; corner k has signs CORNER_SIGNS[k] along the
#: box's local (x, y, z) axes (k = 4 bx + 2 by + bz, bit set = +).
CORNER_SIGNS = np.array([[-1, -1, -1], [-1, -1, 1], [-1, 1, -1], [-1, 1, 1],
                         [1, -1, -1], [1, -1, 1], [1, 1, -1], [1, 1, 1]], dtype=float)


def plane_sphere(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Plane a, sphere b: one point (slot 0) below the sphere centre."""
    n = local_z(quat_a)
    r = params_b[..., 0]
    sep = dot(pos_b - pos_a, n) - r
    point = pos_b - n * (r + 0.5 * sep)[..., None]
    return assemble(n, point[..., None, :], sep[..., None], None, margin)


def plane_capsule(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Plane a, capsule b: the two segment ends (slot 0: local -z end, slot 1: +z end)."""
    n = local_z(quat_a)
    r = params_b[..., 0, None]
    hl = params_b[..., 1, None]
    u = local_z(quat_b)
    ends = np.stack((pos_b - u * hl, pos_b + u * hl), axis=-2)  # (W, P, 2, 3)
    height = dot(ends - pos_a[..., None, :], n[..., None, :])
    sep = height - r
    point = ends - n[..., None, :] * (r + 0.5 * sep)[..., None]
    return assemble(n, point, sep, None, margin)


def plane_box(pos_a, quat_a, params_a, pos_b, quat_b, params_b, margin) -> Manifold:
    """Plane a, box b: the 4 deepest of the 8 corners.

    The chosen corners sit in the slots in increasing corner index (see
    ``CORNER_SIGNS``), so a box resting on a face keeps each corner in the same
    slot. A box lying flat gives 4 valid points, on an edge 2, on a corner 1.
    """
    n = local_z(quat_a)
    m = quat_to_matrix(quat_b)  # columns: box axes in world
    h = params_b
    # Corner heights above the plane: centre height plus each axis' share.
    centre = dot(pos_b - pos_a, n)
    share = [h[..., j] * dot(m[..., :, j], n) for j in range(3)]  # (W, P) each
    offs = [m[..., :, j] * h[..., j, None] for j in range(3)]      # (W, P, 3) each
    heights = []
    corners = []
    for sx, sy, sz in CORNER_SIGNS:
        heights.append(centre + sx * share[0] + sy * share[1] + sz * share[2])
        corners.append(pos_b + sx * offs[0] + sy * offs[1] + sz * offs[2])
    heights = np.stack(heights, axis=-1)  # (W, P, 8)
    corners = np.stack(corners, axis=-2)  # (W, P, 8, 3)
    deepest = np.sort(np.argsort(heights, axis=-1, kind="stable")[..., :4], axis=-1)
    sep = np.take_along_axis(heights, deepest, axis=-1)
    pts = np.take_along_axis(corners, deepest[..., None], axis=-2)
    point = pts - n[..., None, :] * (0.5 * sep)[..., None]
    return assemble(n, point, sep, None, margin)
