"""Scenes shared by the accuracy and effects benchmarks.

Each builder returns a ``SceneBuilder`` (not yet built) so that callers can
change settings or switch effects before ``build()``. Geometry helpers measure
penetration from the body shapes alone (no contact manifold needed).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

import engine as e
from engine.humanoid import add_humanoid
from engine.math3d import quat_from_axis_angle, quat_rotate, quat_to_matrix
from engine.shapes import BOX, CAPSULE, SPHERE

G = e.STANDARD_GRAVITY
Y = np.array([0.0, 1.0, 0.0])


# ------------------------------------------------------------------ pendulums
PENDULUM_LENGTH = 0.5
PENDULUM_RADIUS = 0.05
PENDULUM_MASS = 1.0


def pendulum(amplitude=math.pi / 2, settings=None, **kw):
    """A 0.5 m, 1 kg capsule on a hinge at the origin (axis y), released at
    ``amplitude`` rad from hanging straight down."""
    b = e.SceneBuilder(settings=settings, **kw)
    q = quat_from_axis_angle(Y, amplitude)
    b.add_body("rod", e.Capsule(PENDULUM_RADIUS, PENDULUM_LENGTH / 2 - PENDULUM_RADIUS), mass=PENDULUM_MASS,
               position=quat_rotate(q, np.array([0.0, 0.0, -PENDULUM_LENGTH / 2])), orientation=q)
    b.add_hinge("pivot", None, "rod", anchor=(0, 0, 0), axis=(0, 1, 0))
    return b


def pendulum_exact_period(model, amplitude=math.pi / 2):
    """Exact period of the compound pendulum: T0 (2/π) K(sin²(θ0/2))."""
    from scipy.special import ellipk

    inertia = model.inertia[0, 0] + PENDULUM_MASS * (PENDULUM_LENGTH / 2) ** 2
    small = 2 * math.pi * math.sqrt(inertia / (PENDULUM_MASS * G * PENDULUM_LENGTH / 2))
    return small * 2 / math.pi * ellipk(math.sin(amplitude / 2) ** 2)


def double_pendulum(settings=None, **kw):
    """Two 0.5 m, 1 kg capsules on hinges, released horizontal; no joint damping."""
    b = e.SceneBuilder(settings=settings, **kw)
    length = 0.5
    q = quat_from_axis_angle(Y, math.pi / 2)
    b.add_body("l1", e.Capsule(0.04, length / 2 - 0.04), mass=1.0, position=(length / 2, 0, 0), orientation=q)
    b.add_body("l2", e.Capsule(0.04, length / 2 - 0.04), mass=1.0, position=(1.5 * length, 0, 0), orientation=q)
    b.add_hinge("j1", None, "l1", anchor=(0, 0, 0), axis=(0, 1, 0))
    b.add_hinge("j2", "l1", "l2", anchor=(length, 0, 0), axis=(0, 1, 0))
    return b


def inverted_pendulum(settings=None, ground=False, **kw):
    """A pole on an actuated hinge to the world, standing up (the balance task)."""
    b = e.SceneBuilder(settings=settings, **kw)
    if ground:
        b.add_ground()
    b.add_body("pole", e.Capsule(0.04, 0.46), mass=1.0, position=(0, 0, 0.5),
               orientation=quat_from_axis_angle(Y, 0.02))
    b.add_hinge("hinge", None, "pole", anchor=(0, 0, 0), axis=(0, 1, 0), limits=(-1.5, 1.5), max_torque=20.0)
    return b


# --------------------------------------------------------------- free bodies
def spinning_box(settings=None, **kw):
    """A torque-free box (I1 < I2 < I3) spun near its intermediate axis, no gravity."""
    b = e.SceneBuilder(gravity=None, settings=settings, **kw)
    q = quat_from_axis_angle(np.array([1.0, 2.0, 3.0]), 0.7)
    wb = np.array([0.01, 10.0, 0.01])
    b.add_body("box", e.Box((0.4, 0.2, 0.1)), mass=2.0, orientation=q, angular_velocity=quat_to_matrix(q) @ wb)
    return b


SPRING_K, SPRING_M, SPRING_X0 = 100.0, 1.0, 0.1


def spring_mass(settings=None, **kw):
    """A 1 kg mass on a 100 N/m spring to the world along x (rest length 1 m), no gravity."""
    b = e.SceneBuilder(gravity=None, settings=settings, **kw)
    b.add_body("mass", e.Sphere(0.05), mass=SPRING_M, position=(1.0 + SPRING_X0, 0, 0))
    b.add_spring("s", None, "mass", anchor_a=(0, 0, 0), stiffness=SPRING_K, rest_length=1.0)
    return b


# ------------------------------------------------------------------ contacts
BALL_RADIUS, BALL_DROP = 0.1, 1.0


def bouncing_ball(settings=None, **kw):
    """A rubber ball (r 0.1 m) whose lowest point starts 1 m above a concrete
    floor; restitution of the pair = max(0.8, 0.1) = 0.8."""
    b = e.SceneBuilder(settings=settings, **kw)
    b.add_ground(material="concrete")
    b.add_body("ball", e.Sphere(BALL_RADIUS), mass=1.0, position=(0, 0, BALL_RADIUS + BALL_DROP), material="rubber")
    return b


SLIDE_V0, SLIDE_HALF = 3.0, (0.2, 0.2, 0.05)


def sliding_box(settings=None, **kw):
    """A flat wooden box on a wooden floor launched at 3 m/s along x (μk = 0.2)."""
    b = e.SceneBuilder(settings=settings, **kw)
    b.add_ground(material="wood")
    b.add_body("box", e.Box(SLIDE_HALF), mass=1.0, position=(0, 0, SLIDE_HALF[2]), velocity=(SLIDE_V0, 0, 0),
               material="wood")
    return b


HINGED_HALF = (0.2, 0.15, 0.1)


def hinged_boxes(angle_deg=0.0, masses=(1.0, 1.0, 1.0), settings=None, **kw):
    """Wooden boxes (0.4 x 0.3 x 0.2 m; μs 0.5, μk 0.2) of ``masses`` kg lying
    flat in a row up a floor tilted by ``angle_deg`` about y, 2 cm apart,
    each joined to the next by a hinge across the slope midway between them."""
    th = math.radians(angle_deg)
    n = np.array([-math.sin(th), 0.0, math.cos(th)])  # the floor's normal
    up = np.array([math.cos(th), 0.0, math.sin(th)])  # up the slope
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), -th)
    b = e.SceneBuilder(settings=settings, **kw)
    b.add_ground(normal=n, material="wood")
    lift = n * HINGED_HALF[2]
    for i, m in enumerate(masses):
        b.add_body(f"box{i}", e.Box(HINGED_HALF), mass=m, position=lift + up * 0.42 * i, orientation=q,
                   material="wood")
    for i in range(len(masses) - 1):
        b.add_hinge(f"hinge{i}", f"box{i}", f"box{i + 1}", anchor=lift + up * (0.42 * i + 0.21))
    return b


STACK_HALF = (0.1, 0.1, 0.1)


def box_stack(n=10, settings=None, **kw):
    """``n`` 0.2 m wooden cubes of 1 kg resting in a column on the floor."""
    b = e.SceneBuilder(settings=settings, **kw)
    b.add_ground(material="wood")
    h = STACK_HALF[2]
    for i in range(n):
        b.add_body(f"box_{i}", e.Box(STACK_HALF), mass=1.0, position=(0, 0, h + 2 * h * i), material="wood")
    return b


def box_pile(n=12, settings=None, ground=True, **kw):
    """``n`` boxes dropped in a loose pile (3 x 2 columns, slightly rotated)."""
    b = e.SceneBuilder(settings=settings, **kw)
    if ground:
        b.add_ground(material="wood")
    rng = np.random.default_rng(1)
    for i in range(n):
        x, y, z = (i % 3) * 0.25, ((i // 3) % 2) * 0.25, 0.15 + 0.22 * (i // 6)
        q = quat_from_axis_angle(rng.normal(size=3), 0.2)
        b.add_body(f"box_{i}", e.Box((0.1, 0.08, 0.06)), mass=1.0, position=(x, y, z), orientation=q,
                   material="wood")
    return b


# ------------------------------------------------------------------- ragdoll
def ragdoll(settings=None, ground=True, height=0.0, **kw):
    """The humanoid standing (or ``height`` m above) the floor; returns (builder, humanoid)."""
    b = e.SceneBuilder(settings=settings, **kw)
    if ground:
        b.add_ground()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = add_humanoid(b, position=(0.0, 0.0, height))
    return b, h


# ------------------------------------------------------------------ geometry
def lowest_points(model, state) -> np.ndarray:
    """(W, N) height of each dynamic body's lowest point (inf for others)."""
    z = state.position[..., 2]
    R = quat_to_matrix(state.orientation)  # (W, N, 3, 3)
    p = model.shape_params
    t = model.shape_type
    low = np.full(z.shape, np.inf)
    sphere = (t == SPHERE) & model.dynamic
    capsule = (t == CAPSULE) & model.dynamic
    box = (t == BOX) & model.dynamic
    low[:, sphere] = z[:, sphere] - p[sphere, 0]
    low[:, capsule] = z[:, capsule] - np.abs(R[:, capsule, 2, 2]) * p[capsule, 1] - p[capsule, 0]
    low[:, box] = z[:, box] - (np.abs(R[:, box, 2, :]) * p[box]).sum(-1)
    return low


def ground_penetration(model, state, height=0.0) -> np.ndarray:
    """(W,) deepest penetration of any dynamic body into the plane z = height, m."""
    return np.maximum(height - lowest_points(model, state), 0.0).max(axis=1)
