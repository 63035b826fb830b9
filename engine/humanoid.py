"""The humanoid ragdoll: anthropometric bones, human joint ranges and strengths.

``add_humanoid(builder, ...)`` adds a ragdoll of 14 bones (16 with hands) to a
:class:`~engine.builder.SceneBuilder`, standing upright with its soles on the
plane ``z = position[2]``, facing +x turned by ``yaw`` about +z, and returns a
:class:`Humanoid` naming its bodies, joints and actuated joint axes. Units are
SI: metres, kilograms, seconds, radians, newton-metres.

Bones and joints (parent -> child, in creation order)::

    pelvis (root)
    ├─ spine_lower (ball)  -> abdomen ─ spine_upper (ball) -> chest
    │                                   ├─ neck (ball)        -> head
    │                                   ├─ shoulder_l (ball)  -> upper_arm_l ─ elbow_l (hinge) -> lower_arm_l [─ wrist_l (ball) -> hand_l]
    │                                   └─ shoulder_r ...
    ├─ hip_l (ball) -> thigh_l ─ knee_l (hinge) -> shin_l ─ ankle_l (ball) -> foot_l
    └─ hip_r ...

Every joint's anchor is the anatomical joint centre, where the two segments
meet, and the build pose is every joint's zero. Each joint frame has its x
axis along the twist (ball) or hinge axis, and the signs are anatomical:

* hinge angle > 0 is flexion: the forearm swings forwards/up, the shin
  backwards/up;
* ball ``twist`` turns the child about its bone axis (spine, neck: about the
  vertical, positive = towards the body's left);
* ball ``swing_y`` > 0 is sagittal flexion: trunk/neck bend forwards, thigh
  and upper arm swing forwards, toes up (dorsiflexion), hand forwards;
* ball ``swing_z`` is the frontal-plane swing (lateral bend, ab/adduction,
  ankle inversion/eversion, wrist flexion/extension); both swings are bounded
  by the elliptic cone (swing_y/cone_y)² + (swing_z/cone_z)² <= 1.

Pose helpers work on angle dictionaries ``{joint: hinge angle or (twist,
swing_y, swing_z)}``: :func:`pose` (forward kinematics from the pelvis),
:func:`joint_angles` (its inverse), :func:`standing_pose`, :func:`t_pose`,
:func:`random_pose`. :func:`check_conditioning` (after Jolt's
``RagdollSettings::Stabilize``) and :func:`check_connected` check skeletons,
the humanoid's or a user's.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from . import math3d
from .errors import SceneError
from .joints import Actuator
from .shapes import Box, Capsule

# --------------------------------------------------------------------------
# Anthropometry.
#
# de Leva P. (1996) "Adjustments to Zatsiorsky-Seluyanov's segment inertia
# parameters", J. Biomech. 29(9):1223-1230, table 4, male values. Reference
# subject: stature 1.741 m, body mass 73.0 kg. Mass fractions sum to 100 %.
#
#   segment      endpoints          length (m)  mass (%)  CM (% from 1st endpoint)
#   head         vertex - mid-gonion   0.2033      6.94     59.76
#   upper trunk  suprasternale - xiphoid 0.1707   15.96     29.99
#   mid trunk    xiphoid - omphalion   0.2155     16.33     45.02
#   lower trunk  omphalion - mid-hips  0.1457     11.17     61.15
#   upper arm    shoulder - elbow JC   0.2817      2.71     57.72
#   forearm      elbow - wrist JC      0.2689      1.62     45.74
#   hand         wrist JC - 3rd metacarpale 0.0862 0.61     79.00
#   thigh        hip - knee JC         0.4222     14.16     40.95
#   shank        knee JC - lat. malleolus 0.4340   4.33     44.59
#   foot         heel - toe tip        0.2581      1.37     44.15
#
# Each bone here is a uniform solid, so its centre of mass is its geometric
# centre (within a few cm of de Leva's CM positions); masses are exact.
# The height of the ankle above the sole, 0.039 x stature, is from Winter D.A.
# (2009) "Biomechanics and Motor Control of Human Movement", 4th ed., fig. 4.1.
# Breadths (not in de Leva's table) are rounded adult-male values chosen so
# that no two bones that do not share a joint overlap in the standing pose.
# --------------------------------------------------------------------------

REFERENCE_STATURE = 1.741  # m, de Leva's male reference subject
REFERENCE_MASS = 73.0  # kg, de Leva's male reference subject
STRENGTH_REFERENCE_MASS = 75.0  # kg, body mass the torque table below is for

#: de Leva (1996) male segment lengths (m, at 1.741 m stature) and mass fractions.
DE_LEVA_MALE = {
    "head": {"length": 0.2033, "mass": 0.0694, "cm": 0.5976},
    "upper_trunk": {"length": 0.1707, "mass": 0.1596, "cm": 0.2999},
    "mid_trunk": {"length": 0.2155, "mass": 0.1633, "cm": 0.4502},
    "lower_trunk": {"length": 0.1457, "mass": 0.1117, "cm": 0.6115},
    "upper_arm": {"length": 0.2817, "mass": 0.0271, "cm": 0.5772},
    "forearm": {"length": 0.2689, "mass": 0.0162, "cm": 0.4574},
    "hand": {"length": 0.0862, "mass": 0.0061, "cm": 0.7900},
    "thigh": {"length": 0.4222, "mass": 0.1416, "cm": 0.4095},
    "shank": {"length": 0.4340, "mass": 0.0433, "cm": 0.4459},
    "foot": {"length": 0.2581, "mass": 0.0137, "cm": 0.4415},
}

ANKLE_HEIGHT = 0.039  # x stature, Winter (2009) fig. 4.1
ANKLE_FROM_HEEL = 0.23  # x foot length: the ankle joint lies about a quarter of the foot ahead of the heel
ARM_ABDUCTION = math.radians(8.0)  # rad: arms hang this far out so they clear the trunk

# Breadths and radii in metres at the reference stature (scaled with height).
HIP_HALF_SPACING = 0.087  # hip joint centres at ±y (inter-HJC distance ~0.17 m)
SHOULDER_HALF_SPACING = 0.18  # glenohumeral centres at ±y
SHOULDER_DROP = 0.05  # glenohumeral centre below the suprasternale
PELVIS_HALF = (0.09, 0.15)  # (depth, width) half extents of the pelvis box
ABDOMEN_HALF = (0.085, 0.13)
CHEST_HALF = (0.10, 0.17)
HEAD_RADIUS = 0.085
UPPER_ARM_RADIUS = 0.045
FOREARM_RADIUS = 0.037
HAND_HALF = (0.042, 0.015)  # (palm breadth, thickness) half extents; palms face the thighs
THIGH_RADIUS = 0.07
SHIN_RADIUS = 0.05
FOOT_HALF_WIDTH = 0.05

# --------------------------------------------------------------------------
# Joints: ranges and strengths.
#
# Ranges: AAOS normal ranges of motion (Greene W.B., Heckman J.D. (1994) "The
# Clinical Measurement of Joint Motion", American Academy of Orthopaedic
# Surgeons), folded into cones centred on the standing pose; Bullet's
# RagdollDemo (shoulder cone pi/2, hip cone pi/4, neck cone pi/4 with twist
# pi/2, knee and elbow hinges over a quarter turn) and Jolt's ragdoll samples
# as engine references. A symmetric cone cannot hold an asymmetric human range
# (hip: flexion 120°, extension 30°), so cones take a middle value.
#
# Strengths: rounded peak isometric torques of young adult men, N·m at 75 kg
# body mass, per actuated axis (twist or hinge, swing_y, swing_z); e.g.
# Anderson, Madigan & Nussbaum (2007) J. Biomech. 40:3105 for hip, knee and
# ankle; Askew et al. (1987) Clin. Orthop. 222:261 for the elbow; Vasavada,
# Li & Delp (2001) Spine 26:1904 for the neck. They scale with body mass
# (``mass / 75``) and ``torque_scale``.
# --------------------------------------------------------------------------

_deg = math.radians

#: joint -> kind, limits (rad) and maximum torques (N·m at 75 kg).
JOINT_TABLE = {
    # lumbar and thoracic spine share AAOS thoracolumbar flexion 80°, extension 25°,
    # lateral bend 35°, rotation 45° (the lumbar part rotates little)
    "spine_lower": {"kind": "ball", "swing": (_deg(30), _deg(20)), "twist": (_deg(-15), _deg(15)),
                    "torque": (100.0, 150.0, 130.0)},
    "spine_upper": {"kind": "ball", "swing": (_deg(25), _deg(20)), "twist": (_deg(-30), _deg(30)),
                    "torque": (100.0, 130.0, 110.0)},
    # AAOS cervical: flexion 45°, extension 45°, lateral bend 45°, rotation 60°
    "neck": {"kind": "ball", "swing": (_deg(45), _deg(40)), "twist": (_deg(-60), _deg(60)),
             "torque": (20.0, 30.0, 25.0)},
    # AAOS shoulder flexion 180°, extension 60°, abduction 180°, rotation 70°/90°;
    # Bullet: cone pi/2
    "shoulder": {"kind": "ball", "swing": (_deg(90), _deg(90)), "twist": (_deg(-80), _deg(80)),
                 "torque": (60.0, 90.0, 80.0)},
    # AAOS elbow 0-150°
    "elbow": {"kind": "hinge", "angle": (0.0, _deg(145)), "torque": (70.0,)},
    # AAOS wrist: flexion 80°, extension 70° (swing_z here), radial 20° / ulnar 30°
    # deviation (swing_y); twist stands for forearm pronation/supination 80°/80°
    "wrist": {"kind": "ball", "swing": (_deg(25), _deg(70)), "twist": (_deg(-80), _deg(80)),
              "torque": (8.0, 10.0, 12.0)},
    # AAOS hip: flexion 120°, extension 30°, abduction 45°, adduction 30°, rotation 45°;
    # Bullet: cone pi/4
    "hip": {"kind": "ball", "swing": (_deg(60), _deg(40)), "twist": (_deg(-40), _deg(40)),
            "torque": (80.0, 220.0, 150.0)},
    # AAOS knee 0-135° (Norkin & White 0-140°); flexion only, the shin goes behind
    "knee": {"kind": "hinge", "angle": (0.0, _deg(140)), "torque": (200.0,)},
    # AAOS ankle: dorsiflexion 20°, plantarflexion 50° (swing_y), inversion 35°,
    # eversion 15° (swing_z); a little rotation about the shin
    "ankle": {"kind": "ball", "swing": (_deg(35), _deg(25)), "twist": (_deg(-15), _deg(15)),
              "torque": (20.0, 130.0, 60.0)},
}

#: Passive joint damping (N·m·s/rad) per N·m of the joint's largest maximum
#: torque before ``torque_scale``: 6.6 N·m·s/rad at the hip, 0.36 at the wrist.
#: Chosen so that the passive doll dropped from 1 m comes to rest (every bone
#: under 1 cm/s) within 3 s; at 0.01 s its forearms still swung after 4 s.
DAMPING_PER_TORQUE = 0.03  # s

#: Actuator name suffixes per axis (as engine.joints names them).
ACTUATOR_SUFFIX = {"hinge": ("",), "ball": (":twist", ":swing_y", ":swing_z")}

# Joint frames relative to the child bone (columns x, y, z of a rotation).
# x is the twist/hinge axis; the y axis is chosen so that positive swing_y (or
# hinge angle) is anatomical flexion.
_UP = np.column_stack(([0, 0, 1], [0, 1, 0], [-1, 0, 0]))  # spine, neck: x up, y left
_DOWN = np.column_stack(([0, 0, -1], [0, -1, 0], [-1, 0, 0]))  # limbs: x down the bone, y right
_KNEE = np.column_stack(([0, 1, 0], [0, 0, 1], [1, 0, 0]))  # hinge axis +y: shin swings back
_ELBOW = np.column_stack(([0, -1, 0], [0, 0, -1], [1, 0, 0]))  # hinge axis -y: forearm swings forward


@dataclass
class Humanoid:
    """What :func:`add_humanoid` built.

    bodies, joints: canonical part name (without prefix, e.g. "thigh_l") ->
    index into ``builder.bodies`` / ``builder.joints``, in creation order.
    joint_kinds, limits: per joint, "ball"/"hinge" and the limits dict of its
    JointSpec (radians). actuators: every joint axis with a maximum torque > 0,
    ordered by joint creation order, then axis 0, 1, 2.
    root, feet, head: canonical body names. arm_abduction: rad, how far the
    arms hang out from the vertical in the build pose.
    """

    prefix: str
    height: float
    mass: float
    bodies: dict
    joints: dict
    joint_kinds: dict
    limits: dict
    actuators: list
    hands: bool
    yaw: float
    position: np.ndarray
    arm_abduction: float = ARM_ABDUCTION
    root: str = "pelvis"
    feet: tuple = ("foot_l", "foot_r")
    head: str = "head"
    warnings: list = field(default_factory=list)

    def name(self, part: str) -> str:
        """The scene name of a canonical part name ("knee_l" -> prefix + "knee_l")."""
        return self.prefix + part

    @property
    def root_index(self) -> int:
        return self.bodies[self.root]

    @property
    def num_actuators(self) -> int:
        return len(self.actuators)


# ------------------------------------------------------------------ helpers
def _scene(builder_or_model):
    """The SceneBuilder behind a builder or a compiled Model."""
    if isinstance(getattr(builder_or_model, "joints", None), list):
        return builder_or_model
    builder = getattr(builder_or_model, "_builder", None)
    if builder is None:
        raise TypeError(f"expected a SceneBuilder or a Model, got {type(builder_or_model).__name__}")
    return builder


def _positive(value, name):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


def _quat_axis_angle(axis, angle):
    return math3d.quat_from_axis_angle(np.asarray(axis, dtype=float), float(angle))


def _q_twist(angle):
    """Rotation by ``angle`` about the joint frame's x axis."""
    h = 0.5 * float(angle)
    return np.array([math.cos(h), math.sin(h), 0.0, 0.0])


