"""Tests of the humanoid ragdoll builder (engine.humanoid)."""

import math
import warnings

import numpy as np
import pytest

from engine import Box, Capsule, SceneBuilder, SceneError, Sphere, math3d
from engine.humanoid import (
    Actuator,
    DAMPING_PER_TORQUE,
    _q_swing,
    _q_twist,
    JOINT_TABLE,
    add_humanoid,
    check_conditioning,
    check_connected,
    joint_angles,
    pose,
    random_pose,
    standing_pose,
    swing_twist,
    t_pose,
    within_limits,
)

BONES = ["pelvis", "abdomen", "chest", "head", "upper_arm_l", "lower_arm_l", "upper_arm_r", "lower_arm_r",
         "thigh_l", "shin_l", "foot_l", "thigh_r", "shin_r", "foot_r"]
HANDS = ["hand_l", "hand_r"]


def make(**kw):
    b = SceneBuilder()
    h = add_humanoid(b, **kw)
    return b, h


# ---------------------------------------------------------------- geometry helpers
def z_extent(shape, position, orientation):
    """(lowest z, highest z) of a posed shape."""
    R = math3d.quat_to_matrix(np.asarray(orientation))
    if isinstance(shape, Sphere):
        r = shape.radius
    elif isinstance(shape, Capsule):
        r = abs(R[2, 2]) * shape.half_length + shape.radius
    else:
        r = float(np.abs(R[2]) @ np.asarray(shape.half_extents))
    return position[2] - r, position[2] + r


def sdf(shape, p):
    """Signed distance of body-local points p (..., 3) to a shape."""
    if isinstance(shape, Sphere):
        return np.linalg.norm(p, axis=-1) - shape.radius
    if isinstance(shape, Capsule):
        q = p.copy()
        q[..., 2] -= np.clip(q[..., 2], -shape.half_length, shape.half_length)
        return np.linalg.norm(q, axis=-1) - shape.radius
    d = np.abs(p) - np.asarray(shape.half_extents)
    return np.linalg.norm(np.maximum(d, 0.0), axis=-1) + np.minimum(d.max(axis=-1), 0.0)


def interior_points(shape, n=14):
    """Body-local points filling a shape."""
    if isinstance(shape, Sphere):
        ext = np.full(3, shape.radius)
    elif isinstance(shape, Capsule):
        ext = np.array([shape.radius, shape.radius, shape.half_length + shape.radius])
    else:
        ext = np.asarray(shape.half_extents)
    g = np.linspace(-1.0, 1.0, n)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * ext
    return pts[sdf(shape, pts) <= 0.0]


def world_anchor(b, spec, which):
    body = b.bodies[spec.parent if which == "parent" else spec.child]
    local = spec.anchor_parent if which == "parent" else spec.anchor_child
    return body.position + math3d.quat_rotate(body.orientation, local)


def anchors_from_pose(b, h, positions, orientations):
    out = {}
    for name, j in h.joints.items():
        spec = b.joints[j]
        pa = positions[spec.parent] + math3d.quat_rotate(orientations[spec.parent], spec.anchor_parent)
        pc = positions[spec.child] + math3d.quat_rotate(orientations[spec.child], spec.anchor_child)
        out[name] = (pa, pc)
    return out


# ------------------------------------------------------------------------ tests
@pytest.mark.parametrize("hands", [False, True])
@pytest.mark.parametrize("mass", [75.0, 52.3, 120.0])
def test_total_mass(hands, mass):
    b, h = make(mass=mass, hands=hands)
    total = sum(b.bodies[i].mass for i in h.bodies.values())
    assert abs(total - mass) <= 1e-9 * mass


def test_bones_and_names():
    b, h = make()
    assert list(h.bodies) == BONES  # 14 bones
    assert [b.bodies[i].name for i in h.bodies.values()] == BONES
    b, h = make(hands=True, prefix="bob_")
    assert sorted(h.bodies) == sorted(BONES + HANDS)  # 16 bones
    assert all(b.bodies[i].name == "bob_" + n for n, i in h.bodies.items())
    assert all(b.joints[j].name == "bob_" + n for n, j in h.joints.items())
    assert h.root == "pelvis" and h.head == "head" and h.feet == ("foot_l", "foot_r")
    assert len(h.joints) == len(h.bodies) - 1
    assert all(b.bodies[i].material == "bone" for i in h.bodies.values())


