"""Scene builder: describe bodies, springs and joints once, compile to a Model.

Everything is given in world coordinates at the scene's initial pose (SI units:
metres, kilograms, seconds, radians). ``build()`` validates the scene, naming
the item at fault in every error, and compiles it into an immutable
:class:`engine.model.Model`, whose ``initial_state(num_worlds)`` gives a
batched :class:`engine.state.State`.

>>> b = SceneBuilder()
>>> ball = b.add_body("ball", Sphere(0.1), mass=1.0, position=(0, 0, 2))
>>> model = b.build()
>>> state = model.initial_state(num_worlds=8)
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace

import numpy as np

from . import math3d
from .errors import SceneError
from .materials import MaterialTable
from .settings import Settings
from .shapes import Box, Capsule, Plane, Sphere

STANDARD_GRAVITY = 9.80665  # m/s², the thesis's g
GRAVITATIONAL_CONSTANT = 6.67430e-11  # m³ kg⁻¹ s⁻², CODATA 2018

#: Effects a scene may declare with ``SceneBuilder.enable``; others are implied
#: by what the scene holds (springs, joints, motors, contacts, damping).
DECLARABLE_EFFECTS = ("gravity", "gravitation", "damping", "contacts", "friction",
                      "restitution", "self_collision")
ALL_EFFECTS = DECLARABLE_EFFECTS + ("springs", "joints", "joint_limits", "motors")

WORLD = None  # anchor a spring or joint to the fixed world frame


def frame_from_x_axis(x) -> np.ndarray:
    """A unit quaternion whose rotated x axis is the unit vector ``x``
    (y and z completed deterministically)."""
    x = np.asarray(x, dtype=float)
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    return math3d.quat_from_matrix(np.column_stack((x, y, z)))


def _vec(value, n, what, name):
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{what}: {name} must be {n} numbers, got {value!r}") from exc
    if arr.shape != (n,):
        raise SceneError(f"{what}: {name} must be {n} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{what}: {name} has a NaN or infinite entry: {value!r}")
    return arr


def _scalar(value, what, name, minimum=None, allow_inf=False, strict=False):
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{what}: {name} must be a number, got {value!r}") from exc
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise SceneError(f"{what}: {name} must be finite, got {value!r}")
    if minimum is not None and (v < minimum or (strict and v == minimum)):
        op = ">" if strict else ">="
        raise SceneError(f"{what}: {name} must be {op} {minimum}, got {value!r}")
    return v


def _bits(value, what, name):
    """A collision group or mask: a whole number in [0, 2³²)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 0 <= value < 2 ** 32:
        raise SceneError(f"{what}: {name} must be a whole number in [0, 2**32) (a bit set), got {value!r}")
    return int(value)