def _q_swing(swing_y, swing_z):
    """Rotation by sqrt(sy² + sz²) about (0, sy, sz) / norm."""
    angle = math.hypot(swing_y, swing_z)
    if angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    s = math.sin(0.5 * angle) / angle
    return np.array([math.cos(0.5 * angle), 0.0, swing_y * s, swing_z * s])


def _wrap(angle):
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def swing_twist(q_rel) -> tuple[float, float, float]:
    """(twist, swing_y, swing_z) of a joint's relative rotation
    q_rel = q_swing(swing_y, swing_z) ⊗ q_twist(twist), twist about x."""
    q = np.asarray(q_rel, dtype=float)
    twist = _wrap(2.0 * math.atan2(q[1], q[0]))
    swing = math3d.quat_mul(q, math3d.quat_conj(_q_twist(twist)))
    if swing[0] < 0.0:
        swing = -swing
    n = math.hypot(swing[2], swing[3])
    factor = 2.0 * math.atan2(n, swing[0]) / n if n > 1e-12 else 2.0 / swing[0]
    return twist, swing[2] * factor, swing[3] * factor


def _joint_key(humanoid, key):
    if key in humanoid.joints:
        return key
    if humanoid.prefix and isinstance(key, str) and key.startswith(humanoid.prefix):
        bare = key[len(humanoid.prefix):]
        if bare in humanoid.joints:
            return bare
    raise KeyError(f"the humanoid has no joint {key!r}; joints: {list(humanoid.joints)}")


