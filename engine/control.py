"""Per-step inputs from outside the scene: motor torques and applied forces.

Every array has the leading world axis. Inputs are checked before they touch
the state: a wrong shape, NaN or infinity raises ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .math3d import cross
from .state import world_index


@dataclass
class Control:
    """Inputs for one step of W worlds.

    motor: (W, A) torques in N·m, one per actuated joint axis (the model's
        ``actuators``), clamped to each axis's maximum torque.
    force: (W, N, 3) world-frame forces in N applied at the body centres.
    torque: (W, N, 3) world-frame torques in N·m.
    """

    motor: np.ndarray | None = None
    force: np.ndarray | None = None
    torque: np.ndarray | None = None

    @classmethod
    def zeros(cls, model, num_worlds, motor=True, force=False):
        return cls(
            motor=np.zeros((num_worlds, model.num_actuators)) if motor else None,
            force=np.zeros((num_worlds, model.num_bodies, 3)) if force else None,
            torque=np.zeros((num_worlds, model.num_bodies, 3)) if force else None,
        )

    def worlds(self, lo: int, hi: int) -> Control:
        """The inputs of worlds [lo, hi) (views where the inputs are arrays)."""
        return Control(*(None if a is None else np.asarray(a)[lo:hi] for a in (self.motor, self.force, self.torque)))

    def add_force_at_point(self, model, body, force, point, positions):
        """Add a world-frame force (N) at a world point (m) on ``body``:
        a force at the centre plus the torque (p - x) × F.

        force, point: (W, 3); positions: the state's (W, N, 3) positions.
        """
        i = model.body_index(body)
        W = positions.shape[0]
        if self.force is None:
            self.force = np.zeros((W, model.num_bodies, 3))
        if self.torque is None:
            self.torque = np.zeros((W, model.num_bodies, 3))
        force = np.broadcast_to(np.asarray(force, dtype=float), (W, 3))
        point = np.broadcast_to(np.asarray(point, dtype=float), (W, 3))
        self.force[:, i] += force
        self.torque[:, i] += cross(point - positions[:, i], force)

    def validate(self, model, num_worlds):
        """Raise ValueError for a wrong shape or a non-finite entry."""
        expected = {
            "motor": (num_worlds, model.num_actuators),
            "force": (num_worlds, model.num_bodies, 3),
            "torque": (num_worlds, model.num_bodies, 3),
        }
        for name, shape in expected.items():
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value)
            if arr.shape != shape:
                raise ValueError(f"control.{name} must have shape {shape}, got {arr.shape}")
            if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
                kind = "complex" if np.issubdtype(arr.dtype, np.complexfloating) else "not numeric"
                raise ValueError(f"control.{name} must be real numeric values, got {kind} dtype {arr.dtype}")
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0]
                raise ValueError(f"control.{name} has a NaN or infinite entry at index {tuple(int(i) for i in bad)}")


def apply_impulse(model, state, body, impulse, point=None, worlds=None):
    """Apply an instantaneous world-frame impulse (N·s) to ``body`` at a world
    ``point`` (m; default the body's centre), in the selected worlds.

    impulse, point: (3,) or (W, 3). Velocities change by Δv = J/m and
    Δω = I_w⁻¹ ((p - x) × J). A push in the environments is one of these.
    """
    from .math3d import quat_rotate, quat_rotate_inv

    i = model.body_index(body)
    W = state.num_worlds
    J = _per_world_vector("impulse", impulse, W).copy()
    if not np.all(np.isfinite(J)):
        raise ValueError("impulse has a NaN or infinite entry")
    if worlds is not None:
        idx = world_index(worlds, W)  # indices, slice or boolean mask, as State.select
        mask = np.zeros(W, dtype=bool)
        mask[idx] = True
        J[~mask] = 0.0
    x = state.position[:, i]
    p = x if point is None else _per_world_vector("impulse point", point, W)
    if not np.all(np.isfinite(p)):
        raise ValueError("impulse point has a NaN or infinite entry")
    state.velocity[:, i] += J * model.inv_mass[i]
    q = state.orientation[:, i]
    state.angular_velocity[:, i] += quat_rotate(q, model.inv_inertia[i] * quat_rotate_inv(q, cross(p - x, J)))


def _per_world_vector(name, value, num_worlds):
    """A (W, 3) float array from a 3-vector or a (W, 3) array, or a ValueError naming ``name``."""
    arr = np.asarray(value, dtype=float)
    if arr.shape not in ((3,), (num_worlds, 3)):
        raise ValueError(f"{name} must have shape (3,) or ({num_worlds}, 3), got {arr.shape}")
    return np.broadcast_to(arr, (num_worlds, 3))
