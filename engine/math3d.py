"""Vectorised 3D vector and quaternion arithmetic on arrays of any leading shape.

Quaternions are stored as ``(..., 4)`` arrays in ``(w, x, y, z)`` order and are
unit quaternions wherever they stand for an orientation. Every product here is
written out component by component rather than with ``np.cross``/``einsum``/BLAS,
so a result never depends on the batch size it was computed in: stepping W
worlds together gives bit-for-bit what stepping them one at a time gives.
"""

from __future__ import annotations

import numpy as np


#: Below these many elements, ``dot`` and ``mat_vec`` multiply once and sum the
#: products with one ``np.add.reduce`` along the last axis: the same sums in the
#: same order (((p0 + p1) + p2) per row, whatever the batch), in 2 numpy calls
#: instead of 8-11, 2-3x faster on a few vectors; above them the reduction's
#: short inner loop loses (3-4x slower at 1024 worlds x 16 bodies).
REDUCE_BELOW = 384
MAT_VEC_REDUCE_BELOW = 96  # elements of v (a third of dot's: each vector takes nine products)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product over the last axis (size 3)."""
    if a.size < REDUCE_BELOW and b.size < REDUCE_BELOW:
        return np.add.reduce(a * b, axis=-1)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


#: Unit axes x, y, z (of the world or of a frame).
EX = np.array([1.0, 0.0, 0.0])
EY = np.array([0.0, 1.0, 0.0])
EZ = np.array([0.0, 0.0, 1.0])

# cross's products a_y b_z, a_z b_x, a_x b_y, then a_z b_y, a_x b_z, a_y b_x.
_CROSS_A = np.array([1, 2, 0, 2, 0, 1])
_CROSS_B = np.array([2, 0, 1, 1, 2, 0])


#: Vectors (..., 3) at or above this count take the component-wise forms of
#: ``cross`` and ``mat_vec``: the same products summed in the same order, so the
#: same bits, but without fancy indexing or strided in-place sums, which cost
#: 2-6x more on large batches (1024 worlds x 16 bodies); below it the fewer
#: numpy calls of the compact forms win.
COMPONENT_WISE_FROM = 512


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (size 3): (a_y b_z - a_z b_y, ...)."""
    if a.size < 3 * COMPONENT_WISE_FROM and b.size < 3 * COMPONENT_WISE_FROM:
        # The six products in one array (np.take, 2-3x cheaper than fancy
        # indexing on small arrays), then first three minus last three.
        p = a.take(_CROSS_A, -1) * b.take(_CROSS_B, -1)
        return p[..., :3] - p[..., 3:]
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    np.subtract(ay * bz, az * by, out=out[..., 0])
    np.subtract(az * bx, ax * bz, out=out[..., 1])
    np.subtract(ax * by, ay * bx, out=out[..., 2])
    return out


def norm(a: np.ndarray) -> np.ndarray:
    """Euclidean length over the last axis."""
    return np.sqrt(dot(a, a))


def clamp_norm(a: np.ndarray, limit: float) -> np.ndarray:
    """Vectors ``a`` (..., 3) scaled down to length at most ``limit``."""
    n = norm(a)
    return a * (np.minimum(n, limit) / np.maximum(n, 1e-300))[..., None]


def normalize(a: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors along ``a``; zero vectors stay zero."""
    n = norm(a)
    return a / np.maximum(n, eps)[..., None]