def _relative_rotation(kind, value, name):
    """q_rel of a joint from its angle (hinge) or (twist, swing_y, swing_z) (ball)."""
    v = np.asarray(value, dtype=float).reshape(-1)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"joint {name!r}: angles must be finite, got {value!r}")
    if kind == "hinge":
        if v.shape != (1,):
            raise ValueError(f"joint {name!r} is a hinge: give one angle, got {value!r}")
        return _q_twist(v[0])
    if kind == "ball":
        if v.shape != (3,):
            raise ValueError(f"joint {name!r} is a ball joint: give (twist, swing_y, swing_z), got {value!r}")
        return math3d.quat_mul(_q_swing(v[1], v[2]), _q_twist(v[0]))
    if kind == "fixed":
        if np.any(v != 0):
            raise ValueError(f"joint {name!r} is fixed: it has no angles, got {value!r}")
        return np.array([1.0, 0.0, 0.0, 0.0])
    raise ValueError(f"joint {name!r}: unknown kind {kind!r}")


def _tree_order(scene, joint_ids, root):
    """Joints ordered outwards from ``root``: (joint, known body, unknown body)."""
    known = {root}
    pending = list(joint_ids)
    order = []
    while pending:
        progressed = False
        for j in list(pending):
            spec = scene.joints[j]
            if spec.parent in known and spec.child not in known:
                order.append((j, True))
                known.add(spec.child)
            elif spec.child in known and spec.parent not in known:
                order.append((j, False))
                known.add(spec.parent)
            elif spec.parent in known and spec.child in known:
                raise SceneError(f"joint {spec.name!r} closes a loop; pose() needs a tree of joints")
            else:
                continue
            pending.remove(j)
            progressed = True
        if not progressed:
            names = [scene.joints[j].name for j in pending]
            raise SceneError(f"joints {names} are not connected to the root body {scene.bodies[root].name!r}")
    return order