def _settings_from(values, what, base=None):
    """``base`` (default ``Settings()``) with the fields in the mapping ``values``
    replaced; an unknown field is a SceneError naming it and the known ones."""
    known = {f.name for f in fields(Settings)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise SceneError(f"{what}: unknown settings {unknown}; settings: {sorted(known)}")
    return replace(Settings() if base is None else base, **values)


def _undo_world_body_on_error(method):
    """Leave the builder as it was when ``method`` raises: naming the world
    (``None``) as a joint's or spring's body adds the world body first."""
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        bodies, world = len(self.bodies), self._world_body
        try:
            return method(self, *args, **kwargs)
        except Exception:
            for spec in self.bodies[bodies:]:
                del self._names[spec.name]
            del self.bodies[bodies:]
            self._world_body = world
            raise
    return wrapper


@dataclass
class BodySpec:
    name: str
    shape: object
    mass: float
    inertia: np.ndarray  # principal moments, kg·m²
    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    material: str
    static: bool
    linear_damping: float
    angular_damping: float
    collision_group: int
    collision_mask: int


@dataclass
class SpringSpec:
    name: str
    body_a: int
    body_b: int
    anchor_a: np.ndarray  # body-local
    anchor_b: np.ndarray
    rest_length: float
    stiffness: float
    damping: float
    elastic_limit: float  # m of extension past which it breaks (inf: never)


@dataclass
class JointSpec:
    name: str
    kind: str  # "hinge", "ball", "fixed"
    parent: int
    child: int
    anchor_parent: np.ndarray  # body-local anchor points
    anchor_child: np.ndarray
    frame_parent: np.ndarray  # body-local joint frame (quaternion); x axis = twist/hinge axis
    frame_child: np.ndarray
    limits: dict = field(default_factory=dict)
    max_torque: np.ndarray = field(default_factory=lambda: np.zeros(3))
    damping: float = 0.0
    stiffness: float = 0.0
    rest_angles: np.ndarray = field(default_factory=lambda: np.zeros(3))
    break_force: float = math.inf
    break_torque: float = math.inf
    collide_connected: bool = False


class SceneBuilder:
    """Collects a scene and compiles it into a :class:`Model`.

    gravity: a 3-vector in m/s² (default (0, 0, -9.80665)), or None for none.
    materials: a :class:`MaterialTable` (default: the textbook table).
    settings: a :class:`Settings`, or a mapping of its fields' values; keyword
    overrides of its fields may follow either.
    """

    def __init__(self, gravity=(0.0, 0.0, -STANDARD_GRAVITY), materials=None, settings=None, **setting_overrides):
        self.gravity = None if gravity is None else gravity
        self.materials = (materials or MaterialTable()).copy()
        if settings is None:
            base = Settings()
        elif isinstance(settings, Settings):
            base = settings
        elif isinstance(settings, Mapping):
            base = _settings_from(settings, "settings")
        else:
            raise SceneError(f"settings must be a Settings or a mapping of its fields, got {type(settings).__name__}")
        self.settings = _settings_from(setting_overrides, "setting", base) if setting_overrides else base
        self.bodies: list[BodySpec] = []
        self.springs: list[SpringSpec] = []
        self.joints: list[JointSpec] = []
        self.effects: dict[str, dict] = {}
        self.collision_exclusions: set[tuple[int, int]] = set()
        self._names: dict[str, int] = {}
        self._world_body = None
        if gravity is not None:
            self.effects["gravity"] = {}

    # ----------------------------------------------------------------- bodies
    def add_body(
        self,
        name: str,
        shape,
        mass: float | None = None,
        density: float | None = None,
        position=(0.0, 0.0, 0.0),
        orientation=(1.0, 0.0, 0.0, 0.0),
        velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
        material: str = "default",
        static: bool = False,
        linear_damping: float = 0.0,
        angular_damping: float = 0.0,
        collision_group: int = 1,
        collision_mask: int = 0xFFFFFFFF,
    ) -> int:
        """Add a rigid body and return its index.

        shape: Sphere, Capsule, Box (or Plane / None for static bodies only).
        mass (kg) or density (kg/m³); if neither, the material's density.
        orientation: unit quaternion (w, x, y, z); it is normalised.
        velocity (m/s) and angular_velocity (rad/s) are in the world frame.
        linear_damping, angular_damping: 1/s, velocity decays as exp(-c t).
        collision_group, collision_mask: bit sets; two bodies collide when each
        one's group meets the other's mask.
        """
        what = f"body {name!r}"
        if not isinstance(name, str) or not name:
            raise SceneError(f"body names must be non-empty strings, got {name!r}")
        if name in self._names:
            raise SceneError(f"{what}: a body of that name already exists")
        if shape is not None and not isinstance(shape, (Sphere, Capsule, Box, Plane)):
            raise SceneError(f"{what}: shape must be Sphere, Capsule, Box, Plane or None, got {shape!r}")
        try:
            if shape is not None:
                shape.validate(what)
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        try:
            self.materials.get(material, what)
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        if (shape is None or isinstance(shape, Plane)) and not static:
            raise SceneError(f"{what}: a body without a solid shape must be static")
        pos = _vec(position, 3, what, "position")
        quat = _vec(orientation, 4, what, "orientation")
        qn = np.linalg.norm(quat)
        if qn < 1e-9:
            raise SceneError(f"{what}: orientation quaternion has zero length")
        quat = quat / qn
        vel = _vec(velocity, 3, what, "velocity")
        avel = _vec(angular_velocity, 3, what, "angular_velocity")
        lin_d = _scalar(linear_damping, what, "linear_damping", minimum=0.0)
        ang_d = _scalar(angular_damping, what, "angular_damping", minimum=0.0)
        if static:
            m, inertia = math.inf, np.full(3, math.inf)
            if np.any(vel) or np.any(avel):
                raise SceneError(f"{what}: a static body cannot have a velocity")
            if mass is not None or density is not None:
                raise SceneError(f"{what}: a static body has no mass; leave out mass and density")
        else:
            if mass is not None and density is not None:
                raise SceneError(f"{what}: give mass or density, not both")
            if mass is not None:
                m = _scalar(mass, what, "mass", minimum=0.0, strict=True)
            else:
                rho = self.materials.get(material).density if density is None else density
                rho = _scalar(rho, what, "density", minimum=0.0, strict=True)
                m = rho * shape.volume()
            inertia = m * shape.unit_inertia()
        self.bodies.append(
            BodySpec(name, shape, m, inertia, pos, quat, vel, avel, material, bool(static),
                     lin_d, ang_d, _bits(collision_group, what, "collision_group"),
                     _bits(collision_mask, what, "collision_mask"))
        )
        if lin_d > 0 or ang_d > 0:
            self.effects.setdefault("damping", {})
        index = len(self.bodies) - 1
        self._names[name] = index
        return index

    def add_ground(self, name: str = "ground", height: float = 0.0, normal=(0.0, 0.0, 1.0),
                   material: str = "concrete") -> int:
        """Add the static ground plane through (0, 0, height) with the given
        outward normal (a sloped plane when the normal is tilted)."""
        what = f"plane {name!r}"
        n = _vec(normal, 3, what, "normal")
        length = np.linalg.norm(n)
        if length < 1e-9:
            raise SceneError(f"{what}: normal has zero length")
        n = n / length
        h = _scalar(height, what, "height")
        z = np.array([0.0, 0.0, 1.0])
        axis = np.cross(z, n)
        s = np.linalg.norm(axis)
        if s < 1e-12:
            quat = np.array([1.0, 0.0, 0.0, 0.0]) if n[2] > 0 else np.array([0.0, 1.0, 0.0, 0.0])
        else:
            quat = math3d.quat_from_axis_angle(axis / s, math.atan2(s, n[2]))
        index = self.add_body(name, Plane(), position=(0.0, 0.0, h), orientation=quat,
                              material=material, static=True)
        for effect in ("contacts", "friction", "restitution"):
            self.effects.setdefault(effect, {})
        return index

    def body_index(self, body, what: str = "") -> int:
        """Index of a body given by name or index; ``None`` means the world."""
        if body is WORLD:
            if self._world_body is None:
                self._world_body = self.add_body("world", None, static=True)
            return self._world_body
        if isinstance(body, str):
            if body not in self._names:
                raise SceneError(f"{what}: no body named {body!r}; bodies: {list(self._names)}")
            return self._names[body]
        if isinstance(body, (int, np.integer)) and 0 <= int(body) < len(self.bodies):
            return int(body)
        raise SceneError(f"{what}: no body {body!r} (there are {len(self.bodies)} bodies)")

    def _local_point(self, body: int, world_point) -> np.ndarray:
        spec = self.bodies[body]
        return math3d.quat_rotate_inv(spec.orientation, world_point - spec.position)

    def _check_name(self, items, name, kind):
        if not isinstance(name, str) or not name:
            raise SceneError(f"{kind} names must be non-empty strings, got {name!r}")
        if any(item.name == name for item in items):
            raise SceneError(f"{kind} {name!r}: a {kind} of that name already exists")

    # ---------------------------------------------------------------- springs
    @_undo_world_body_on_error
    def add_spring(self, name: str, body_a, body_b, anchor_a=None, anchor_b=None,
                   stiffness: float = 100.0, damping: float = 0.0, rest_length: float | None = None,
                   elastic_limit: float = math.inf) -> int:
        """Add a Hooke spring between world points ``anchor_a`` on ``body_a``
        and ``anchor_b`` on ``body_b`` (default: the body centres).

        stiffness k in N/m, damping c in N·s/m along the spring line, rest
        length in m (default: the initial distance), elastic_limit in m: when
        |length - rest_length| exceeds it the spring breaks for good and an
        event reports it (the thesis's limit of elasticity, section 4.3.2).
        A body of ``None`` anchors that end to the fixed world.
        """
        what = f"spring {name!r}"
        self._check_name(self.springs, name, "spring")
        ia = self.body_index(body_a, what)
        ib = self.body_index(body_b, what)
        if ia == ib:
            raise SceneError(f"{what}: both ends are on body {self.bodies[ia].name!r}")
        pa = self.bodies[ia].position if anchor_a is None else _vec(anchor_a, 3, what, "anchor_a")
        pb = self.bodies[ib].position if anchor_b is None else _vec(anchor_b, 3, what, "anchor_b")
        k = _scalar(stiffness, what, "stiffness", minimum=0.0, strict=True)
        c = _scalar(damping, what, "damping", minimum=0.0)
        rest = float(np.linalg.norm(pb - pa)) if rest_length is None else _scalar(
            rest_length, what, "rest_length", minimum=0.0)
        limit = _scalar(elastic_limit, what, "elastic_limit", minimum=0.0, allow_inf=True, strict=True)
        self.springs.append(SpringSpec(name, ia, ib, self._local_point(ia, pa), self._local_point(ib, pb),
                                       rest, k, c, limit))
        return len(self.springs) - 1

    # ----------------------------------------------------------------- joints
    def _joint_frame(self, what, parent, child, anchor, axis):
        """Body-local anchors and joint frames (x axis = ``axis``) of a joint
        defined in world coordinates at the build pose."""
        ip = self.body_index(parent, what)
        ic = self.body_index(child, what)
        if ip == ic:
            raise SceneError(f"{what}: parent and child are the same body {self.bodies[ip].name!r}")
        if self.bodies[ip].static and self.bodies[ic].static:
            raise SceneError(f"{what}: both bodies are static")
        p = self.bodies[ic].position if anchor is None else _vec(anchor, 3, what, "anchor")
        a = _vec(axis, 3, what, "axis")
        n = np.linalg.norm(a)
        if n < 1e-9:
            raise SceneError(f"{what}: axis has zero length")
        frame_world = frame_from_x_axis(a / n)
        fp = math3d.quat_mul(math3d.quat_conj(self.bodies[ip].orientation), frame_world)
        fc = math3d.quat_mul(math3d.quat_conj(self.bodies[ic].orientation), frame_world)
        return ip, ic, self._local_point(ip, p), self._local_point(ic, p), fp, fc

    def _joint_common(self, what, max_torque, n_axes, damping, stiffness, break_force, break_torque):
        if np.ndim(max_torque) == 0:
            mt = np.full(n_axes, _scalar(max_torque, what, "max_torque", minimum=0.0))
        else:
            mt = np.array(_vec(max_torque, n_axes, what, "max_torque"), dtype=float)
            if np.any(mt < 0):
                raise SceneError(f"{what}: max_torque must be >= 0 on every axis, got {max_torque!r}")
        return dict(
            max_torque=np.concatenate((mt, np.zeros(3 - n_axes))),
            damping=_scalar(damping, what, "damping", minimum=0.0),
            stiffness=_scalar(stiffness, what, "stiffness", minimum=0.0),
            break_force=_scalar(break_force, what, "break_force", minimum=0.0, allow_inf=True, strict=True),
            break_torque=_scalar(break_torque, what, "break_torque", minimum=0.0, allow_inf=True, strict=True),
        )

    def _range(self, what, name, value, lo_bound=-math.pi, hi_bound=math.pi):
        if value is None:
            return None
        r = _vec(value, 2, what, name)
        if r[0] > r[1]:
            raise SceneError(f"{what}: {name} has min {r[0]:g} > max {r[1]:g}")
        if r[0] < lo_bound - 1e-12 or r[1] > hi_bound + 1e-12:
            raise SceneError(f"{what}: {name} must lie within [{lo_bound:g}, {hi_bound:g}] rad, got {value!r}")
        return r

    @_undo_world_body_on_error
    def add_hinge(self, name: str, parent, child, anchor=None, axis=(0.0, 1.0, 0.0), limits=None,
                  max_torque: float = 0.0, damping: float = 0.0, stiffness: float = 0.0,
                  rest_angle: float = 0.0, break_force: float = math.inf, break_torque: float = math.inf,
                  collide_connected: bool = False) -> int:
        """A hinge (revolute joint, 1 DOF) about the world ``axis`` through the
        world point ``anchor`` (default: the child's centre).

        The angle is the child's rotation relative to the parent about the
        axis (right-hand rule), zero at the build pose; ``limits`` = (min, max)
        in radians within [-π, π]. max_torque (N·m) > 0 makes it actuated;
        damping (N·m·s/rad) and stiffness (N·m/rad, towards ``rest_angle``)
        are passive muscle tone (the spring pulls the short way round:
        ``rest_angle`` counts modulo 2π). Past ``break_force`` (N) or ``break_torque``
        (N·m) of constraint load the joint breaks. ``parent`` may be None for
        the fixed world.
        """
        what = f"joint {name!r}"
        self._check_name(self.joints, name, "joint")
        ip, ic, ap, ac, fp, fc = self._joint_frame(what, parent, child, anchor, axis)
        lim = self._range(what, "limits", limits)
        common = self._joint_common(what, max_torque, 1, damping, stiffness, break_force, break_torque)
        rest = _scalar(rest_angle, what, "rest_angle")
        self.joints.append(JointSpec(name, "hinge", ip, ic, ap, ac, fp, fc,
                                     limits={} if lim is None else {"angle": lim},
                                     rest_angles=np.array([rest, 0.0, 0.0]),
                                     collide_connected=bool(collide_connected), **common))
        return len(self.joints) - 1

    @_undo_world_body_on_error
    def add_ball(self, name: str, parent, child, anchor=None, twist_axis=(0.0, 0.0, 1.0),
                 swing_limits=None, twist_limits=None, max_torque=0.0, damping: float = 0.0,
                 stiffness: float = 0.0, break_force: float = math.inf, break_torque: float = math.inf,
                 collide_connected: bool = False) -> int:
        """A ball joint (3 DOF) at the world point ``anchor`` with a swing-twist limit.

        twist_axis: world direction of the twist axis (the joint frame's x);
        swing_limits: (cone_y, cone_z), half-angles in radians in (0, π) of an
        elliptic swing cone about the frame's y and z axes; twist_limits:
        (min, max) in radians within [-π, π], not enforced while the swing
        exceeds 150° (``joints.TWIST_LIMIT_MAX_SWING``: the twist is undefined
        at a swing of π). max_torque: one value or
        (twist, swing_y, swing_z) in N·m; passive damping and stiffness act on
        each axis towards the build pose.
        """
        what = f"joint {name!r}"
        self._check_name(self.joints, name, "joint")
        ip, ic, ap, ac, fp, fc = self._joint_frame(what, parent, child, anchor, twist_axis)
        limits = {}
        if swing_limits is not None:
            cone = _vec(swing_limits, 2, what, "swing_limits")
            if np.any(cone <= 0) or np.any(cone >= math.pi):
                raise SceneError(f"{what}: swing cone angles must lie in (0, π) rad, got {swing_limits!r}")
            limits["swing"] = cone
        tw = self._range(what, "twist_limits", twist_limits)
        if tw is not None:
            limits["twist"] = tw
        common = self._joint_common(what, max_torque, 3, damping, stiffness, break_force, break_torque)
        self.joints.append(JointSpec(name, "ball", ip, ic, ap, ac, fp, fc, limits=limits,
                                     collide_connected=bool(collide_connected), **common))
        return len(self.joints) - 1

    @_undo_world_body_on_error
    def add_fixed(self, name: str, parent, child, anchor=None, break_force: float = math.inf,
                  break_torque: float = math.inf, collide_connected: bool = False) -> int:
        """A fixed joint (0 DOF) holding the child's pose relative to the parent."""
        what = f"joint {name!r}"
        self._check_name(self.joints, name, "joint")
        ip, ic, ap, ac, fp, fc = self._joint_frame(what, parent, child, anchor, (1.0, 0.0, 0.0))
        common = self._joint_common(what, 0.0, 1, 0.0, 0.0, break_force, break_torque)
        self.joints.append(JointSpec(name, "fixed", ip, ic, ap, ac, fp, fc,
                                     collide_connected=bool(collide_connected), **common))
        return len(self.joints) - 1

    # ---------------------------------------------------------------- effects
    def enable(self, effect: str, **params) -> None:
        """Declare an effect the scene calls for.

        "gravity" (uniform, set by the builder's ``gravity``), "gravitation"
        (pairwise Newtonian attraction, ``G`` defaults to 6.6743e-11 and
        ``softening`` to 0 m), "damping", "contacts" (which, when first
        declared, brings "friction" and "restitution" with it, as
        ``add_ground`` does: drop either with ``disable`` afterwards),
        "friction", "restitution", "self_collision".
        Without "contacts" (or a ground) bodies pass through each other.
        """
        if effect not in DECLARABLE_EFFECTS:
            raise SceneError(
                f"unknown effect {effect!r}; effects a scene can declare: {list(DECLARABLE_EFFECTS)}"
            )
        if effect == "gravitation":
            g = _scalar(params.get("G", GRAVITATIONAL_CONSTANT), "effect 'gravitation'", "G",
                        minimum=0.0, strict=True)
            soft = _scalar(params.get("softening", 0.0), "effect 'gravitation'", "softening", minimum=0.0)
            unknown = set(params) - {"G", "softening"}
            if unknown:
                raise SceneError(f"effect 'gravitation': unknown parameters {sorted(unknown)}")
            params = {"G": g, "softening": soft}
        elif effect == "gravity" and self.gravity is None:
            self.gravity = (0.0, 0.0, -STANDARD_GRAVITY)
        elif params:
            raise SceneError(f"effect {effect!r} takes no parameters, got {sorted(params)}")
        if effect == "contacts" and "contacts" not in self.effects:
            # Contacts come with the materials' friction and restitution, as with
            # add_ground; disable("friction") or disable("restitution") afterwards drops one.
            for implied in ("friction", "restitution"):
                self.effects.setdefault(implied, {})
        self.effects[effect] = params

    def disable(self, effect: str) -> None:
        """Remove a declared effect (gravity, contacts, friction, restitution, ...).

        Effects implied by what the scene holds (springs, joints, joint limits,
        motors) are removed by leaving those items out; asking to disable one
        raises, rather than silently keeping it.
        """
        if effect not in ALL_EFFECTS:
            raise SceneError(f"unknown effect {effect!r}; effects: {list(ALL_EFFECTS)}")
        if effect not in DECLARABLE_EFFECTS:
            raise SceneError(
                f"effect {effect!r} is implied by the scene's items, not declared: build the scene "
                f"without them (no springs / joints / limits / max_torque) to drop it"
            )
        self.effects.pop(effect, None)
        if effect == "gravity":
            self.gravity = None

    # ------------------------------------------------------------------ build
    def build(self):
        """Validate and compile the scene into an immutable Model."""
        from .model import compile_model

        if not any(not b.static for b in self.bodies):
            raise SceneError("the scene has no dynamic body; add one with add_body()")
        try:
            self.settings.validate()
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        if self.gravity is not None:
            g = _vec(self.gravity, 3, "scene", "gravity")
            self.gravity = g
        # The model keeps a copy: later changes to this builder do not reach it
        # (nor its with_settings, nor humanoid.pose reading the scene through it).
        return compile_model(copy.deepcopy(self))