# quat_mul's 16 products p_i q_j with their signs, row by row (w, x, y, z) in
# the order of the written-out sums below.
_QP = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3])
_QQ = np.array([0, 1, 2, 3, 1, 0, 3, 2, 2, 3, 0, 1, 3, 2, 1, 0])
_QSIGN = np.array([1, -1, -1, -1, 1, 1, 1, -1, 1, -1, 1, 1, 1, 1, -1, 1], dtype=float)


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` of ``(..., 4)`` quaternions in (w, x, y, z) order."""
    if p.size < COMPONENT_WISE_FROM and q.size < COMPONENT_WISE_FROM:
        # Few quaternions: the 16 signed products in one array, each row summed
        # by one reduction, in the order of the sums below (5 numpy calls, not 40).
        t = p.take(_QP, -1) * q.take(_QQ, -1) * _QSIGN
        return np.add.reduce(t.reshape(t.shape[:-1] + (4, 4)), axis=-1)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        (
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ),
        axis=-1,
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion)."""
    out = q.copy()
    out[..., 1:] *= -1.0
    return out


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions along ``q``."""
    n = np.sqrt(q[..., 0] ** 2 + q[..., 1] ** 2 + q[..., 2] ** 2 + q[..., 3] ** 2)
    return q / n[..., None]


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4).

    Uses v' = v + 2w (u×v) + 2 u×(u×v) with u the vector part, which costs two
    cross products instead of two quaternion products.
    """
    w = q[..., 0:1]
    u = q[..., 1:4]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def quat_rotate_inv(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` by the inverse of unit quaternions ``q``."""
    w = q[..., 0:1]
    u = -q[..., 1:4]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def quat_from_axis_angle(axis, angle) -> np.ndarray:
    """Unit quaternion for a rotation of ``angle`` radians about ``axis``."""
    axis = normalize(np.asarray(axis, dtype=float))
    angle = np.asarray(angle, dtype=float)
    half = 0.5 * angle
    s = np.sin(half)
    return np.concatenate((np.cos(half)[..., None], axis * s[..., None]), axis=-1)


def quat_to_rotation_vector(q: np.ndarray) -> np.ndarray:
    """The rotation vector φ n (..., 3), angle φ in [0, π] radians, of unit
    quaternions ``q`` (either sign): the inverse of ``quat_from_axis_angle``."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.sqrt((q[..., 1:] ** 2).sum(-1))
    angle = 2.0 * np.arctan2(s, q[..., 0])
    return q[..., 1:] * np.where(s > 0, angle / np.where(s > 0, s, 1.0), 2.0)[..., None]


# quat_to_matrix's entries (row-major) as a ± b of products of components
# (w, x, y, z = 0..3): the first factors, the second factors, and the signs of b.
_M_PAIRS = ((2, 2, 3, 3), (1, 2, 0, 3), (1, 3, 0, 2),
            (1, 2, 0, 3), (1, 1, 3, 3), (2, 3, 0, 1),
            (1, 3, 0, 2), (2, 3, 0, 1), (1, 1, 2, 2))
_M_A = np.array([i for a1, a2, b1, b2 in _M_PAIRS for i in (a1, b1)])
_M_B = np.array([i for a1, a2, b1, b2 in _M_PAIRS for i in (a2, b2)])
_M_SIGN = np.array([1, 1, 1, -1, 1, 1, 1, 1, 1, 1, 1, -1, 1, -1, 1, 1, 1, 1], dtype=float)
_M_DIAG = np.array([0, 4, 8])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``q``."""
    if q.size < COMPONENT_WISE_FROM:
        # Few quaternions: the 18 products in one array, then the same sums as
        # below (1 - 2 (a + b) on the diagonal, 2 (a ± b) off it) in 8 numpy calls.
        t = q.take(_M_A, -1) * q.take(_M_B, -1) * _M_SIGN
        v = 2 * (t[..., 0::2] + t[..., 1::2])
        v[..., _M_DIAG] = 1 - v[..., _M_DIAG]
        return v.reshape(v.shape[:-1] + (3, 3))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), axis=-1),
            np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), axis=-1),
            np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), axis=-1),
        ),
        axis=-2,
    )


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (w >= 0) of a single 3x3 rotation matrix (Shepperd's method)."""
    m = np.asarray(m, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    if q[0] < 0:
        q = -q
    return q / np.linalg.norm(q)


def quat_integrate(q: np.ndarray, omega: np.ndarray, h: float) -> np.ndarray:
    """Advance orientations by world angular velocity ``omega`` over ``h`` seconds.

    First-order update q += h/2 (ω ⊗ q) followed by renormalisation, as in the
    thesis's explicit Euler and in Box2D/Bullet.
    """
    wq = np.concatenate((np.zeros(omega.shape[:-1] + (1,)), omega), axis=-1)
    return quat_normalize(q + (0.5 * h) * quat_mul(wq, q))


def quat_exp_integrate(q: np.ndarray, omega: np.ndarray, h: float) -> np.ndarray:
    """Advance orientations by the exact rotation of constant world ``omega`` over ``h``.

    q' = exp(h ω / 2) ⊗ q: the rotation by angle h|ω| about ω/|ω|.
    """
    angle = norm(omega) * h
    half = 0.5 * angle
    # sin(x/2)/x written to stay finite at x -> 0 (series 1/2 - x²/48).
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    s_over = np.where(small, 0.5 - angle * angle / 48.0, np.sin(half) / safe)
    dq = np.concatenate((np.cos(half)[..., None], omega * (s_over * h)[..., None]), axis=-1)
    return quat_normalize(quat_mul(dq, q))


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]×`` of shape ``(..., 3, 3)``."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        (np.stack((z, -w, y), -1), np.stack((w, z, -x), -1), np.stack((-y, x, z), -1)), axis=-2
    )