# ---------------------------------------------------------------- the build
def add_humanoid(
    builder,
    prefix: str = "",
    height: float = 1.75,
    mass: float = 75.0,
    position=(0.0, 0.0, 0.0),
    yaw: float = 0.0,
    hands: bool = False,
    torque_scale: float = 1.0,
    damping: float = 1.0,
    material: str = "bone",
) -> Humanoid:
    """Add a standing humanoid ragdoll to ``builder`` and describe it.

    prefix: prepended to every body and joint name (several humanoids per scene).
    height: stature in m (top of the head above the soles); mass: total body
    mass in kg, split by de Leva's fractions (the bone masses sum to it).
    position: world point between the feet on the ground (m); the soles lie
    exactly on the plane z = position[2]. yaw: rad about +z; at 0 it faces +x
    with its left side towards +y. hands: add hand bones (else the hand's mass
    and length go to the forearm). torque_scale: multiplies every maximum
    torque (0 makes a passive doll without actuators). damping: multiplies the
    passive joint damping, DAMPING_PER_TORQUE x the joint's strength
    (N·m·s/rad); 0 for none. material: a material name of the builder's table.

    Raises ValueError naming the argument for a non-positive height or mass.
    """
    height = _positive(height, "height")
    mass = _positive(mass, "mass")
    try:
        torque_scale = float(torque_scale)
        damping = float(damping)
        yaw = float(yaw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"torque_scale, damping and yaw must be numbers: {exc}") from None
    if not math.isfinite(torque_scale) or torque_scale < 0:
        raise ValueError(f"torque_scale must be a finite number >= 0, got {torque_scale!r}")
    if not math.isfinite(damping) or damping < 0:
        raise ValueError(f"damping must be a finite number >= 0, got {damping!r}")
    if not math.isfinite(yaw):
        raise ValueError(f"yaw must be finite, got {yaw!r}")
    origin = np.asarray(position, dtype=float).reshape(-1)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"position must be 3 finite numbers, got {position!r}")
    if not isinstance(prefix, str):
        raise ValueError(f"prefix must be a string, got {prefix!r}")

    s = height / REFERENCE_STATURE  # geometric scale
    strength = mass / STRENGTH_REFERENCE_MASS
    seg = {k: v["length"] * s for k, v in DE_LEVA_MALE.items()}
    q_yaw = _quat_axis_angle((0.0, 0.0, 1.0), yaw)

    def world(p):
        return origin + math3d.quat_rotate(q_yaw, np.asarray(p, dtype=float))

    # Masses: de Leva fractions, normalised so they sum to `mass` exactly.
    frac = {
        "pelvis": DE_LEVA_MALE["lower_trunk"]["mass"],
        "abdomen": DE_LEVA_MALE["mid_trunk"]["mass"],
        "chest": DE_LEVA_MALE["upper_trunk"]["mass"],
        "head": DE_LEVA_MALE["head"]["mass"],
    }
    for side in "lr":
        frac[f"upper_arm_{side}"] = DE_LEVA_MALE["upper_arm"]["mass"]
        if hands:
            frac[f"lower_arm_{side}"] = DE_LEVA_MALE["forearm"]["mass"]
            frac[f"hand_{side}"] = DE_LEVA_MALE["hand"]["mass"]
        else:
            frac[f"lower_arm_{side}"] = DE_LEVA_MALE["forearm"]["mass"] + DE_LEVA_MALE["hand"]["mass"]
        frac[f"thigh_{side}"] = DE_LEVA_MALE["thigh"]["mass"]
        frac[f"shin_{side}"] = DE_LEVA_MALE["shank"]["mass"]
        frac[f"foot_{side}"] = DE_LEVA_MALE["foot"]["mass"]
    total = sum(frac.values())
    masses = {k: mass * v / total for k, v in frac.items()}

    # Heights of the joint centres above the soles (m).
    z_ankle = ANKLE_HEIGHT * height
    z_knee = z_ankle + seg["shank"]
    z_hip = z_knee + seg["thigh"]
    z_navel = z_hip + seg["lower_trunk"]  # omphalion
    z_xiphoid = z_navel + seg["mid_trunk"]
    z_neck = z_xiphoid + seg["upper_trunk"]  # suprasternale
    z_shoulder = z_neck - SHOULDER_DROP * s

    bodies: dict[str, int] = {}
    orient: dict[str, np.ndarray] = {}  # body-local orientation before yaw

    def add(part, shape, center, q_local=(1.0, 0.0, 0.0, 0.0)):
        q_local = np.asarray(q_local, dtype=float)
        orient[part] = q_local
        bodies[part] = builder.add_body(prefix + part, shape, mass=masses[part], position=world(center),
                                        orientation=math3d.quat_mul(q_yaw, q_local), material=material)

    def capsule(part, top, bottom, radius, q_local=(1.0, 0.0, 0.0, 0.0)):
        top, bottom = np.asarray(top, dtype=float), np.asarray(bottom, dtype=float)
        half = 0.5 * float(np.linalg.norm(top - bottom)) - radius
        add(part, Capsule(radius, half), 0.5 * (top + bottom), q_local)

    def box(part, lo_z, hi_z, half_xy):
        add(part, Box((half_xy[0] * s, half_xy[1] * s, 0.5 * (hi_z - lo_z))), (0.0, 0.0, 0.5 * (lo_z + hi_z)))

    # Trunk and head (boxes span de Leva's segment endpoints; the head capsule
    # runs from the suprasternale to the vertex and so includes the neck).
    box("pelvis", z_hip, z_navel, PELVIS_HALF)
    box("abdomen", z_navel, z_xiphoid, ABDOMEN_HALF)
    box("chest", z_xiphoid, z_neck, CHEST_HALF)
    capsule("head", (0.0, 0.0, height), (0.0, 0.0, z_neck), HEAD_RADIUS * s)

    # Arms hang ARM_ABDUCTION out from the vertical, elbows straight, palms in.
    hand_length = 2.0 * DE_LEVA_MALE["hand"]["cm"] * seg["hand"]  # box centred on de Leva's hand CM
    arm = {}
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        q_arm = _quat_axis_angle((1.0, 0.0, 0.0), sgn * ARM_ABDUCTION)  # local +z = up the arm
        down = math3d.quat_rotate(q_arm, np.array([0.0, 0.0, -1.0]))
        shoulder = np.array([0.0, sgn * SHOULDER_HALF_SPACING * s, z_shoulder])
        elbow = shoulder + seg["upper_arm"] * down
        wrist = elbow + seg["forearm"] * down
        fingertips = wrist + hand_length * down
        arm[side] = (q_arm, shoulder, elbow, wrist)
        capsule(f"upper_arm_{side}", shoulder, elbow, UPPER_ARM_RADIUS * s, q_arm)
        capsule(f"lower_arm_{side}", elbow, wrist if hands else fingertips, FOREARM_RADIUS * s, q_arm)
        if hands:
            add(f"hand_{side}", Box((HAND_HALF[0] * s, HAND_HALF[1] * s, 0.5 * hand_length)),
                wrist + 0.5 * hand_length * down, q_arm)

    # Legs: vertical, feet flat with the soles on z = 0 (local).
    leg = {}
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        y = sgn * HIP_HALF_SPACING * s
        hip, knee, ankle = (np.array([0.0, y, z]) for z in (z_hip, z_knee, z_ankle))
        leg[side] = (hip, knee, ankle)
        capsule(f"thigh_{side}", hip, knee, THIGH_RADIUS * s)
        capsule(f"shin_{side}", knee, ankle, SHIN_RADIUS * s)
        foot_len = seg["foot"]
        add(f"foot_{side}", Box((0.5 * foot_len, FOOT_HALF_WIDTH * s, 0.5 * z_ankle)),
            (foot_len * (0.5 - ANKLE_FROM_HEEL), y, 0.5 * z_ankle))

    # Joints.
    joints: dict[str, int] = {}
    kinds: dict[str, str] = {}
    limits: dict[str, dict] = {}
    actuators: list[Actuator] = []

    def joint(name, kind_key, parent, child, anchor, frame_local):
        table = JOINT_TABLE[kind_key]
        frame_local = math3d.quat_from_matrix(np.asarray(frame_local, dtype=float))
        frame_world = math3d.quat_mul(math3d.quat_mul(q_yaw, orient[child]), frame_local)
        axis = math3d.quat_rotate(frame_world, np.array([1.0, 0.0, 0.0]))
        base = np.asarray(table["torque"], dtype=float) * strength
        torque = base * torque_scale
        c = damping * DAMPING_PER_TORQUE * float(base.max())
        full = prefix + name
        if table["kind"] == "ball":
            j = builder.add_ball(full, bodies[parent], bodies[child], anchor=world(anchor), twist_axis=axis,
                                 swing_limits=table["swing"], twist_limits=table["twist"],
                                 max_torque=torque, damping=c)
        else:
            j = builder.add_hinge(full, bodies[parent], bodies[child], anchor=world(anchor), axis=axis,
                                  limits=table["angle"], max_torque=float(torque[0]), damping=c)
        # Replace the builder's frames (x axis only prescribed) by the
        # anatomical ones: same x axis, y and z fixed to the bones, so swing_y
        # means flexion whatever the yaw. The build pose stays the zero:
        # q_parent ⊗ frame_parent == q_child ⊗ frame_child.
        spec = builder.joints[j]
        q_parent = builder.bodies[spec.parent].orientation
        q_child = builder.bodies[spec.child].orientation
        spec.frame_child = math3d.quat_mul(math3d.quat_conj(q_child), frame_world)
        spec.frame_parent = math3d.quat_mul(math3d.quat_conj(q_parent), frame_world)
        joints[name] = j
        kinds[name] = spec.kind
        limits[name] = {k: tuple(float(x) for x in v) for k, v in spec.limits.items()}
        for a in range(3):
            if spec.max_torque[a] > 0:
                actuators.append(Actuator(full + ACTUATOR_SUFFIX[spec.kind][a], j, a, float(spec.max_torque[a])))

    joint("spine_lower", "spine_lower", "pelvis", "abdomen", (0.0, 0.0, z_navel), _UP)
    joint("spine_upper", "spine_upper", "abdomen", "chest", (0.0, 0.0, z_xiphoid), _UP)
    joint("neck", "neck", "chest", "head", (0.0, 0.0, z_neck), _UP)
    for side in "lr":
        q_arm, shoulder, elbow, wrist = arm[side]
        joint(f"shoulder_{side}", "shoulder", "chest", f"upper_arm_{side}", shoulder, _DOWN)
        joint(f"elbow_{side}", "elbow", f"upper_arm_{side}", f"lower_arm_{side}", elbow, _ELBOW)
        if hands:
            joint(f"wrist_{side}", "wrist", f"lower_arm_{side}", f"hand_{side}", wrist, _DOWN)
    for side in "lr":
        hip, knee, ankle = leg[side]
        joint(f"hip_{side}", "hip", "pelvis", f"thigh_{side}", hip, _DOWN)
        joint(f"knee_{side}", "knee", f"thigh_{side}", f"shin_{side}", knee, _KNEE)
        joint(f"ankle_{side}", "ankle", f"shin_{side}", f"foot_{side}", ankle, _DOWN)

    humanoid = Humanoid(prefix=prefix, height=height, mass=mass, bodies=bodies, joints=joints,
                        joint_kinds=kinds, limits=limits, actuators=actuators, hands=bool(hands),
                        yaw=yaw, position=origin.copy())
    check_connected(builder, bodies["pelvis"], bodies.values())
    humanoid.warnings = check_conditioning(builder, joints=joints.values())
    for message in humanoid.warnings:
        warnings.warn(message, stacklevel=2)
    return humanoid


