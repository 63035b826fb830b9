"""The compiled, immutable description of a scene (as MuJoCo's mjModel, Brax's System).

``compile_model`` turns a :class:`SceneBuilder` into index and parameter
arrays and the list of effects the scene calls for; stepping is then only
array arithmetic. Arrays on the model are read-only.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from .core.effects import compile_effects
from .effects.damping import Damping
from .effects.gravitation import Gravitation
from .effects.gravity import Gravity
from .effects.springs import Springs
from .errors import SceneError
from .shapes import NONE
from .state import State


def _readonly(arr):
    arr = np.ascontiguousarray(arr)
    arr.flags.writeable = False
    return arr


class Model:
    """Immutable scene: bodies, springs, joints, effects and settings.

    Body arrays (N = number of bodies, static ones included):
    ``mass`` (kg, inf for static), ``inv_mass`` (1/kg, 0 for static),
    ``inertia`` (N, 3) principal moments in kg·m² (body frame = principal
    frame), ``inv_inertia`` (0 for static), ``dynamic`` (bool), ``shape_type``
    and ``shape_params`` (see :mod:`engine.shapes`). ``effect_arrays``: the
    bodies', effects' and motors' arrays the integration kernels read
    (:func:`engine.core.effects.compile_effects`).
    """

    def __init__(self, builder):
        self._builder = builder
        self.settings = builder.settings
        bodies = builder.bodies
        self.body_names = tuple(b.name for b in bodies)
        self.num_bodies = len(bodies)
        self.dynamic = _readonly(np.array([not b.static for b in bodies]))
        self.mass = _readonly(np.array([b.mass for b in bodies], dtype=float))
        self.inv_mass = _readonly(np.where(self.dynamic, 1.0 / np.where(self.dynamic, self.mass, 1.0), 0.0))
        inertia = np.array([b.inertia for b in bodies], dtype=float).reshape(-1, 3)
        for b, row in zip(bodies, inertia):
            if not b.static and not np.all(row > 0):
                raise SceneError(f"body {b.name!r}: inertia must be positive, got {row}")
        self.inertia = _readonly(inertia)
        safe = np.where(self.dynamic[:, None], inertia, 1.0)
        self.inertia_safe = _readonly(safe)  # static bodies: 1, to divide by safely
        self.inv_inertia = _readonly(np.where(self.dynamic[:, None], 1.0 / safe, 0.0))
        self.shape_type = _readonly(np.array(
            [NONE if b.shape is None else b.shape.type_code for b in bodies], dtype=np.int64))
        self.shapes = tuple(b.shape for b in bodies)
        self.shape_params = _readonly(np.array(
            [np.zeros(3) if b.shape is None else b.shape.params() for b in bodies], dtype=float).reshape(-1, 3))
        self.body_material = tuple(b.material for b in bodies)
        self.materials = builder.materials
        self.gravity = None if builder.gravity is None else _readonly(np.asarray(builder.gravity, dtype=float))

        # Effects the scene calls for, each compiled to its own arrays.
        fx = builder.effects
        self.effects = {}
        if "gravity" in fx and self.gravity is not None:
            self.effects["gravity"] = Gravity(self.gravity, self.dynamic)
        if "gravitation" in fx:
            p = fx["gravitation"]
            self.effects["gravitation"] = Gravitation(p["G"], p["softening"], self.mass, self.dynamic)
        if builder.springs:
            self.effects["springs"] = Springs(builder.springs, self.mass, self.dynamic, self.inv_mass,
                                              self.settings.substep_dt)
        lin = np.array([b.linear_damping for b in bodies])
        ang = np.array([b.angular_damping for b in bodies])
        if "damping" in fx and (lin.any() or ang.any()):
            self.effects["damping"] = Damping(lin, ang)
        self.spring_names = tuple(s.name for s in builder.springs)
        self.num_springs = len(builder.springs)

        # Joints and contacts are compiled by their own modules.
        from .joints import compile_joints

        self.joints = compile_joints(self, builder)
        self.joint_names = () if self.joints is None else self.joints.names
        self.num_joints = len(self.joint_names)
        self.actuators = () if self.joints is None else self.joints.actuators
        self.num_actuators = len(self.actuators)
        from .contacts import compile_contacts

        self.contacts = compile_contacts(self, builder)

        # The bodies', effects' and motors' arrays for the integration kernels, once.
        self.effect_arrays = compile_effects(self)
        self.end_hooks = tuple(e for e in self.effects.values() if getattr(e, "end_of_step", None))

        self._initial = {
            "position": np.array([b.position for b in bodies], dtype=float).reshape(-1, 3),
            "orientation": np.array([b.orientation for b in bodies], dtype=float).reshape(-1, 4),
            "velocity": np.array([b.velocity for b in bodies], dtype=float).reshape(-1, 3),
            "angular_velocity": np.array([b.angular_velocity for b in bodies], dtype=float).reshape(-1, 3),
        }
        for v in self._initial.values():
            v.flags.writeable = False

    # ------------------------------------------------------------------ naming
    @property
    def effect_names(self) -> tuple[str, ...]:
        """Effects compiled into this model's step, in no particular order."""
        names = set(self.effects)
        if self.joints is not None:
            names |= self.joints.effect_names
        if self.contacts is not None:
            names |= self.contacts.effect_names
        return tuple(sorted(names))

    def body_index(self, body) -> int:
        if isinstance(body, str):
            try:
                return self.body_names.index(body)
            except ValueError:
                raise KeyError(f"no body named {body!r}; bodies: {list(self.body_names)}") from None
        i = int(body)
        if not 0 <= i < self.num_bodies:
            raise KeyError(f"no body {body} (there are {self.num_bodies})")
        return i

    # ------------------------------------------------------------------- state
    def initial_state(self, num_worlds: int = 1) -> State:
        """W copies of the scene's initial pose, as a batched State."""
        if not isinstance(num_worlds, (int, np.integer)) or num_worlds < 1:
            if not (isinstance(num_worlds, float) and num_worlds.is_integer() and num_worlds >= 1):
                raise ValueError(f"num_worlds must be an integer >= 1, got {num_worlds!r}")
        W = int(num_worlds)
        arrays = {k: np.repeat(v[None], W, axis=0) for k, v in self._initial.items()}
        arrays["step"] = np.zeros(W, dtype=np.int64)
        arrays["spring_broken"] = np.zeros((W, self.num_springs), dtype=bool)
        if self.joints is not None:
            arrays.update(self.joints.initial_arrays(W))
        if self.contacts is not None:
            arrays.update(self.contacts.initial_arrays(W))
        return State(arrays)

    def reset_worlds(self, state: State, worlds, source: State | None = None) -> None:
        """Reset ``worlds`` of ``state`` in place to the initial pose (or to
        ``source``, a state of one world or of as many worlds as selected)."""
        state.assign(worlds, self.initial_state(1) if source is None else source)

    def time(self, state: State) -> np.ndarray:
        """Simulated seconds per world."""
        return state.step * self.settings.dt

    def with_settings(self, **changes) -> "Model":
        """The same scene compiled with other settings (dt, substeps, ...)."""
        b = copy.deepcopy(self._builder)
        b.settings = replace(self.settings, **changes)
        return b.build()

    def __repr__(self):
        return (f"Model({self.num_bodies} bodies, {self.num_joints} joints, {self.num_springs} springs, "
                f"effects={list(self.effect_names)}, dt={self.settings.dt:g}, substeps={self.settings.substeps})")


def compile_model(builder) -> Model:
    return Model(builder)