def mat_vec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) @ (..., 3), written out: row i is m_i0 v_0 + m_i1 v_1 + m_i2 v_2,
    summed left to right in either form (see ``COMPONENT_WISE_FROM``)."""
    if v.size < MAT_VEC_REDUCE_BELOW and m.size < 3 * MAT_VEC_REDUCE_BELOW:
        return np.add.reduce(m * v[..., None, :], axis=-1)
    if v.size < 3 * COMPONENT_WISE_FROM and m.size < 9 * COMPONENT_WISE_FROM:
        # The columns scaled by v's components, summed in place.
        out = m[..., 0] * v[..., 0:1]
        out += m[..., 1] * v[..., 1:2]
        out += m[..., 2] * v[..., 2:3]
        return out
    out = np.empty(np.broadcast_shapes(m.shape[:-1], v.shape), dtype=np.result_type(m, v))
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    for i in range(3):
        row = m[..., i, 0] * v0
        row += m[..., i, 1] * v1
        row += m[..., i, 2] * v2
        out[..., i] = row
    return out


# sym3_inverse's cofactors c00, c01, c02, c11, c12, c22 as p q - r s of the
# upper triangle's entries (row-major flat indices), and the cofactor of each
# entry of the (symmetric) inverse.
_C_P = np.array([4, 2, 1, 0, 1, 0])
_C_Q = np.array([8, 5, 5, 8, 2, 4])
_C_R = np.array([5, 1, 2, 2, 0, 1])
_C_S = np.array([5, 8, 4, 2, 5, 1])
_C_OF = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])


def sym3_inverse(k: np.ndarray) -> np.ndarray:
    """Inverse of symmetric (..., 3, 3) matrices by the adjugate (singular: 0)."""
    if k.size < 3 * COMPONENT_WISE_FROM:
        # Few matrices: the six cofactors' products in two arrays and the same
        # sums as below, in about 15 numpy calls instead of 50.
        f = k.reshape(k.shape[:-2] + (9,))
        c = f.take(_C_P, -1) * f.take(_C_Q, -1) - f.take(_C_R, -1) * f.take(_C_S, -1)
        det = np.add.reduce(f[..., 0:3] * c[..., 0:3], axis=-1)  # a00 c00 + a01 c01 + a02 c02
        inv_det = np.where(det != 0.0, 1.0 / np.where(det != 0.0, det, 1.0), 0.0)
        return (c.take(_C_OF, -1) * inv_det[..., None]).reshape(k.shape)
    a00, a01, a02 = k[..., 0, 0], k[..., 0, 1], k[..., 0, 2]
    a11, a12, a22 = k[..., 1, 1], k[..., 1, 2], k[..., 2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    inv_det = np.where(det != 0.0, 1.0 / np.where(det != 0.0, det, 1.0), 0.0)
    out = np.empty(k.shape)
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = c00 * inv_det, c01 * inv_det, c02 * inv_det
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = c01 * inv_det, c11 * inv_det, c12 * inv_det
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = c02 * inv_det, c12 * inv_det, c22 * inv_det
    return out


def sym3_solve(k: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve K x = b for symmetric positive definite (..., 3, 3) K by the adjugate."""
    return mat_vec(sym3_inverse(k), b)


def world_inv_inertia(q: np.ndarray, inv_inertia_body: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:
    """World-frame inverse inertia R diag(I⁻¹) Rᵀ as (..., 3, 3); ``r``: the
    rotation matrices of ``q`` if already known (then ``q`` is unused)."""
    if r is None:
        r = quat_to_matrix(q)
    d = inv_inertia_body[..., None, :]
    rd = r * d  # R diag(d): scale columns
    out = np.empty(r.shape)
    for i in range(3):
        for j in range(i, 3):
            v = rd[..., i, 0] * r[..., j, 0] + rd[..., i, 1] * r[..., j, 1] + rd[..., i, 2] * r[..., j, 2]
            out[..., i, j] = v
            out[..., j, i] = v
    return out


def inverse_or_nan(A: np.ndarray) -> np.ndarray:
    """``np.linalg.inv`` of (..., n, n) matrices, NaN for any that is singular
    in floating point. Such a matrix comes from a world already diverging
    (bodies 1e17 m apart): its inverse turns that world non-finite, which the
    step reports (SimulationError naming the world) instead of stopping every
    world with LinAlgError."""
    try:
        return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        sign, _ = np.linalg.slogdet(A)
        bad = sign == 0
        out = np.linalg.inv(np.where(bad[..., None, None], np.eye(A.shape[-1]), A))
        out[bad] = np.nan
        return out