# ------------------------------------------------------------------ checks
#: Defaults of check_conditioning. Jolt's RagdollSettings::Stabilize (after
#: O. Strunk, "Stop my constraints from blowing up!", Havok) goes further: it
#: redistributes mass so every child/parent ratio lies in [0.8, 1.2] and raises
#: a parent's principal inertias towards the sum of its children's (at most 2x).
#: We only warn, at ratios a soft-step solver with substeps still handles; the
#: default humanoid's largest ratios are 5.9 (mass) and 13 (inertia), both at
#: the shoulder (chest/upper arm).
MAX_MASS_RATIO = 10.0
MAX_INERTIA_RATIO = 20.0


def check_conditioning(builder, max_mass_ratio: float = MAX_MASS_RATIO,
                       max_inertia_ratio: float = MAX_INERTIA_RATIO, joints=None) -> list[str]:
    """Warnings for joints whose bodies are badly matched for an iterative solver.

    For each joint (all of the builder's, or the indices in ``joints``) between
    two dynamic bodies, the mass ratio max(m_p/m_c, m_c/m_p) and the ratio of
    the bodies' largest principal moments of inertia (same form) are compared
    with the thresholds. Returns one message per exceeded ratio, naming the
    joint, both bodies and the ratio; an empty list means well conditioned.
    """
    scene = _scene(builder)
    max_mass_ratio = _positive(max_mass_ratio, "max_mass_ratio")
    max_inertia_ratio = _positive(max_inertia_ratio, "max_inertia_ratio")
    out = []
    for j in range(len(scene.joints)) if joints is None else joints:
        spec = scene.joints[int(j)]
        p, c = scene.bodies[spec.parent], scene.bodies[spec.child]
        if p.static or c.static:
            continue
        r = p.mass / c.mass
        r = max(r, 1.0 / r)
        if r > max_mass_ratio:
            out.append(f"joint {spec.name!r}: mass ratio {r:.3g} between parent {p.name!r} ({p.mass:.4g} kg) "
                       f"and child {c.name!r} ({c.mass:.4g} kg) exceeds {max_mass_ratio:g}")
        ip, ic = float(np.max(p.inertia)), float(np.max(c.inertia))
        r = ip / ic
        r = max(r, 1.0 / r)
        if r > max_inertia_ratio:
            out.append(f"joint {spec.name!r}: inertia ratio {r:.3g} between parent {p.name!r} "
                       f"({ip:.3g} kg·m²) and child {c.name!r} ({ic:.3g} kg·m²) exceeds {max_inertia_ratio:g}")
    return out


