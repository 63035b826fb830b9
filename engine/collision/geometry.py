"""Small vectorised geometric helpers shared by the narrow-phase pair functions.

Everything works on arrays of any leading shape (usually ``(W, P)``) and is
written element by element (no BLAS, no ``np.cross``/``einsum``), so results
do not depend on the batch size. Units: metres.
"""

from __future__ import annotations

import numpy as np

from ..math3d import dot, norm, quat_rotate

EX = np.array([1.0, 0.0, 0.0])
EY = np.array([0.0, 1.0, 0.0])
EZ = np.array([0.0, 0.0, 1.0])

#: Distances (m) below which a direction is treated as undefined and a
#: fallback direction is used instead.
TINY_LENGTH = 1e-9


def local_z(quat: np.ndarray) -> np.ndarray:
    """World direction of the body's local +z axis (capsule axis, plane normal)."""
    return quat_rotate(quat, EZ)


def sign_nonneg(x: np.ndarray) -> np.ndarray:
    """+1 where ``x >= 0``, -1 elsewhere (never 0, so it is safe as an orientation)."""
    return np.where(x >= 0.0, 1.0, -1.0)


def pick(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``values[..., index]`` per element: values (..., K), index (...) int -> (...)."""
    values = np.broadcast_to(values, index.shape + values.shape[-1:])
    return np.take_along_axis(values, index[..., None], axis=-1)[..., 0]


def column(matrix: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Column ``index`` of each 3x3 matrix: matrix (..., 3, 3), index (...) -> (..., 3)."""
    matrix = np.broadcast_to(matrix, index.shape + (3, 3))
    idx = np.broadcast_to(index[..., None, None], index.shape + (3, 1))
    return np.take_along_axis(matrix, idx, axis=-1)[..., 0]


def one_hot(index: np.ndarray) -> np.ndarray:
    """Unit coordinate vectors ``e_index`` as floats: index (...) -> (..., 3)."""
    return (index[..., None] == np.arange(3)).astype(float)


def normalize_or(v: np.ndarray, fallback: np.ndarray, eps: float = TINY_LENGTH):
    """Unit vectors along ``v`` and their lengths; ``fallback`` where ``|v| <= eps``."""
    length = norm(v)
    ok = length > eps
    unit = v / np.where(ok, length, 1.0)[..., None]
    return np.where(ok[..., None], unit, fallback), length


def perpendicular_fallback(axis: np.ndarray) -> np.ndarray:
    """A fixed unit vector perpendicular to the unit vectors ``axis``.

    The world +z axis with its component along ``axis`` removed; if ``axis``
    is (nearly) vertical, the world +x axis likewise. Used as the contact
    normal when two capsule axes meet, where any perpendicular is as good.
    """
    vz = EZ - axis * axis[..., 2:3]
    vx = EX - axis * axis[..., 0:1]
    use_z = dot(vz, vz) > 1e-6
    v = np.where(use_z[..., None], vz, vx)
    return v / norm(v)[..., None]


def closest_points_segments(p1, d1, p2, d2):
    """Parameters ``(s, t)`` in [0, 1] of the closest points ``p1 + s d1`` and
    ``p2 + t d2`` of two segments.

    Ericson, *Real-Time Collision Detection* (2005), section 5.1.9
    (ClosestPtSegmentSegment), with the branches written as masks. Degenerate
    segments (zero length) and parallel segments are handled: for parallel
    segments ``s`` starts at 0 and both are then clamped, which gives a pair
    inside the overlap when the segments overlap.
    """
    eps = 1e-18
    r = p1 - p2
    a = dot(d1, d1)
    e = dot(d2, d2)
    f = dot(d2, r)
    c = dot(d1, r)
    b = dot(d1, d2)
    a_ok = a > eps
    e_ok = e > eps
    a_safe = np.where(a_ok, a, 1.0)
    e_safe = np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    general = denom > 1e-12 * a * e
    s = np.where(general, np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    s = np.where(t < 0.0, np.clip(-c / a_safe, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a_safe, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # Degenerate segments: a point against a segment, or two points.
    s = np.where(e_ok, s, np.clip(-c / a_safe, 0.0, 1.0))
    t = np.where(e_ok, t, 0.0)
    t = np.where(a_ok, t, np.clip(f / e_safe, 0.0, 1.0))
    s = np.where(a_ok, s, 0.0)
    s = np.where(a_ok | e_ok, s, 0.0)
    t = np.where(a_ok | e_ok, t, 0.0)
    return s, t