def test_segment_masses_follow_de_leva():
    b, h = make(mass=73.0, hands=True)
    m = {n: b.bodies[i].mass for n, i in h.bodies.items()}
    assert m["head"] == pytest.approx(0.0694 * 73)
    assert m["thigh_l"] == pytest.approx(0.1416 * 73)
    assert m["chest"] + m["abdomen"] + m["pelvis"] == pytest.approx(0.4346 * 73)
    b, h = make(mass=73.0, hands=False)  # the hand goes into the forearm
    assert b.bodies[h.bodies["lower_arm_l"]].mass == pytest.approx((0.0162 + 0.0061) * 73)


@pytest.mark.parametrize("height,origin,yaw", [(1.75, (0, 0, 0), 0.0), (1.5, (1.0, -2.0, 0.3), 1.1),
                                               (2.0, (0, 0, -1.0), -2.5)])
@pytest.mark.parametrize("hands", [False, True])
def test_height_and_soles(height, origin, yaw, hands):
    b, h = make(height=height, position=origin, yaw=yaw, hands=hands)
    ground = origin[2]
    top = max(z_extent(b.bodies[i].shape, b.bodies[i].position, b.bodies[i].orientation)[1]
              for i in h.bodies.values())
    assert abs((top - ground) - height) <= 0.02 * height
    for foot in h.feet:
        f = b.bodies[h.bodies[foot]]
        lo, _ = z_extent(f.shape, f.position, f.orientation)
        assert abs(lo - ground) <= 1e-9
    for name, i in h.bodies.items():  # nothing else reaches the ground
        if name not in h.feet:
            lo, _ = z_extent(b.bodies[i].shape, b.bodies[i].position, b.bodies[i].orientation)
            assert lo > ground + 0.02, name
    # the feet stand around `position` and point along the yaw direction
    feet = [b.bodies[h.bodies[f]].position for f in h.feet]
    mid = 0.5 * (feet[0] + feet[1])
    forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    offset = mid - np.asarray(origin, dtype=float)
    assert abs(offset @ left) < 1e-9 and 0 < offset @ forward < 0.1 * height
    assert (feet[0] - feet[1]) @ left > 0  # the left foot is on the left


def test_left_right_mirror():
    b, h = make(hands=True)
    for name, i in h.bodies.items():
        if name.endswith("_l"):
            pl, pr = b.bodies[i].position, b.bodies[h.bodies[name[:-1] + "r"]].position
            np.testing.assert_allclose(pl * [1, -1, 1], pr, atol=1e-12)
            assert b.bodies[i].mass == b.bodies[h.bodies[name[:-1] + "r"]].mass


@pytest.mark.parametrize("hands", [False, True])
def test_no_overlap_between_unjointed_bones(hands):
    b, h = make(hands=hands, yaw=0.4)
    jointed = {frozenset((b.joints[j].parent, b.joints[j].child)) for j in h.joints.values()}
    idx = list(h.bodies.values())
    for a in idx:
        A = b.bodies[a]
        pts = math3d.quat_rotate(A.orientation, interior_points(A.shape)) + A.position
        for c in idx:
            if c == a or frozenset((a, c)) in jointed:
                continue
            C = b.bodies[c]
            local = math3d.quat_rotate_inv(C.orientation, pts - C.position)
            assert sdf(C.shape, local).min() > 0.005, (A.name, C.name)