def check_connected(builder, root, bodies: Iterable) -> None:
    """Raise SceneError unless every body in ``bodies`` (names or indices) has
    a path of joints to ``root``. Joints are followed in either direction."""
    scene = _scene(builder)

    def index(b):
        if isinstance(b, str):
            for i, spec in enumerate(scene.bodies):
                if spec.name == b:
                    return i
            raise SceneError(f"check_connected: no body named {b!r}")
        return int(b)

    r = index(root)
    neighbours: dict[int, set] = {}
    for spec in scene.joints:
        neighbours.setdefault(spec.parent, set()).add(spec.child)
        neighbours.setdefault(spec.child, set()).add(spec.parent)
    seen, stack = {r}, [r]
    while stack:
        for n in neighbours.get(stack.pop(), ()):
            if n not in seen:
                seen.add(n)
                stack.append(n)
    loose = [scene.bodies[i].name for i in map(index, bodies) if i not in seen]
    if loose:
        raise SceneError(f"bodies {loose} have no joint path to the root body {scene.bodies[r].name!r}; "
                         f"connect each with a joint")


# ------------------------------------------------------------------- poses
def pose(humanoid: Humanoid, model_or_builder, angles: Mapping | None = None, root_position=None,
         root_orientation=None) -> tuple[np.ndarray, np.ndarray]:
    """Body poses of the scene with the humanoid's joints at ``angles``.

    angles: joint name (canonical or prefixed) -> hinge angle, or (twist,
    swing_y, swing_z) for a ball joint, in rad; joints left out stay at the
    build pose (zero). root_position (m) and root_orientation (w, x, y, z) place
    the pelvis (default: where it was built). Forward kinematics from the
    pelvis: q_child = q_parent ⊗ frame_parent ⊗ q_rel ⊗ conj(frame_child),
    x_child = x_parent + R_parent·anchor_parent − R_child·anchor_child.

    Returns positions (N, 3) and orientations (N, 4) of all N bodies of the
    scene; other bodies keep their build pose. Limits are not enforced.
    """
    scene = _scene(model_or_builder)
    pos = np.array([b.position for b in scene.bodies], dtype=float).reshape(-1, 3)
    quat = np.array([b.orientation for b in scene.bodies], dtype=float).reshape(-1, 4)
    rel = {}
    for key, value in (angles or {}).items():
        name = _joint_key(humanoid, key)
        j = humanoid.joints[name]
        rel[j] = _relative_rotation(scene.joints[j].kind, value, humanoid.name(name))
    root = humanoid.root_index
    if root_position is not None:
        rp = np.asarray(root_position, dtype=float).reshape(-1)
        if rp.shape != (3,) or not np.all(np.isfinite(rp)):
            raise ValueError(f"root_position must be 3 finite numbers, got {root_position!r}")
        pos[root] = rp
    if root_orientation is not None:
        rq = np.asarray(root_orientation, dtype=float).reshape(-1)
        if rq.shape != (4,) or not np.all(np.isfinite(rq)) or np.linalg.norm(rq) < 1e-9:
            raise ValueError(f"root_orientation must be a non-zero quaternion (w, x, y, z), got {root_orientation!r}")
        quat[root] = rq / np.linalg.norm(rq)
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    for j, outward in _tree_order(scene, humanoid.joints.values(), root):
        spec = scene.joints[j]
        q_rel = rel.get(j, identity)
        p, c = spec.parent, spec.child
        if outward:
            quat[c] = math3d.quat_mul(math3d.quat_mul(math3d.quat_mul(quat[p], spec.frame_parent), q_rel),
                                      math3d.quat_conj(spec.frame_child))
            pos[c] = (pos[p] + math3d.quat_rotate(quat[p], spec.anchor_parent)
                      - math3d.quat_rotate(quat[c], spec.anchor_child))
        else:
            quat[p] = math3d.quat_mul(math3d.quat_mul(math3d.quat_mul(quat[c], spec.frame_child),
                                                      math3d.quat_conj(q_rel)), math3d.quat_conj(spec.frame_parent))
            pos[p] = (pos[c] + math3d.quat_rotate(quat[c], spec.anchor_child)
                      - math3d.quat_rotate(quat[p], spec.anchor_parent))
    return pos, quat


