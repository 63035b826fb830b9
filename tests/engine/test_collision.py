"""Collision detection against analytic geometry.

Each test states its tolerance; most configurations are exact in floating
point up to a few ulps, so 1e-9 m is used unless a brute-force sampled
reference sets a looser one.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import engine as e
from engine.collision import (
    INVALID_SEPARATION,
    PAIR_FUNCTIONS,
    aabb,
    box_box,
    candidate_pairs,
    capsule_box,
    capsule_capsule,
    collide,
    collide_rows,
    overlapping,
    plane_box,
    plane_capsule,
    plane_sphere,
    sphere_box,
    sphere_capsule,
    sphere_sphere,
)
from engine.core.collide import KIND_CODES, detect, detect_serial
from engine.core.jit import SERIAL_BELOW
from engine.math3d import norm, quat_from_axis_angle, quat_mul, quat_normalize, quat_rotate, quat_rotate_inv
from engine.shapes import BOX, CAPSULE, NONE, PLANE, SPHERE

TOL = 1e-9  # m, for configurations computed exactly up to rounding
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
MARGIN = 0.02  # m


def one(v):
    """A single pair in a single world: (3,) -> (1, 1, 3), (4,) -> (1, 1, 4)."""
    return np.asarray(v, dtype=float)[None, None]


def par(*p):
    """Shape parameters of one pair: (1, 3)."""
    p = list(p) + [0.0] * (3 - len(p))
    return np.array([p], dtype=float)


def rot(axis, angle):
    return quat_from_axis_angle(np.asarray(axis, float), angle)


def call(fn, pa, qa, ha, pb, qb, hb, margin=MARGIN):
    return fn(one(pa), one(qa), par(*ha), one(pb), one(qb), par(*hb), margin)


def valid_points(m):
    """(points, separations) of the valid slots of pair (0, 0)."""
    v = m.valid[0, 0]
    return m.point[0, 0][v], m.separation[0, 0][v]


def sorted_rows(a):
    return a[np.lexsort(a.T[::-1])]


# ----------------------------------------------------------------- plane pairs

def test_plane_sphere_resting_penetration():
    # Sphere r=0.5 with its centre 0.49 m above the ground: 1 cm deep.
    m = call(plane_sphere, (0, 0, 0), IDENTITY, (), (1.0, 2.0, 0.49), IDENTITY, (0.5,))
    pts, sep = valid_points(m)
    assert len(sep) == 1
    assert sep[0] == pytest.approx(-0.01, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (0, 0, 1), atol=TOL)
    np.testing.assert_allclose(pts[0], (1.0, 2.0, -0.005), atol=TOL)  # midway between surfaces
    assert not m.valid[0, 0, 1:].any() and np.all(m.separation[0, 0, 1:] == INVALID_SEPARATION)


def test_plane_sphere_tilted_plane_and_speculative_margin():
    # Plane through (0,0,1) tilted 30 degrees about x; sphere 0.01 m above its surface.
    q = rot((1, 0, 0), math.radians(30))
    n = quat_rotate(q, np.array([0.0, 0, 1]))
    centre = np.array([0.0, 0, 1]) + n * (0.3 + 0.01)
    m = call(plane_sphere, (0, 0, 1), q, (), centre, IDENTITY, (0.3,), margin=0.02)
    assert m.valid[0, 0, 0] and m.separation[0, 0, 0] == pytest.approx(0.01, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], n, atol=TOL)
    # The same gap with a smaller margin is no contact.
    m = call(plane_sphere, (0, 0, 1), q, (), centre, IDENTITY, (0.3,), margin=0.005)
    assert not m.valid.any() and np.isinf(m.separation).all()


def test_capsule_lying_on_plane_gives_two_points():
    q = rot((0, 1, 0), math.pi / 2)  # capsule axis along world x
    m = call(plane_capsule, (0, 0, 0), IDENTITY, (), (0, 0, 0.095), q, (0.1, 0.4))
    pts, sep = valid_points(m)
    assert len(sep) == 2
    np.testing.assert_allclose(sep, [-0.005, -0.005], atol=TOL)
    np.testing.assert_allclose(sorted_rows(pts), [[-0.4, 0, -0.0025], [0.4, 0, -0.0025]], atol=TOL)


def test_capsule_standing_on_plane_gives_one_point():
    m = call(plane_capsule, (0, 0, 0), IDENTITY, (), (0, 0, 0.49), IDENTITY, (0.1, 0.4))
    pts, sep = valid_points(m)
    assert len(sep) == 1 and m.valid[0, 0, 0]  # slot 0 is the local -z end
    assert sep[0] == pytest.approx(-0.01, abs=TOL)


def test_box_flat_on_plane_gives_four_corners():
    h = (0.3, 0.2, 0.1)
    m = call(plane_box, (0, 0, 0), IDENTITY, (), (0.5, -0.5, 0.098), IDENTITY, h)
    pts, sep = valid_points(m)
    assert len(sep) == 4
    np.testing.assert_allclose(sep, -0.002, atol=TOL)
    expected = [(0.5 + sx * 0.3, -0.5 + sy * 0.2, -0.001) for sx in (-1, 1) for sy in (-1, 1)]
    np.testing.assert_allclose(sorted_rows(pts), sorted_rows(np.array(expected)), atol=TOL)


def test_box_on_edge_gives_two_points_and_on_corner_one():
    h = (0.5, 0.5, 0.5)
    # Rotated 45 degrees about x: the lowest edge (along x) is sqrt(2)/2 below the centre.
    q = rot((1, 0, 0), math.pi / 4)
    m = call(plane_box, (0, 0, 0), IDENTITY, (), (0, 0, math.sqrt(0.5) - 0.003), q, h)
    pts, sep = valid_points(m)
    assert len(sep) == 2
    np.testing.assert_allclose(sep, -0.003, atol=TOL)
    np.testing.assert_allclose(sorted_rows(pts), [[-0.5, 0, -0.0015], [0.5, 0, -0.0015]], atol=TOL)
    # A body diagonal vertical: the lowest corner is sqrt(3)/2 below the centre.
    diag = np.array([1.0, 1.0, 1.0]) / math.sqrt(3)
    axis = np.cross(diag, [0, 0, -1.0])
    q = rot(axis, math.acos(-diag[2]))
    m = call(plane_box, (0, 0, 0), IDENTITY, (), (0, 0, math.sqrt(0.75) - 0.004), q, h)
    pts, sep = valid_points(m)
    assert len(sep) == 1
    assert sep[0] == pytest.approx(-0.004, abs=1e-12 + TOL)
    np.testing.assert_allclose(pts[0], (0, 0, -0.002), atol=TOL)


def test_box_on_plane_slots_stable_under_small_rocking():
    # A box rocking slightly keeps each bottom corner in the same slot.
    h = (0.3, 0.2, 0.1)
    slots = []
    for angle in (-0.01, -0.001, 0.0, 0.002, 0.01):
        q = rot((0.3, 1.0, 0.0), angle)
        m = call(plane_box, (0, 0, 0), IDENTITY, (), (0, 0, 0.099), q, h, margin=0.05)
        assert m.valid.all()
        local = quat_rotate_inv(q, m.point[0, 0] - np.array([0, 0, 0.099]))
        slots.append(np.sign(local[:, :2]))
    for s in slots[1:]:
        np.testing.assert_array_equal(s, slots[0])


# ----------------------------------------------------------------- round pairs

def test_sphere_sphere_distance_and_normal():
    d = np.array([0.3, -0.4, 1.2])
    dist = np.linalg.norm(d)
    pa = np.array([1.0, 2.0, 3.0])
    m = call(sphere_sphere, pa, IDENTITY, (0.5,), pa + d, IDENTITY, (0.8,), margin=0.1)
    assert m.separation[0, 0, 0] == pytest.approx(dist - 1.3, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], d / dist, atol=TOL)
    # midpoint between the surface points pa + 0.5 n and pb - 0.8 n
    np.testing.assert_allclose(m.point[0, 0, 0], pa + d / dist * (0.5 + (dist - 1.3) / 2), atol=TOL)
    assert m.count[0, 0] == 1


def test_sphere_capsule_side_and_cap():
    q = rot((0, 1, 0), math.pi / 2)  # capsule along x, half length 0.5, radius 0.1
    # Beside the cylinder part: closest axis point (0.2, 0, 0).
    m = call(sphere_capsule, (0.2, 0, 0.35), IDENTITY, (0.2,), (0, 0, 0), q, (0.1, 0.5), margin=0.1)
    assert m.separation[0, 0, 0] == pytest.approx(0.05, abs=TOL) and m.valid[0, 0, 0]
    assert not call(sphere_capsule, (0.2, 0, 0.35), IDENTITY, (0.2,), (0, 0, 0), q, (0.1, 0.5)).valid.any()
    np.testing.assert_allclose(m.normal[0, 0], (0, 0, -1), atol=TOL)
    m = call(sphere_capsule, (0.2, 0, 0.29), IDENTITY, (0.2,), (0, 0, 0), q, (0.1, 0.5))
    assert m.valid[0, 0, 0] and m.separation[0, 0, 0] == pytest.approx(-0.01, abs=TOL)
    # Beyond the end cap: distance to the end point (0.5, 0, 0).
    m = call(sphere_capsule, (0.8, 0.4, 0), IDENTITY, (0.2,), (0, 0, 0), q, (0.1, 0.5), margin=1.0)
    assert m.separation[0, 0, 0] == pytest.approx(0.5 - 0.3, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (-0.6, -0.8, 0), atol=TOL)


def test_parallel_capsules_give_two_points_over_overlap():
    q = rot((0, 1, 0), math.pi / 2)  # both along x
    # b shifted 0.3 along x and lying on top of a, 1 cm deep.
    m = call(capsule_capsule, (0, 0, 0), q, (0.1, 0.5), (0.3, 0, 0.19), q, (0.1, 0.5))
    pts, sep = valid_points(m)
    assert len(sep) == 2
    np.testing.assert_allclose(sep, -0.01, atol=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (0, 0, 1), atol=TOL)
    np.testing.assert_allclose(sorted_rows(pts), [[-0.2, 0, 0.095], [0.5, 0, 0.095]], atol=TOL)


def test_nearly_parallel_capsules_still_two_points_crossing_one():
    qa = rot((0, 1, 0), math.pi / 2)
    qb = quat_mul(rot((0, 0, 1), 0.005), qa)  # 0.005 rad off parallel
    m = call(capsule_capsule, (0, 0, 0), qa, (0.1, 0.5), (0, 0, 0.195), qb, (0.1, 0.5))
    assert m.count[0, 0] == 2
    # Exact per-point separations: distance of a's axis end to b's segment, minus radii.
    _, sep = valid_points(m)
    lateral = 0.5 * math.sin(0.005)
    np.testing.assert_allclose(sep, math.hypot(0.195, lateral) - 0.2, atol=1e-6)
    # Crossing at right angles: one point where the axes cross.
    qc = rot((1, 0, 0), math.pi / 2)
    m = call(capsule_capsule, (0, 0, 0), qa, (0.1, 0.5), (0.1, 0, 0.19), qc, (0.1, 0.5))
    pts, sep = valid_points(m)
    assert len(sep) == 1 and sep[0] == pytest.approx(-0.01, abs=TOL)
    np.testing.assert_allclose(pts[0], (0.1, 0, 0.095), atol=TOL)


def test_coincident_and_intersecting_capsules_are_finite():
    q = rot((0, 1, 0), math.pi / 2)
    for qb, pb in ((q, (0, 0, 0)), (IDENTITY, (0, 0, 0)), (q, (0.2, 0, 0))):
        m = call(capsule_capsule, (0, 0, 0), q, (0.1, 0.5), pb, qb, (0.1, 0.5))
        assert np.isfinite(m.normal).all() and np.isfinite(m.point).all()
        assert np.linalg.norm(m.normal[0, 0]) == pytest.approx(1.0, abs=TOL)
        _, sep = valid_points(m)
        np.testing.assert_allclose(sep, -0.2, atol=TOL)  # axes meet: depth = r_a + r_b


# ------------------------------------------------------------ round vs box

def test_sphere_box_face_corner_inside():
    h = (0.5, 0.4, 0.3)
    m = call(sphere_box, (0, 0, 0.39), IDENTITY, (0.1,), (0, 0, 0), IDENTITY, h)
    assert m.separation[0, 0, 0] == pytest.approx(-0.01, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (0, 0, -1), atol=TOL)  # sphere -> box
    np.testing.assert_allclose(m.point[0, 0, 0], (0, 0, 0.295), atol=TOL)
    # Corner region: distance to the corner (0.5, 0.4, 0.3).
    c = np.array([0.5, 0.4, 0.3]) + np.array([1.0, 2.0, 2.0]) / 3 * 0.12
    assert not call(sphere_box, c, IDENTITY, (0.1,), (0, 0, 0), IDENTITY, h, margin=0.015).valid.any()
    m = call(sphere_box, c, IDENTITY, (0.1,), (0, 0, 0), IDENTITY, h, margin=0.03)
    assert m.separation[0, 0, 0] == pytest.approx(0.02, abs=TOL) and m.valid[0, 0, 0]
    np.testing.assert_allclose(m.normal[0, 0], -np.array([1.0, 2.0, 2.0]) / 3, atol=TOL)
    # Centre inside: pushed out through the nearest face (+y, 0.05 away).
    m = call(sphere_box, (0.1, 0.35, 0), IDENTITY, (0.1,), (0, 0, 0), IDENTITY, h)
    assert m.separation[0, 0, 0] == pytest.approx(-0.15, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (0, -1, 0), atol=TOL)


def test_capsule_lying_on_box_face_gives_two_points():
    q = rot((0, 1, 0), math.pi / 2)  # along x, half length 0.5
    h = (1.0, 1.0, 0.5)
    for z, depth in ((0.599, -0.001), (0.59, -0.01), (0.61, 0.01)):
        m = call(capsule_box, (0.2, 0.1, z), q, (0.1, 0.5), (0, 0, 0), IDENTITY, h)
        pts, sep = valid_points(m)
        assert len(sep) == 2, z
        np.testing.assert_allclose(sep, depth, atol=TOL)
        np.testing.assert_allclose(m.normal[0, 0], (0, 0, -1), atol=TOL)
        np.testing.assert_allclose(sorted_rows(pts), [[-0.3, 0.1, 0.5 + depth / 2], [0.7, 0.1, 0.5 + depth / 2]],
                                   atol=TOL)
    # Hanging over the edge: clipped to the face, the outer point sits at x = 1.
    m = call(capsule_box, (0.8, 0, 0.59), q, (0.1, 0.5), (0, 0, 0), IDENTITY, h)
    pts, _ = valid_points(m)
    np.testing.assert_allclose(sorted_rows(pts)[:, 0], [0.3, 1.0], atol=TOL)


def test_capsule_standing_on_box_and_near_edge():
    h = (1.0, 1.0, 0.5)
    m = call(capsule_box, (0.2, 0, 1.09), IDENTITY, (0.1, 0.5), (0, 0, 0), IDENTITY, h)
    pts, sep = valid_points(m)
    assert len(sep) == 1 and sep[0] == pytest.approx(-0.01, abs=TOL)
    np.testing.assert_allclose(pts[0], (0.2, 0, 0.495), atol=TOL)
    # Capsule parallel to y, beside the top edge along y at (1, *, 0.5): gap to the edge.
    q = rot((1, 0, 0), math.pi / 2)
    centre = np.array([1.0, 0, 0.5]) + np.array([0.6, 0, 0.8]) * 0.11
    m = call(capsule_box, centre, q, (0.1, 0.5), (0, 0, 0), IDENTITY, h)
    assert m.count[0, 0] == 1 and m.separation[0, 0, 0] == pytest.approx(0.01, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (-0.6, 0, -0.8), atol=TOL)


# ----------------------------------------------------------------- box vs box

def test_box_resting_on_larger_box_gives_four_points():
    m = call(box_box, (0, 0, 0), IDENTITY, (2.0, 2.0, 0.5), (0.1, 0.2, 0.99), IDENTITY, (0.5, 0.4, 0.5))
    pts, sep = valid_points(m)
    assert len(sep) == 4
    np.testing.assert_allclose(sep, -0.01, atol=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (0, 0, 1), atol=TOL)
    expected = [(0.1 + sx * 0.5, 0.2 + sy * 0.4, 0.495) for sx in (-1, 1) for sy in (-1, 1)]
    np.testing.assert_allclose(sorted_rows(pts), sorted_rows(np.array(expected)), atol=TOL)
    # Same pair the other way round: same points, opposite normal.
    m2 = call(box_box, (0.1, 0.2, 0.99), IDENTITY, (0.5, 0.4, 0.5), (0, 0, 0), IDENTITY, (2.0, 2.0, 0.5))
    np.testing.assert_allclose(m2.normal[0, 0], (0, 0, -1), atol=TOL)
    np.testing.assert_allclose(sorted_rows(valid_points(m2)[0]), sorted_rows(pts), atol=TOL)


def test_box_on_same_size_box_rotated_reduces_to_four_points():
    # The overlap of two unit squares rotated 0.3 rad is an octagon: 8 clipped
    # points, reduced to 4, all 1 cm deep and inside both footprints.
    qb = rot((0, 0, 1), 0.3)
    m = call(box_box, (0, 0, 0), IDENTITY, (0.5, 0.5, 0.5), (0, 0, 0.99), qb, (0.5, 0.5, 0.5))
    pts, sep = valid_points(m)
    assert len(sep) == 4
    np.testing.assert_allclose(sep, -0.01, atol=TOL)
    assert np.all(np.abs(pts[:, :2]) <= 0.5 + TOL)
    local = quat_rotate_inv(qb, pts)
    assert np.all(np.abs(local[:, :2]) <= 0.5 + TOL)
    # The 4 chosen points span a large part of the octagon (area > half of it).
    hull = pts[:, :2][np.argsort(np.arctan2(pts[:, 1], pts[:, 0]))]
    area = 0.5 * abs(np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - hull[:, 1] * np.roll(hull[:, 0], -1)))
    assert area > 0.5


def test_box_edge_on_box_edge_gives_one_point():
    # a: top edge along y (rotated 45 deg about y); b: bottom edge along x.
    qa = rot((0, 1, 0), math.pi / 4)
    qb = rot((1, 0, 0), math.pi / 4)
    zb = 2 * math.sqrt(0.5) - 0.01
    m = call(box_box, (0, 0, 0), qa, (0.5, 0.5, 0.5), (0, 0, zb), qb, (0.5, 0.5, 0.5))
    pts, sep = valid_points(m)
    assert len(sep) == 1
    assert sep[0] == pytest.approx(-0.01, abs=TOL)
    np.testing.assert_allclose(m.normal[0, 0], (0, 0, 1), atol=TOL)
    np.testing.assert_allclose(pts[0], (0, 0, math.sqrt(0.5) - 0.005), atol=TOL)


def test_box_box_separated_and_coincident():
    m = call(box_box, (0, 0, 0), IDENTITY, (0.5, 0.5, 0.5), (0, 0, 1.05), IDENTITY, (0.5, 0.5, 0.5))
    assert not m.valid.any()
    m = call(box_box, (0, 0, 0), IDENTITY, (0.5, 0.5, 0.5), (0, 0, 1.01), IDENTITY, (0.5, 0.5, 0.5))
    _, sep = valid_points(m)
    np.testing.assert_allclose(sep, 0.01, atol=TOL)  # speculative contacts
    m = call(box_box, (0, 0, 0), IDENTITY, (0.5, 0.5, 0.5), (0, 0, 0), IDENTITY, (0.5, 0.5, 0.5))
    assert np.isfinite(m.normal).all() and np.isfinite(m.point).all() and m.count[0, 0] == 4
    np.testing.assert_allclose(valid_points(m)[1], -1.0, atol=TOL)


def test_box_on_box_slots_stable_under_small_perturbation():
    ref = None
    for dx, angle in ((0.0, 0.0), (0.001, 0.001), (-0.002, -0.003), (0.003, 0.002)):
        qb = rot((0.2, 1.0, 0.1), angle)
        m = call(box_box, (0, 0, 0), IDENTITY, (2.0, 2.0, 0.5), (dx, 0, 0.99), qb, (0.5, 0.4, 0.5), margin=0.05)
        assert m.count[0, 0] == 4
        local = quat_rotate_inv(qb, m.point[0, 0] - np.array([dx, 0, 0.99]))
        signs = np.sign(local[:, :2])
        if ref is None:
            ref = signs
        np.testing.assert_array_equal(signs, ref)


# ------------------------------------------------- random configurations

SHAPE_PARAMS = {PLANE: (0.0, 0.0, 0.0), SPHERE: (0.3, 0.0, 0.0), CAPSULE: (0.15, 0.4, 0.0), BOX: (0.4, 0.3, 0.2)}
ALL_KINDS = [(a, b) for a, b in itertools.product(SHAPE_PARAMS, repeat=2) if not (a == PLANE and b == PLANE)]


def random_scene(rng, W, P, spread=1.0):
    pos_a = rng.uniform(-spread, spread, size=(W, P, 3))
    pos_b = rng.uniform(-spread, spread, size=(W, P, 3))
    qa = quat_normalize(rng.normal(size=(W, P, 4)))
    qb = quat_normalize(rng.normal(size=(W, P, 4)))
    return pos_a, qa, pos_b, qb


def random_params(rng, kind, P):
    base = np.array(SHAPE_PARAMS[kind])
    return np.where(base > 0, base * rng.uniform(0.5, 1.5, size=(P, 3)), 0.0)


@pytest.mark.parametrize("ta,tb", [(a, b) for a, b in ALL_KINDS if a != b])
def test_swapped_order_flips_normal(ta, tb):
    # Tolerance: exact (the dispatcher swaps arguments, it does not recompute).
    rng = np.random.default_rng(10 * ta + tb)
    pa, qa, pb, qb = random_scene(rng, 2, 50)
    ha, hb = random_params(rng, ta, 50), random_params(rng, tb, 50)
    m1 = collide(ta, tb, pa, qa, ha, pb, qb, hb, 0.1)
    m2 = collide(tb, ta, pb, qb, hb, pa, qa, ha, 0.1)
    np.testing.assert_array_equal(m1.normal, -m2.normal)
    np.testing.assert_array_equal(m1.point, m2.point)
    np.testing.assert_array_equal(m1.separation, m2.separation)
    np.testing.assert_array_equal(m1.valid, m2.valid)


@pytest.mark.parametrize("kind", [SPHERE, CAPSULE])
def test_same_kind_pairs_are_symmetric(kind):
    # Round shapes: swapping a and b flips the normal and keeps the deepest
    # separation (tolerance 1e-12 m; the two orders round differently).
    rng = np.random.default_rng(kind)
    pa, qa, pb, qb = random_scene(rng, 2, 50)
    ha, hb = random_params(rng, kind, 50), random_params(rng, kind, 50)
    m1 = collide(kind, kind, pa, qa, ha, pb, qb, hb, 0.1)
    m2 = collide(kind, kind, pb, qb, hb, pa, qa, ha, 0.1)
    single = (m1.count == 1) & (m2.count == 1)
    np.testing.assert_allclose(m1.normal[single], -m2.normal[single], atol=1e-12)
    np.testing.assert_allclose(m1.separation[single].min(axis=-1), m2.separation[single].min(axis=-1), atol=1e-12)


@pytest.mark.parametrize("ta,tb", ALL_KINDS)
def test_batched_equals_per_world_bit_for_bit(ta, tb):
    rng = np.random.default_rng(100 + 10 * ta + tb)
    W, P = 5, 40
    pa, qa, pb, qb = random_scene(rng, W, P)
    ha, hb = random_params(rng, ta, P), random_params(rng, tb, P)
    batched = collide(ta, tb, pa, qa, ha, pb, qb, hb, 0.05)
    for w in range(W):
        single = collide(ta, tb, pa[w:w + 1], qa[w:w + 1], ha, pb[w:w + 1], qb[w:w + 1], hb, 0.05)
        for name in ("normal", "point", "separation", "valid"):
            np.testing.assert_array_equal(getattr(batched, name)[w:w + 1], getattr(single, name), err_msg=name)
    # Also pair by pair (P = 1): the pair axis is as batch-independent as the world axis.
    for p in range(0, P, 7):
        single = collide(ta, tb, pa[:, p:p + 1], qa[:, p:p + 1], ha[p:p + 1], pb[:, p:p + 1], qb[:, p:p + 1],
                         hb[p:p + 1], 0.05)
        np.testing.assert_array_equal(batched.point[:, p:p + 1], single.point)
        np.testing.assert_array_equal(batched.separation[:, p:p + 1], single.separation)


@pytest.mark.parametrize("ta,tb", ALL_KINDS)
def test_outputs_finite_and_normals_unit(ta, tb):
    # Random poses plus degenerate ones: coincident centres and equal orientations.
    rng = np.random.default_rng(200 + 10 * ta + tb)
    pa, qa, pb, qb = random_scene(rng, 2, 60)
    pb[:, :20] = pa[:, :20]
    qb[:, :10] = qa[:, :10]
    pa[:, 20:25] = 0.0
    pb[:, 20:25] = 0.0
    qa[:, 20:25] = IDENTITY
    qb[:, 20:25] = IDENTITY
    ha, hb = random_params(rng, ta, 60), random_params(rng, tb, 60)
    with np.errstate(all="raise"):
        m = collide(ta, tb, pa, qa, ha, pb, qb, hb, 0.02)
    assert np.isfinite(m.normal).all() and np.isfinite(m.point).all()
    np.testing.assert_allclose(np.linalg.norm(m.normal, axis=-1), 1.0, atol=1e-12)
    assert np.isfinite(m.separation[m.valid]).all()
    assert np.all(m.separation[~m.valid] == INVALID_SEPARATION)
    assert m.valid[:, :20].any(axis=-1).all() or ta == PLANE  # coincident solids always touch


@pytest.mark.parametrize("ta", [SPHERE, CAPSULE, BOX])
def test_coincident_centres_give_fixed_finite_contact(ta):
    for tb in (SPHERE, CAPSULE, BOX):
        m = collide(ta, tb, one((1, 2, 3)), one(IDENTITY), par(*SHAPE_PARAMS[ta]), one((1, 2, 3)), one(IDENTITY),
                    par(*SHAPE_PARAMS[tb]), 0.01)
        assert np.isfinite(m.normal).all() and np.isfinite(m.point).all() and m.valid[0, 0, 0]
        assert m.separation[0, 0, 0] < 0


def _point_box_distance(p, h):
    return np.linalg.norm(p - np.clip(p, -h, h), axis=-1)


def test_capsule_box_gap_matches_brute_force():
    # Separated capsules: the reported gap equals a brute-force minimum over
    # 2001 samples of the axis (tolerance 1e-6 m, the sampling error bound).
    rng = np.random.default_rng(7)
    W, P = 1, 400
    pa, qa, pb, qb = random_scene(rng, W, P, spread=1.5)
    ha, hb = random_params(rng, CAPSULE, P), random_params(rng, BOX, P)
    m = capsule_box(pa, qa, ha, pb, qb, hb, 10.0)
    u = quat_rotate(qa, np.array([0.0, 0, 1]))
    s = np.linspace(-1, 1, 2001)[:, None]
    samples = pa[..., None, :] + u[..., None, :] * (ha[None, :, 1, None, None] * s)
    local = quat_rotate_inv(np.broadcast_to(qb[..., None, :], samples.shape[:-1] + (4,)), samples - pb[..., None, :])
    gap = _point_box_distance(local, hb[None, :, None, :]).min(axis=-1) - ha[None, :, 0]
    reported = np.where(m.valid, m.separation, np.inf).min(axis=-1)
    apart = gap > 1e-3
    assert apart.sum() > 100
    np.testing.assert_allclose(reported[apart], gap[apart], atol=1e-6)
    assert np.all(reported[~apart] <= gap[~apart] + 1e-9)


def test_capsule_capsule_gap_matches_brute_force():
    # Crossing capsules (one point): exact closest distance, never above the
    # sampled minimum (tolerance 1e-12 m).
    rng = np.random.default_rng(8)
    W, P = 1, 400
    pa, qa, pb, qb = random_scene(rng, W, P)
    ha, hb = random_params(rng, CAPSULE, P), random_params(rng, CAPSULE, P)
    m = capsule_capsule(pa, qa, ha, pb, qb, hb, 10.0)
    ua = quat_rotate(qa, np.array([0.0, 0, 1]))
    ub = quat_rotate(qb, np.array([0.0, 0, 1]))
    s = np.linspace(-1, 1, 1001)[:, None]
    sa = pa[..., None, :] + ua[..., None, :] * (ha[None, :, 1, None, None] * s)
    tau = np.clip(np.sum((sa - pb[..., None, :]) * ub[..., None, :], axis=-1), -hb[None, :, 1, None],
                  hb[None, :, 1, None])
    nearest = pb[..., None, :] + ub[..., None, :] * tau[..., None]
    gap = np.linalg.norm(sa - nearest, axis=-1).min(axis=-1) - ha[None, :, 0] - hb[None, :, 0]
    single = m.count == 1
    assert single.sum() > 300
    reported = m.separation[..., 0]
    assert np.all(reported[single] <= gap[single] + 1e-12)
    np.testing.assert_allclose(reported[single], gap[single], atol=1e-3)  # sampling step bound


def test_box_box_penetrating_points_lie_on_both_surfaces():
    # Each valid point p with separation s has p - n s/2 on a's surface and
    # p + n s/2 on b's surface (tolerance 1e-9 m), for penetrating pairs.
    rng = np.random.default_rng(9)
    W, P = 1, 1500
    pa, qa, pb, qb = random_scene(rng, W, P, spread=0.6)
    ha, hb = random_params(rng, BOX, P), random_params(rng, BOX, P)
    m = box_box(pa, qa, ha, pb, qb, hb, 0.02)
    use = m.valid & (m.separation <= 0)
    assert use.any(axis=-1).sum() > 300
    half = m.normal[..., None, :] * (np.where(use, m.separation, 0.0) / 2)[..., None]

    def surface_error(p, pos, q, h):
        local = quat_rotate_inv(np.broadcast_to(q[..., None, :], p.shape[:-1] + (4,)), p - pos[..., None, :])
        return np.max(np.abs(local) - h[None, :, None, :], axis=-1)

    np.testing.assert_allclose(surface_error(m.point - half, pa, qa, ha)[use], 0.0, atol=1e-9)
    np.testing.assert_allclose(surface_error(m.point + half, pb, qb, hb)[use], 0.0, atol=1e-9)
    # and the normal points from a to b
    assert np.all(np.sum((pb - pa) * m.normal, axis=-1)[m.count > 0] > 0)


def test_dispatcher_rejects_impossible_pairs():
    x = one((0, 0, 0))
    q = one(IDENTITY)
    with pytest.raises(ValueError):
        collide(PLANE, PLANE, x, q, par(), x, q, par(), 0.01)
    with pytest.raises(ValueError):
        collide(NONE, SPHERE, x, q, par(), x, q, par(0.1), 0.01)
    assert len(PAIR_FUNCTIONS) == 9


# ------------------------------------------------------------------ broadphase

def test_candidate_pairs_filters():
    #        0 ground  1 ball   2 box    3 static box  4 none  5 capsule  6 plane  7 ghost
    types = [PLANE, SPHERE, BOX, BOX, NONE, CAPSULE, PLANE, SPHERE]
    dynamic = [False, True, True, False, False, True, False, True]
    group = [1, 1, 1, 1, 1, 1, 1, 2]
    mask = [0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFE]  # 7 ignores group 1
    a, b = candidate_pairs(np.array(types), np.array(dynamic), np.array(group), np.array(mask),
                           excluded={(2, 5)})
    got = {tuple(sorted(p)) for p in zip(a.tolist(), b.tolist())}
    expected = {(0, 1), (0, 2), (0, 5), (1, 2), (1, 3), (1, 5), (1, 6), (2, 3), (2, 6), (3, 5), (5, 6)}
    assert got == expected
    assert len(got) == len(a)
    # Oriented in canonical order: plane, sphere, capsule, box.
    order = {PLANE: 0, SPHERE: 1, CAPSULE: 2, BOX: 3}
    for i, j in zip(a, b):
        assert order[types[i]] <= order[types[j]]
    # Excluded pairs are excluded in either orientation.
    a2, b2 = candidate_pairs(np.array(types), np.array(dynamic), np.array(group), np.array(mask),
                             excluded={(5, 2), (1, 0)})
    got2 = {tuple(sorted(p)) for p in zip(a2.tolist(), b2.tolist())}
    assert got2 == expected - {(0, 1)}


def test_aabb_bounds_and_overlap():
    types = np.array([SPHERE, CAPSULE, BOX, PLANE, NONE])
    params = np.array([[0.5, 0, 0], [0.1, 0.4, 0], [0.5, 0.5, 0.5], [0, 0, 0], [0, 0, 0]])
    pos = np.array([[[0, 0, 0], [2, 0, 0], [0, 3, 0], [0, 0, -1], [0, 0, 0]]], dtype=float)
    q45 = rot((0, 0, 1), math.pi / 4)
    qx = rot((0, 1, 0), math.pi / 2)  # capsule axis along x
    quat = np.array([[IDENTITY, qx, q45, IDENTITY, IDENTITY]])
    lo, hi = aabb(types, params, pos, quat)
    np.testing.assert_allclose(lo[0, 0], (-0.5, -0.5, -0.5), atol=TOL)
    np.testing.assert_allclose(hi[0, 1], (2.5, 0.1, 0.1), atol=TOL)
    np.testing.assert_allclose(lo[0, 1], (1.5, -0.1, -0.1), atol=TOL)
    r = math.sqrt(0.5)
    np.testing.assert_allclose(hi[0, 2], (r, 3 + r, 0.5), atol=TOL)
    assert np.all(np.isneginf(lo[0, 3])) and np.all(np.isposinf(hi[0, 3]))
    pairs_a = np.array([3, 0, 0, 1])
    pairs_b = np.array([2, 1, 2, 2])
    ok = overlapping(lo, hi, pairs_a, pairs_b, 0.0)
    # plane always; sphere-capsule 1.0 apart on x (0.5 vs 1.5); sphere-box 3 - r - 0.5 apart.
    np.testing.assert_array_equal(ok[0], [True, False, False, False])
    ok = overlapping(lo, hi, pairs_a, pairs_b, 0.51)  # each box grows 0.51: gaps up to 1.02 close
    np.testing.assert_array_equal(ok[0], [True, True, False, False])
    assert ok.shape == (1, 4)


def test_aabb_contains_shape_for_random_poses():
    # Every sampled surface point lies inside the AABB (tolerance 1e-12 m).
    rng = np.random.default_rng(3)
    N = 30
    types = np.array([SPHERE, CAPSULE, BOX] * 10)
    params = np.array([random_params(rng, t, 1)[0] for t in types])
    pos = rng.uniform(-1, 1, size=(2, N, 3))
    quat = quat_normalize(rng.normal(size=(2, N, 4)))
    lo, hi = aabb(types, params, pos, quat)
    signs = np.array(list(itertools.product((-1, 1), repeat=3)), dtype=float)
    for n, t in enumerate(types):
        if t == BOX:
            local = signs * params[n]
        elif t == CAPSULE:
            d = rng.normal(size=(200, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            local = d * params[n, 0] + np.array([0, 0, 1.0]) * params[n, 1] * np.sign(d[:, 2:3])
        else:
            d = rng.normal(size=(200, 3))
            local = d / np.linalg.norm(d, axis=1, keepdims=True) * params[n, 0]
        for w in range(2):
            world = pos[w, n] + quat_rotate(np.broadcast_to(quat[w, n], (len(local), 4)), local)
            assert np.all(world >= lo[w, n] - 1e-12) and np.all(world <= hi[w, n] + 1e-12)


# ------------------------------------------------- the step's detection kernels

def all_kinds_scene(speculative_distance=0.02):
    """The ground, two spheres, two capsules, two boxes and a static box, all
    free to collide: every one of the nine canonical pair kinds appears."""
    b = e.SceneBuilder(speculative_distance=speculative_distance)
    b.add_ground()
    for i, shape in enumerate((e.Sphere(0.2), e.Sphere(0.15), e.Capsule(0.1, 0.3), e.Capsule(0.12, 0.2),
                               e.Box((0.2, 0.15, 0.1)), e.Box((0.3, 0.2, 0.25)))):
        b.add_body(f"body{i}", shape, mass=1.0, position=(0.3 * i, 0, 1.0))
    b.add_body("block", e.Box((0.4, 0.4, 0.2)), static=True, position=(0.5, 0.5, 0.2))
    return b.build()


def random_step_state(model, W, seed):
    """W worlds with the bodies crowded into 1.2 m around the block, turned
    and moving at random (many pairs overlap, some deeply)."""
    rng = np.random.default_rng(seed)
    s = model.initial_state(W)
    dyn = np.flatnonzero(model.dynamic)
    s.position[:, dyn] = rng.uniform((-0.1, -0.1, 0.0), (1.1, 1.1, 0.8), size=(W, dyn.size, 3))
    s.orientation[:, dyn] = quat_normalize(rng.normal(size=(W, dyn.size, 4)))
    s.velocity[:, dyn] = rng.normal(0.0, 2.0, size=(W, dyn.size, 3))
    s.angular_velocity[:, dyn] = rng.normal(0.0, 5.0, size=(W, dyn.size, 3))
    return s


def run_detect(model, state, fn=None):
    """The step detection's outputs for ``state``: (normal, point, separation,
    valid) as (W, P, ...) arrays, keep and contact separation (W, P)."""
    cs = model.contacts
    W, P = state.num_worlds, cs.num_pairs
    normal, point = np.empty((W * P, 3)), np.empty((W * P, 4, 3))
    sep, valid = np.empty((W * P, 4)), np.empty((W * P, 4), dtype=bool)
    keep, least = np.empty((W, P), dtype=bool), np.empty((W, P))
    (fn or detect)(cs._shape_type, cs._shape_params, cs.bounding_radius, cs.pair_a, cs.pair_b, cs.pair_kind,
                   state.position, state.orientation, state.velocity, state.angular_velocity, model.settings.dt,
                   model.settings.speculative_distance, np.empty((W, model.num_bodies, 7)), np.empty((W, P)),
                   normal, point, sep, valid, keep, least, np.empty((W, 2, 8, 3)))
    return (normal.reshape(W, P, 3), point.reshape(W, P, 4, 3), sep.reshape(W, P, 4), valid.reshape(W, P, 4),
            keep, least)


def test_step_detection_covers_every_pair_kind():
    model = all_kinds_scene()
    assert set(model.contacts.pair_kind.tolist()) == set(KIND_CODES.values())


def test_step_detection_batch_equals_each_world_alone_bit_for_bit():
    # W = 12 worlds take the parallel path (SERIAL_BELOW = 8), one world the
    # serial one; the serial loop over all 12 gives the same bits too.
    model = all_kinds_scene()
    W = 12
    assert W >= SERIAL_BELOW
    state = random_step_state(model, W, seed=5)
    batched = run_detect(model, state)
    assert batched[4].any(axis=0).all()  # every pair touches in some world
    serial = run_detect(model, state, detect_serial)
    for x, y in zip(batched, serial):
        np.testing.assert_array_equal(x, y)
    for w in range(W):
        alone = run_detect(model, state.select([w]))
        for name, x, y in zip(("normal", "point", "separation", "valid", "keep", "least"), batched, alone):
            np.testing.assert_array_equal(x[w:w + 1], y, err_msg=f"world {w}: {name}")


def test_step_detection_is_aabb_overlap_then_the_pair_functions():
    # The step's kernel = the public pieces composed: AABBs grown by the reach
    # |v| dt + |ω| dt r_bound, overlap with half the speculative distance,
    # then each overlapping pair's function with margin speculative + both
    # reaches (exact: the same kernels underneath).
    model = all_kinds_scene()
    cs, st = model.contacts, model.settings
    state = random_step_state(model, 4, seed=6)
    normal, point, sep, valid, keep, least = run_detect(model, state)
    lo, hi = aabb(model.shape_type, model.shape_params, state.position, state.orientation)
    reach = norm(state.velocity) * st.dt + norm(state.angular_velocity) * st.dt * cs.bounding_radius
    over = overlapping(lo - reach[..., None], hi + reach[..., None], cs.pair_a, cs.pair_b,
                       0.5 * st.speculative_distance)
    w, p = np.nonzero(over)
    a, b = cs.pair_a[p], cs.pair_b[p]
    m = collide_rows(cs.pair_kind[p], state.position[w, a], state.orientation[w, a], model.shape_params[a],
                     state.position[w, b], state.orientation[w, b], model.shape_params[b],
                     st.speculative_distance + (reach[w, a] + reach[w, b]))
    np.testing.assert_array_equal(normal[w, p], m.normal)
    np.testing.assert_array_equal(point[w, p], m.point)
    np.testing.assert_array_equal(sep[w, p], m.separation)
    np.testing.assert_array_equal(valid[w, p], m.valid)
    np.testing.assert_array_equal(keep, over & valid.any(axis=-1))
    np.testing.assert_array_equal(least, np.where(valid, sep, np.inf).min(axis=-1))
    # Pairs whose boxes do not overlap: no point, normal 0.
    assert not valid[~over].any() and np.all(sep[~over] == INVALID_SEPARATION) and np.all(normal[~over] == 0)
    assert over.sum() > 20 and (~over).sum() > 20


def test_begin_step_rows_of_resting_shapes():
    # Sphere r 0.1 m 1 cm deep, box (0.2, 0.15, 0.1) flat 2 mm deep, capsule
    # (r 0.05 m, half length 0.3 m) lying along x 5 mm deep, all at rest, in
    # world 0; world 1 has them 1 m up. The detection gives the sphere's one
    # point, the box's 4 bottom corners and the capsule's 2 ends, each midway
    # between the surfaces (tolerance 1e-9 m); begin_step keeps the rows with
    # a valid point, sorted by pair then world.
    b = e.SceneBuilder()
    b.add_ground()
    b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0.0, 0.0, 0.09))
    b.add_body("box", e.Box((0.2, 0.15, 0.1)), mass=1.0, position=(1.0, 0.0, 0.098))
    b.add_body("rod", e.Capsule(0.05, 0.3), mass=1.0, position=(0.0, 2.0, 0.045),
               orientation=rot((0, 1, 0), math.pi / 2))
    model = b.build()
    state = model.initial_state(2)
    state.position[1, 1:, 2] += 1.0
    cs = model.contacts
    normal, point, sep, valid, keep, least = run_detect(model, state)
    ground = {int(bb): p for p, (aa, bb) in enumerate(zip(cs.pair_a, cs.pair_b)) if aa == 0}
    ball, box, rod = ground[1], ground[2], ground[3]
    np.testing.assert_array_equal(np.flatnonzero(keep[0]), sorted((ball, box, rod)))
    assert not keep[1].any() and np.isinf(least[1]).all()
    np.testing.assert_allclose(normal[0, [ball, box, rod]], np.tile([0.0, 0.0, 1.0], (3, 1)), atol=TOL)
    np.testing.assert_array_equal(valid[0, ball], [True, False, False, False])
    np.testing.assert_allclose(sep[0, ball, 0], -0.01, atol=TOL)
    np.testing.assert_allclose(point[0, ball, 0], (0.0, 0.0, -0.005), atol=TOL)
    assert valid[0, box].all()
    np.testing.assert_allclose(sep[0, box], -0.002, atol=TOL)
    corners = [(1.0 + sx * 0.2, sy * 0.15, -0.001) for sx in (-1, 1) for sy in (-1, 1)]  # slots in corner order
    np.testing.assert_allclose(point[0, box], corners, atol=TOL)
    np.testing.assert_array_equal(valid[0, rod], [True, True, False, False])
    np.testing.assert_allclose(sep[0, rod, :2], -0.005, atol=TOL)
    # slot 0 at the capsule's local -z end, which the turn about y puts at -x
    np.testing.assert_allclose(point[0, rod, :2], [(-0.3, 2.0, -0.0025), (0.3, 2.0, -0.0025)], atol=TOL)
    np.testing.assert_allclose(least[0, [ball, box, rod]], [-0.01, -0.002, -0.005], atol=TOL)
    assert np.isinf(np.delete(least[0], [ball, box, rod])).all()  # the pairs of two bodies

    cs.begin_step(model, state, model.settings.dt / model.settings.substeps)
    p_idx, w_idx = np.nonzero(keep.T)
    np.testing.assert_array_equal(cs.rows.p, p_idx)
    np.testing.assert_array_equal(cs.rows.w, w_idx)
    np.testing.assert_array_equal(cs.rows.valid, valid[w_idx, p_idx])
    np.testing.assert_array_equal(state.contact_separation, least)


def test_speculative_reach_grows_with_speed():
    # A sphere 5 cm above the ground: no row at rest (speculative distance
    # 2 cm); falling at 4 m/s it can cover 6.7 cm in the 1/60 s step, so its
    # margin 2 cm + 6.7 cm takes the 5 cm gap in as a speculative point.
    b = e.SceneBuilder()
    b.add_ground()
    b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0.0, 0.0, 0.15))
    model = b.build()
    state = model.initial_state(2)
    state.velocity[1, 1] = (0.0, 0.0, -4.0)
    normal, point, sep, valid, keep, least = run_detect(model, state)
    np.testing.assert_array_equal(keep[:, 0], [False, True])
    np.testing.assert_allclose(sep[1, 0, 0], 0.05, atol=TOL)
    np.testing.assert_allclose(point[1, 0, 0], (0.0, 0.0, 0.025), atol=TOL)
    model.contacts.begin_step(model, state, model.settings.dt / model.settings.substeps)
    np.testing.assert_array_equal(model.contacts.rows.w, [1])
    assert np.isinf(state.contact_separation[0, 0])
    np.testing.assert_allclose(state.contact_separation[1, 0], 0.05, atol=TOL)