@pytest.mark.parametrize("hands", [False, True])
def test_anchors_at_joint_centres_on_both_bones(hands):
    b, h = make(hands=hands, yaw=-0.7, position=(0.5, 0.2, 0.1))
    for name, j in h.joints.items():
        spec = b.joints[j]
        pa, pc = world_anchor(b, spec, "parent"), world_anchor(b, spec, "child")
        np.testing.assert_allclose(pa, pc, atol=1e-12)
        child, parent = b.bodies[spec.child], b.bodies[spec.parent]
        # the anchor lies on the child's own geometry (its end), and at most 2 cm off the parent's
        assert sdf(child.shape, spec.anchor_child) <= 1e-9, name
        assert sdf(parent.shape, spec.anchor_parent) <= 0.02, name
        # build pose is the joint's zero: q_p ⊗ f_p == q_c ⊗ f_c
        a = math3d.quat_mul(parent.orientation, spec.frame_parent)
        c = math3d.quat_mul(child.orientation, spec.frame_child)
        assert min(np.abs(a - c).max(), np.abs(a + c).max()) < 1e-12


def test_standing_pose_within_limits_and_is_build_pose():
    b, h = make(hands=True)
    stand = standing_pose(h)
    assert set(stand) == set(h.joints)
    assert all(within_limits(h, stand).values())
    positions, orientations = pose(h, b, stand)
    np.testing.assert_allclose(positions, [x.position for x in b.bodies], atol=1e-12)
    angles = joint_angles(h, b, positions, orientations)
    for name, v in angles.items():
        assert np.allclose(v, 0.0, atol=1e-12), name
    # the limits themselves are those of the builder's JointSpecs
    for name, j in h.joints.items():
        for key, lim in b.joints[j].limits.items():
            np.testing.assert_allclose(h.limits[name][key], lim)


def test_knee_and_elbow_ranges():
    b, h = make()
    for joint in ("knee_l", "knee_r", "elbow_l", "elbow_r"):
        assert h.joint_kinds[joint] == "hinge"
        lo, hi = h.limits[joint]["angle"]
        assert lo == 0.0 and math.radians(130) <= hi <= math.radians(150)


@pytest.mark.parametrize("yaw", [0.0, 0.5 * math.pi, 2.0])
def test_knee_flexes_backwards_and_elbow_forwards(yaw):
    b, h = make(yaw=yaw, hands=True)
    forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    p0, q0 = pose(h, b, {})
    a0 = anchors_from_pose(b, h, p0, q0)
    p1, q1 = pose(h, b, {"knee_l": math.radians(90), "elbow_r": math.radians(90)})
    a1 = anchors_from_pose(b, h, p1, q1)
    ankle = a1["ankle_l"][1] - a0["ankle_l"][1]
    assert ankle @ forward < -0.3 and ankle[2] > 0.3  # backwards and up, by about a shin length
    # the knee itself did not move; the shin is now horizontal
    np.testing.assert_allclose(a1["knee_l"][1], a0["knee_l"][1], atol=1e-12)
    assert abs(math3d.quat_rotate(q1[h.bodies["shin_l"]], np.array([0, 0, 1.0]))[2]) < 1e-9
    wrist = a1["wrist_r"][1] - a0["wrist_r"][1]
    assert wrist @ forward > 0.2 and wrist[2] > 0.2  # forwards and up
    # the other side did not move
    np.testing.assert_allclose(p1[h.bodies["foot_r"]], p0[h.bodies["foot_r"]], atol=1e-12)
    np.testing.assert_allclose(p1[h.bodies["hand_l"]], p0[h.bodies["hand_l"]], atol=1e-12)


def test_swing_signs_are_anatomical():
    b, h = make(yaw=0.3)
    forward = np.array([math.cos(0.3), math.sin(0.3), 0.0])
    p0, q0 = pose(h, b, {})
    p1, q1 = pose(h, b, {"hip_l": (0, 0.5, 0), "shoulder_r": (0, 0.5, 0), "spine_lower": (0, 0.3, 0)})
    d = lambda name: p1[h.bodies[name]] - p0[h.bodies[name]]
    assert d("shin_l") @ forward > 0.1  # hip flexion lifts the knee forwards
    assert d("lower_arm_r") @ forward > 0.1  # shoulder flexion raises the arm forwards
    assert d("head") @ forward > 0.1  # trunk flexion bends forwards
    p2, _ = pose(h, b, {"ankle_l": (0, 0.3, 0)})  # dorsiflexion: toes up
    foot = h.bodies["foot_l"]
    assert p2[foot][2] > p0[foot][2]