def joint_angles(humanoid: Humanoid, builder_or_model, positions, orientations) -> dict:
    """The humanoid's joint angles in a scene pose (the inverse of :func:`pose`).

    orientations: (N, 4) unit quaternions of all bodies (positions are
    accepted for symmetry with :func:`pose` and not needed). Returns canonical
    joint name -> hinge angle (float) or (twist, swing_y, swing_z) (tuple), rad,
    from q_rel = conj(q_p ⊗ frame_p) ⊗ (q_c ⊗ frame_c) = q_swing ⊗ q_twist.
    A hinge reports its twist; any swing (joint error) is ignored.
    """
    scene = _scene(builder_or_model)
    quat = np.asarray(orientations, dtype=float).reshape(-1, 4)
    out = {}
    for name, j in humanoid.joints.items():
        spec = scene.joints[j]
        a = math3d.quat_mul(quat[spec.parent], spec.frame_parent)
        b = math3d.quat_mul(quat[spec.child], spec.frame_child)
        twist, sy, sz = swing_twist(math3d.quat_mul(math3d.quat_conj(a), b))
        out[name] = float(twist) if spec.kind == "hinge" else (float(twist), float(sy), float(sz))
    return out


def standing_pose(humanoid: Humanoid) -> dict:
    """The build pose: every joint at zero (upright, arms hanging, knees straight)."""
    return {name: 0.0 if kind == "hinge" else (0.0, 0.0, 0.0) for name, kind in humanoid.joint_kinds.items()}


