"""engine.math3d: products on a few vectors take compact numpy forms and on
large batches written-out ones; both must give the same bits, or a world's
trajectory would depend on the batch it is stepped in."""

import numpy as np
import pytest

from engine import math3d as M

BIG = 4096  # rows: above every small-batch threshold of math3d


def _rows(shape, seed):
    return np.random.default_rng(seed).normal(size=shape)


@pytest.mark.parametrize("name, shapes", [
    ("dot", ((3,), (3,))),
    ("cross", ((3,), (3,))),
    ("mat_vec", ((3, 3), (3,))),
    ("quat_mul", ((4,), (4,))),
    ("quat_rotate", ((4,), (3,))),
    ("quat_to_matrix", ((4,),)),
    ("sym3_inverse", ((3, 3),)),
])
def test_small_and_large_batches_give_the_same_bits(name, shapes):
    fn = getattr(M, name)
    args = [_rows((BIG,) + s, seed) for seed, s in enumerate(shapes)]
    if name in ("quat_rotate", "quat_to_matrix"):
        args[0] = M.quat_normalize(args[0])
    if name == "sym3_inverse":
        args[0] = args[0] @ np.swapaxes(args[0], -1, -2)
    big = fn(*args)
    for k in range(0, BIG, 97):  # one row at a time, and a few rows at a time
        one = fn(*[a[k:k + 1] for a in args])
        few = fn(*[a[k:k + 5] for a in args])
        np.testing.assert_array_equal(one, big[k:k + 1])
        np.testing.assert_array_equal(few, big[k:k + 5])
        assert np.array_equal(np.signbit(one), np.signbit(big[k:k + 1]))


def test_compact_forms_are_the_textbook_products():
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    m = rng.normal(size=(5, 3, 3))
    np.testing.assert_allclose(M.dot(a, b), np.einsum("ij,ij->i", a, b), rtol=1e-14)
    np.testing.assert_allclose(M.cross(a, b), np.cross(a, b), rtol=1e-14)
    np.testing.assert_allclose(M.mat_vec(m, a), np.einsum("ijk,ik->ij", m, a), rtol=1e-14)
    q = M.quat_normalize(rng.normal(size=(5, 4)))
    r = M.quat_to_matrix(q)
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-14)
    np.testing.assert_allclose(M.quat_rotate(q, a), np.einsum("ijk,ik->ij", r, a), atol=1e-14)
    # p ⊗ q rotates as R(p) R(q)
    p = M.quat_normalize(rng.normal(size=(5, 4)))
    np.testing.assert_allclose(M.quat_to_matrix(M.quat_mul(p, q)), M.quat_to_matrix(p) @ r, atol=1e-14)
    k = m @ np.swapaxes(m, -1, -2) + np.eye(3)
    np.testing.assert_allclose(M.sym3_inverse(k) @ k, np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-12)


def test_rotation_vector_inverts_axis_angle():
    rng = np.random.default_rng(3)
    axis = rng.normal(size=(50, 3))
    angle = rng.uniform(0.0, np.pi, size=50)
    angle[:3] = (0.0, 1e-9, np.pi - 1e-9)
    q = M.quat_from_axis_angle(axis, angle)
    expected = axis / np.linalg.norm(axis, axis=-1, keepdims=True) * angle[:, None]
    np.testing.assert_allclose(M.quat_to_rotation_vector(q), expected, atol=1e-12)
    # -q is the same rotation.
    np.testing.assert_allclose(M.quat_to_rotation_vector(-q), expected, atol=1e-12)