def test_t_pose_arms_horizontal():
    b, h = make(hands=True, yaw=0.8, height=1.6)
    angles = t_pose(h)
    assert all(within_limits(h, angles).values())
    positions, orientations = pose(h, b, angles)
    anchors = anchors_from_pose(b, h, positions, orientations)
    left = np.array([-math.sin(0.8), math.cos(0.8), 0.0])
    for side, sgn in (("l", 1), ("r", -1)):
        for bone in (f"upper_arm_{side}", f"lower_arm_{side}", f"hand_{side}"):
            axis = math3d.quat_rotate(orientations[h.bodies[bone]], np.array([0, 0, 1.0]))
            assert abs(axis[2]) < 1e-9 and abs(abs(axis @ left) - 1) < 1e-9, bone
        shoulder, wrist = anchors[f"shoulder_{side}"][1], anchors[f"wrist_{side}"][1]
        assert abs(wrist[2] - shoulder[2]) < 1e-9
        assert sgn * (wrist - shoulder) @ left > 0.4  # straight out sideways
    # the rest did not move
    for name in ("pelvis", "head", "foot_l"):
        np.testing.assert_allclose(positions[h.bodies[name]], b.bodies[h.bodies[name]].position, atol=1e-12)


@pytest.mark.parametrize("hands", [False, True])
def test_random_pose_round_trip(hands):
    rng = np.random.default_rng(7)
    b, h = make(hands=hands, yaw=1.3, position=(1, 2, 0))
    for _ in range(25):
        angles = random_pose(rng, h)
        assert set(angles) == set(h.joints)
        assert all(within_limits(h, angles).values())
        root_q = math3d.quat_normalize(rng.normal(size=4))
        root_p = rng.normal(size=3)
        positions, orientations = pose(h, b, angles, root_position=root_p, root_orientation=root_q)
        np.testing.assert_allclose(positions[h.root_index], root_p, atol=1e-15)
        back = joint_angles(h, b, positions, orientations)
        for name, v in angles.items():
            np.testing.assert_allclose(back[name], v, atol=1e-9, err_msg=name)
        # every joint stays assembled
        for name, (pa, pc) in anchors_from_pose(b, h, positions, orientations).items():
            np.testing.assert_allclose(pa, pc, atol=1e-9, err_msg=name)
        assert np.allclose(np.linalg.norm(orientations, axis=1), 1.0)


def test_random_pose_covers_the_cone_and_scale():
    rng = np.random.default_rng(1)
    b, h = make()
    samples = [random_pose(rng, h)["hip_l"] for _ in range(2000)]
    cy, cz = h.limits["hip_l"]["swing"]
    sy = np.array([s[1] for s in samples]) / cy
    sz = np.array([s[2] for s in samples]) / cz
    r2 = sy**2 + sz**2
    assert r2.max() <= 1.0 and r2.max() > 0.98
    assert abs(np.mean(r2 <= 0.25) - 0.25) < 0.04  # uniform over the ellipse's area
    knees = [random_pose(rng, h, scale=0.1)["knee_l"] for _ in range(200)]
    assert 0.0 <= min(knees) and max(knees) <= 0.1 * h.limits["knee_l"]["angle"][1]
    assert all(np.allclose(v, 0) for v in random_pose(rng, h, scale=0.0).values())
    with pytest.raises(ValueError):
        random_pose(rng, h, scale=2.0)


def test_swing_twist_decomposition():
    rng = np.random.default_rng(3)
    for _ in range(200):
        tw = rng.uniform(-3.0, 3.0)
        s = rng.uniform(0, 3.0) * np.array([0, *(lambda v: v / np.linalg.norm(v))(rng.normal(size=2))])
        q = math3d.quat_mul(_q_swing(s[1], s[2]), _q_twist(tw))
        for sign in (1, -1):
            np.testing.assert_allclose(swing_twist(sign * q), (tw, s[1], s[2]), atol=1e-9)


