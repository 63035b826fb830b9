"""3-vectors and quaternions as tuples of floats, for the kernels.

A vector is ``(x, y, z)``, a quaternion ``(w, x, y, z)`` (Hamilton product,
unit length wherever it stands for an orientation). Tuples are values: numba
keeps them in registers, so no kernel allocates in its inner loops. ``load``
and ``store`` move them between the state's arrays and the kernels.
"""

from __future__ import annotations

import math

from .jit import kernel


@kernel
def load3(a, i):
    """Row ``i`` of an (n, 3) array as a vector."""
    return (a[i, 0], a[i, 1], a[i, 2])


@kernel
def load4(a, i):
    """Row ``i`` of an (n, 4) array as a quaternion."""
    return (a[i, 0], a[i, 1], a[i, 2], a[i, 3])


@kernel
def store3(a, i, v):
    a[i, 0] = v[0]
    a[i, 1] = v[1]
    a[i, 2] = v[2]


@kernel
def store4(a, i, q):
    a[i, 0] = q[0]
    a[i, 1] = q[1]
    a[i, 2] = q[2]
    a[i, 3] = q[3]


@kernel
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@kernel
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@kernel
def scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


@kernel
def mul(a, b):
    """Component-wise product."""
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


@kernel
def add_scaled(a, s, b):
    """a + s b."""
    return (a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2])


@kernel
def neg(a):
    return (-a[0], -a[1], -a[2])


@kernel
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel
def norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@kernel
def normalize(a):
    """a / |a|; the zero vector stays zero."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if n < 1e-12:
        n = 1e-12
    return (a[0] / n, a[1] / n, a[2] / n)


@kernel
def quat_mul(p, q):
    """Hamilton product p ⊗ q."""
    return (p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
            p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
            p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
            p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0])


@kernel
def quat_conj(q):
    return (q[0], -q[1], -q[2], -q[3])


@kernel
def quat_normalize(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


@kernel
def rotate(q, v):
    """R(q) v, as v + 2w (u × v) + 2 u × (u × v) with u the vector part."""
    u = (q[1], q[2], q[3])
    t = scale(2.0, cross(u, v))
    return add(add_scaled(v, q[0], t), cross(u, t))


@kernel
def rotate_inv(q, v):
    """R(q)ᵀ v."""
    u = (-q[1], -q[2], -q[3])
    t = scale(2.0, cross(u, v))
    return add(add_scaled(v, q[0], t), cross(u, t))


@kernel
def mat3_vec(m, i, v):
    """m[i] @ v for a stack m of 3x3 matrices, each row summed left to right."""
    return (m[i, 0, 0] * v[0] + m[i, 0, 1] * v[1] + m[i, 0, 2] * v[2],
            m[i, 1, 0] * v[0] + m[i, 1, 1] * v[1] + m[i, 1, 2] * v[2],
            m[i, 2, 0] * v[0] + m[i, 2, 1] * v[1] + m[i, 2, 2] * v[2])


@kernel
def quat_integrate(q, omega, h):
    """q + h/2 (ω ⊗ q), renormalised: the first-order update of an
    orientation by a world angular velocity ω (rad/s) over h seconds."""
    wq = quat_mul((0.0, omega[0], omega[1], omega[2]), q)
    s = 0.5 * h
    return quat_normalize((q[0] + s * wq[0], q[1] + s * wq[1], q[2] + s * wq[2], q[3] + s * wq[3]))


@kernel
def inv_inertia_apply(q, inv_inertia_body, v):
    """World-frame I⁻¹ v = R (I_b⁻¹ ⊙ Rᵀ v) of a body with principal inverse
    moments ``inv_inertia_body`` (1/(kg·m²)) turned by q."""
    return rotate(q, mul(inv_inertia_body, rotate_inv(q, v)))


@kernel
def pick3(a, i):
    """Component ``i`` (0, 1 or 2, known only at run time) of a vector."""
    if i == 0:
        return a[0]
    if i == 1:
        return a[1]
    return a[2]


@kernel
def abs3(a):
    """Component-wise |a|."""
    return (abs(a[0]), abs(a[1]), abs(a[2]))


@kernel
def quat_to_matrix(q):
    """R(q) of a unit quaternion as its three columns (the body's x, y, z axes
    in the world frame), each a vector: a 3x3 matrix as a tuple of columns.

    The entries are those of :func:`engine.math3d.quat_to_matrix`, summed in
    the same order: 1 - 2 (y² + z²) on the diagonal, 2 (xy ± wz) off it.
    """
    w, x, y, z = q[0], q[1], q[2], q[3]
    c0 = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y))
    c1 = (2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x))
    c2 = (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))
    return (c0, c1, c2)


@kernel
def column(m, i):
    """Column ``i`` (known only at run time) of a matrix given by its columns."""
    if i == 0:
        return m[0]
    if i == 1:
        return m[1]
    return m[2]


@kernel
def sym3_inverse(a00, a01, a02, a11, a12, a22):
    """The upper triangle (i00, i01, i02, i11, i12, i22) of the inverse of
    the symmetric 3x3 matrix with upper triangle a, by the adjugate (0 if
    singular): the cofactors and the determinant by the first row, summed as
    :func:`engine.math3d.sym3_inverse` sums them."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    inv_det = 1.0 / det if det != 0.0 else 0.0
    return c00 * inv_det, c01 * inv_det, c02 * inv_det, c11 * inv_det, c12 * inv_det, c22 * inv_det


@kernel
def minimum(a, b):
    """The smaller of two floats, NaN if either is (as ``np.minimum``; the
    builtin ``min`` drops a NaN second argument)."""
    if a != a:
        return a
    if b != b:
        return b
    return b if b < a else a