def t_pose(humanoid: Humanoid) -> dict:
    """Standing with both arms straight out sideways, horizontal.

    The shoulder swings in the frontal plane (swing_z) by 90° minus the build
    pose's arm abduction; the left arm's frame z points backwards, so its
    abduction is a negative swing_z and the right arm's a positive one.
    """
    angles = standing_pose(humanoid)
    lift = 0.5 * math.pi - humanoid.arm_abduction
    angles["shoulder_l"] = (0.0, 0.0, -lift)
    angles["shoulder_r"] = (0.0, 0.0, lift)
    return angles


def random_pose(rng: np.random.Generator, humanoid: Humanoid, scale: float = 1.0) -> dict:
    """Joint angles drawn uniformly within every joint's limits.

    Hinge angles and twists are uniform on [lo, hi]; swings are uniform over the
    elliptic cone (swing_y/cone_y)² + (swing_z/cone_z)² <= 1. ``scale`` in
    [0, 1] shrinks every range towards the standing pose (0 gives it).
    """
    scale = float(scale)
    if not 0.0 <= scale <= 1.0:
        raise ValueError(f"scale must lie in [0, 1], got {scale!r}")
    out = {}
    for name, kind in humanoid.joint_kinds.items():
        lim = humanoid.limits[name]
        if kind == "hinge":
            lo, hi = lim.get("angle", (-math.pi, math.pi))
            out[name] = float(rng.uniform(lo * scale, hi * scale))
        elif kind == "ball":
            lo, hi = lim.get("twist", (-math.pi, math.pi))
            twist = float(rng.uniform(lo * scale, hi * scale))
            cy, cz = lim.get("swing", (0.0, 0.0))
            r = math.sqrt(float(rng.uniform())) * scale
            phi = float(rng.uniform(0.0, 2.0 * math.pi))
            out[name] = (twist, cy * r * math.cos(phi), cz * r * math.sin(phi))
    return out


def within_limits(humanoid: Humanoid, angles: Mapping, tol: float = 1e-9) -> dict:
    """Per joint, whether ``angles`` lie within its limits (inclusive, ± tol)."""
    out = {}
    for key, value in angles.items():
        name = _joint_key(humanoid, key)
        lim = humanoid.limits[name]
        v = np.asarray(value, dtype=float).reshape(-1)
        ok = True
        if humanoid.joint_kinds[name] == "hinge":
            lo, hi = lim.get("angle", (-math.inf, math.inf))
            ok = lo - tol <= v[0] <= hi + tol
        else:
            lo, hi = lim.get("twist", (-math.inf, math.inf))
            ok = lo - tol <= v[0] <= hi + tol
            if "swing" in lim:
                cy, cz = lim["swing"]
                ok = ok and (v[1] / cy) ** 2 + (v[2] / cz) ** 2 <= 1.0 + tol
        out[name] = bool(ok)
    return out