def test_pose_rejects_bad_angles():
    b, h = make()
    with pytest.raises(KeyError, match="wrist_l"):
        pose(h, b, {"wrist_l": (0, 0, 0)})  # no hands
    with pytest.raises(ValueError, match="knee_l"):
        pose(h, b, {"knee_l": (0.1, 0.2, 0.3)})
    with pytest.raises(ValueError, match="hip_l"):
        pose(h, b, {"hip_l": 0.3})
    with pytest.raises(ValueError, match="finite"):
        pose(h, b, {"hip_l": (0, np.nan, 0)})


def test_prefixed_humanoids_share_a_scene():
    b = SceneBuilder()
    b.add_ground()
    h1 = add_humanoid(b, prefix="a/", position=(0, 0, 0))
    h2 = add_humanoid(b, prefix="b/", position=(3, 0, 0), yaw=math.pi, hands=True)
    assert not set(h1.bodies.values()) & set(h2.bodies.values())
    positions, orientations = pose(h2, b, {"b/knee_l": 1.0})
    np.testing.assert_allclose(positions[list(h1.bodies.values())],
                               [b.bodies[i].position for i in h1.bodies.values()])
    assert joint_angles(h2, b, positions, orientations)["knee_l"] == pytest.approx(1.0, abs=1e-12)
    assert h2.actuators[0].joint == h2.joints["spine_lower"] and h2.actuators[0].name == "b/spine_lower:twist"


def test_actuators():
    b, h = make(hands=True, mass=90.0, torque_scale=0.5)
    assert all(isinstance(a, Actuator) for a in h.actuators)
    keys = [(a.joint, a.axis) for a in h.actuators]
    assert keys == sorted(keys)  # joint creation order, then axis
    expected = []
    for name, j in h.joints.items():
        base = JOINT_TABLE[name.rsplit("_", 1)[0] if name[-2:] in ("_l", "_r") else name]["torque"]
        for axis, t in enumerate(base):
            expected.append((j, axis, t * 90.0 / 75.0 * 0.5))
    assert [(a.joint, a.axis) for a in h.actuators] == [(j, ax) for j, ax, _ in expected]
    for a, (_, _, t) in zip(h.actuators, expected):
        assert a.max_torque == pytest.approx(t)
        assert b.joints[a.joint].max_torque[a.axis] == pytest.approx(t)
    assert len(h.actuators) == 37  # with hands: 11 ball joints x 3 axes + 2 elbows + 2 knees
    names = [a.name for a in h.actuators]
    assert "knee_l" in names and "hip_r:swing_y" in names and "hip_r:twist" in names
    # strengths in the human range at 75 kg
    b, h = make()
    t = {a.name: a.max_torque for a in h.actuators}
    assert 150 <= t["knee_l"] <= 250 and 150 <= t["hip_l:swing_y"] <= 250
    assert 100 <= t["ankle_l:swing_y"] <= 150 and 100 <= t["spine_lower:swing_y"] <= 150
    assert 60 <= t["shoulder_l:swing_y"] <= 90 and 50 <= t["elbow_l"] <= 70
    assert 20 <= t["neck:swing_y"] <= 30
    b, h = make(torque_scale=0.0)  # a passive doll
    assert h.actuators == []


def test_damping_scale():
    b, h = make(damping=0.0)
    assert all(b.joints[j].damping == 0.0 for j in h.joints.values())
    b, h = make(damping=2.0)
    assert b.joints[h.joints["knee_l"]].damping == pytest.approx(2 * DAMPING_PER_TORQUE * 200)


def test_default_humanoid_is_well_conditioned():
    for hands in (False, True):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            b, h = make(hands=hands)
        assert h.warnings == []
        assert check_conditioning(b) == []


def test_conditioning_flags_a_bad_skeleton():
    b = SceneBuilder()
    b.add_body("forearm", Capsule(0.04, 0.1), mass=1.0, position=(0, 0, 1.0))
    b.add_body("hand", Box((0.05, 0.02, 0.08)), mass=100.0, position=(0, 0, 0.74))
    b.add_ball("wrist", "forearm", "hand", anchor=(0, 0, 0.82))
    msgs = check_conditioning(b)
    assert any("'wrist'" in m and "mass ratio 100" in m for m in msgs)
    assert check_conditioning(b, max_mass_ratio=200, max_inertia_ratio=1e6) == []
    # the inertia check alone: equal masses, very different sizes
    b = SceneBuilder()
    b.add_body("rod", Capsule(0.02, 1.0), mass=1.0, position=(0, 0, 2.0))
    b.add_body("pebble", Sphere(0.01), mass=1.0, position=(0, 0, 0.9))
    b.add_hinge("pin", "rod", "pebble", anchor=(0, 0, 0.95))
    msgs = check_conditioning(b)
    assert len(msgs) == 1 and "'pin'" in msgs[0] and "inertia ratio" in msgs[0]
    # the humanoid warns when a user overloads a bone of it
    b, h = make(hands=True)
    b.bodies[h.bodies["hand_l"]].mass = 100.0
    assert any("'wrist_l'" in m for m in check_conditioning(b))


@pytest.mark.parametrize("kw,word", [({"height": 0}, "height"), ({"height": -1.7}, "height"),
                                     ({"height": float("nan")}, "height"), ({"mass": 0.0}, "mass"),
                                     ({"mass": -3}, "mass"), ({"mass": "heavy"}, "mass"),
                                     ({"torque_scale": -1}, "torque_scale"), ({"damping": -0.1}, "damping"),
                                     ({"position": (0, 0)}, "position")])
def test_bad_arguments(kw, word):
    b = SceneBuilder()
    with pytest.raises(ValueError, match=word):
        add_humanoid(b, **kw)


def test_unknown_material_is_a_scene_error():
    with pytest.raises(SceneError, match="unobtainium"):
        make(material="unobtainium")


def test_check_connected():
    b, h = make()
    check_connected(b, "pelvis", [b.bodies[i].name for i in h.bodies.values()])
    b.add_body("loose_bone", Capsule(0.03, 0.1), mass=1.0, position=(2, 0, 1))
    with pytest.raises(SceneError, match="loose_bone.*no joint path.*pelvis"):
        check_connected(b, "pelvis", list(h.bodies.values()) + ["loose_bone"])
    # a connected user skeleton passes, joints followed either way
    b.add_hinge("glue", "loose_bone", "foot_l", anchor=(1, 0, 0.5))
    check_connected(b, h.root_index, ["loose_bone"])


def test_build_compiles():
    b = SceneBuilder()
    b.add_ground()
    h = add_humanoid(b, hands=True)
    model = b.build()
    assert model.num_bodies == len(h.bodies) + 1
    if model.joints is not None:  # once the joint solver compiles joints
        assert [(a.name, a.joint, a.axis) for a in model.actuators] == \
            [(a.name, a.joint, a.axis) for a in h.actuators]
        np.testing.assert_allclose([a.max_torque for a in model.actuators], [a.max_torque for a in h.actuators])
        if hasattr(model.joints, "angles"):  # the solver reads the same angles as joint_angles()
            angles = random_pose(np.random.default_rng(5), h)
            state = model.initial_state(1)
            state.position[0], state.orientation[0] = pose(h, model, angles)
            engine_angles = model.joints.angles(state)[0]
            for name, j in h.joints.items():
                expected = np.atleast_1d(angles[name])
                np.testing.assert_allclose(engine_angles[j][:expected.size], expected, atol=1e-9, err_msg=name)
    # pose() also takes the compiled model
    positions, orientations = pose(h, model, {"knee_r": 0.5})
    assert joint_angles(h, model, positions, orientations)["knee_r"] == pytest.approx(0.5)
    state = model.initial_state(2)
    np.testing.assert_allclose(state.position[0], pose(h, model, standing_pose(h))[0], atol=1e-12)
