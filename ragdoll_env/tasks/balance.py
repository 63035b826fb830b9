"""Ragdoll/Balance-v0: keep the humanoid standing on the ground through random pushes.

Scene: a ground plane and :func:`engine.humanoid.add_humanoid` (14 bones, 13
joints, 31 actuated joint axes at the default strengths), standing with its
soles on the ground, facing +x.

Action (31): torque / max torque on every actuated joint axis, in the order of
``model.actuators`` (``env.unwrapped.actuator_names``), in [-1, 1] (clipped).

Observation (float32, 81), names and slices in ``env.unwrapped.obs_layout``:

=======================  ====  ==========================================================
pelvis_height               1  z of the pelvis centre above the ground, m
pelvis_orientation          4  pelvis quaternion (w, x, y, z), sign chosen so w >= 0
pelvis_velocity             3  world frame, m/s
pelvis_angular_velocity     3  world frame, rad/s
joint_angles               31  per actuated axis: hinge angle or (twist, swing_y, swing_z) component, rad
joint_velocities           31  per actuated axis: child-minus-parent angular velocity in the joint frame, rad/s
com_from_feet               3  centre of mass minus the midpoint of the two foot centres, world frame, m
com_velocity                3  centre-of-mass velocity, m/s
foot_contacts               2  1.0 where foot_l / foot_r touches the ground (0 while the engine has no contacts)
=======================  ====  ==========================================================

Healthy while the pelvis centre is above ``healthy_pelvis_height`` (0.6 m),
the head centre above ``healthy_head_height`` (1.05 m; standing: 1.0 and 1.61 m)
and no body but the feet touches the ground or another static body (read
from ``model.contacts.touching_static`` once the engine has contacts). The
episode terminates when unhealthy.

Reward terms (``info``), paid while healthy except the control cost:
``reward_survive`` = alive_bonus (1);
``reward_upright`` = upright_weight (0.5) x the z component of the chest's up axis (clipped to [0, 1]);
``reward_height`` = height_weight (0.5) x head height / standing head height (clipped to [0, 1]);
``reward_capture`` = capture_weight (1) x exp(-(d / capture_scale)²), d the horizontal distance (m)
from the capture point ξ = c + ċ / ω (c, ċ the centre of mass and its velocity, ω = √(g / h), h the
height of c above the foot centres, at least 0.05 m;
Pratt et al. 2006, "Capture point: a step toward humanoid push recovery") to the midpoint of the
feet, capture_scale 0.1 m: 1 with the body balanced over its feet, falling off as a push or a lean
carries the point the body would have to step to away from them (the standing pose: 0.6);
``reward_ctrl`` = -ctrl_cost_weight (0.1) x mean(a²).
At most 3 per step: 3600 over the registered 20 s (1200 steps).

Pushes (core keyword arguments): ``push_strength`` (5, 20) N·s, every
``push_interval`` (2, 4) s, at the centre of one of ``push_bodies``
("chest", "pelvis"), in a uniformly random horizontal direction.
Timing: dt 1/60 s x frame_skip 1 = 1/60 s per step (60 Hz control, about
MuJoCo Humanoid-v5's 67 Hz). A torque held for a whole step is an explicit
PD on the light bones (a 1 kg foot, an 8 kg pelvis), which oscillates once
kd·Δt/I or kp·Δt²/I is too large: at 30 Hz the standing PD could not be
stiff enough, and under the default pushes it fell in 11 of 20 episodes
(and in 9 at 60 Hz with the same gains); tuned for 60 Hz it fell in 6 of 120
in push trials (9 of 120 with the engine of 2026-12-03: 2, 4 and 3 of 40) and
in 12 of 100 in a 100-episode ``training.evaluate``; at the engine's rigid-joint
defaults of 2026-12-04, in 15 of 320 (eight seed sets of 40); since its
lifted-foot ankle gains (2026-12-05), in 12 of the same 320 (21 at the old
gains with that day's engine).
Reset: every joint angle component + uniform ±reset_noise_scale (0.02 rad,
clipped to the limits), soles lowered onto the ground, whole-body horizontal
velocity uniform ±reset_noise_scale m/s.
"""

from __future__ import annotations

import warnings

import numpy as np

from engine import math3d
from engine.diagnostics import center_of_mass
from engine.humanoid import add_humanoid, pose, standing_pose
from engine.shapes import BOX, CAPSULE, SPHERE

from .base import Task, ctrl_cost, nonneg, positive, boolean

_EZ = np.array([0.0, 0.0, 1.0])


def lowest_points(model, positions, orientations, bodies):
    """Lowest z (m) of each of ``bodies``' shapes at the given poses (N, 3), (N, 4)."""
    out = []
    for i in bodies:
        code, p = model.shape_type[i], model.shape_params[i]
        x, q = positions[i], orientations[i]
        if code == SPHERE:
            out.append(x[2] - p[0])
        elif code == CAPSULE:
            axis = math3d.quat_rotate(q, _EZ) * p[1]
            out.append(x[2] - abs(axis[2]) - p[0])
        elif code == BOX:
            r = math3d.quat_to_matrix(q)
            out.append(x[2] - float(np.abs(r[2]) @ p))
    return np.array(out)


def touching_static(model, state):
    """(W, N) bool from the engine's contacts, or all False while it has none."""
    contacts = getattr(model, "contacts", None)
    fn = getattr(contacts, "touching_static", None)
    if fn is None:
        return np.zeros((state.num_worlds, model.num_bodies), dtype=bool)
    return np.asarray(fn(state), dtype=bool)


class BalanceTask(Task):
    env_id = "Ragdoll/Balance-v0"
    params = {
        "height": (1.75, positive),
        "mass": (75.0, positive),
        "torque_scale": (1.0, positive),
        "joint_damping": (1.0, nonneg),
        "healthy_pelvis_height": (0.6, nonneg),
        "healthy_head_height": (1.05, nonneg),
        "terminate_on_contact": (True, boolean),
        "alive_bonus": (1.0, nonneg),
        "upright_weight": (0.5, nonneg),
        "height_weight": (0.5, nonneg),
        "capture_weight": (1.0, nonneg),
        "capture_scale": (0.1, positive),
        "ctrl_cost_weight": (0.1, nonneg),
    }
    dt = 1.0 / 60.0
    substeps = 4
    frame_skip = 1
    reset_noise_scale = 0.02
    push_strength = (5.0, 20.0)
    push_interval = (2.0, 4.0)
    push_bodies = ("chest", "pelvis")
    push_recovery_time = 1.0
    max_episode_steps = 1200  # 20 s at the default 1/60 s per step
    camera = {"distance": 4.0, "elevation": 10.0, "azimuth": -70.0}
    _warned = False

    def build(self, builder):
        builder.add_ground()
        self.humanoid = add_humanoid(builder, height=self.height, mass=self.mass, torque_scale=self.torque_scale,
                                     damping=self.joint_damping)

    def bind(self, model):
        super().bind(model)
        h = self.humanoid
        idx = {part: model.body_index(h.name(part)) for part in h.bodies}
        self.body = idx
        self.pelvis, self.chest, self.head = idx["pelvis"], idx["chest"], idx["head"]
        self.feet = np.array([idx[f] for f in h.feet])
        self.humanoid_bodies = np.array(sorted(idx.values()))
        allowed = np.zeros(model.num_bodies, dtype=bool)
        allowed[self.feet] = True
        self.forbidden_contact = np.zeros(model.num_bodies, dtype=bool)
        self.forbidden_contact[self.humanoid_bodies] = True
        self.forbidden_contact &= ~allowed
        self.act_joint = np.array([a.joint for a in model.actuators], dtype=np.int64)
        self.act_axis = np.array([a.axis for a in model.actuators], dtype=np.int64)
        self.actuator_names = tuple(a.name for a in model.actuators)
        init = model.initial_state(1)
        self.standing_pelvis_height = float(init.position[0, self.pelvis, 2])
        self.standing_head_height = float(init.position[0, self.head, 2])
        self.contacts_available = getattr(getattr(model, "contacts", None), "touching_static", None) is not None
        if not self.contacts_available and not BalanceTask._warned:
            BalanceTask._warned = True
            warnings.warn("Balance-v0: the engine has no contact model yet (model.contacts is None), so the "
                          "humanoid falls through the ground and foot_contacts read 0", stacklevel=3)
        A = model.num_actuators
        self._layout([
            ("pelvis_height", 1, -np.inf, np.inf),
            ("pelvis_orientation", 4, -1.0, 1.0),
            ("pelvis_velocity", 3, -np.inf, np.inf),
            ("pelvis_angular_velocity", 3, -np.inf, np.inf),
            ("joint_angles", A, -np.pi, np.pi),
            ("joint_velocities", A, -np.inf, np.inf),
            ("com_from_feet", 3, -np.inf, np.inf),
            ("com_velocity", 3, -np.inf, np.inf),
            ("foot_contacts", 2, 0.0, 1.0),
        ])
        # joint-angle limits for the reset noise
        self._joint_names = list(h.joint_kinds)

    # ------------------------------------------------------------ reset
    def reset_world(self, model, rng, noise):
        h = self.humanoid
        angles = standing_pose(h)
        for name in self._joint_names:
            kind, lim = h.joint_kinds[name], h.limits[name]
            if kind == "hinge":
                lo, hi = lim.get("angle", (-np.pi, np.pi))
                angles[name] = float(np.clip(rng.uniform(-noise, noise), lo, hi))
            else:
                d = rng.uniform(-noise, noise, size=3)
                lo, hi = lim.get("twist", (-np.pi, np.pi))
                d[0] = np.clip(d[0], lo, hi)
                angles[name] = tuple(float(v) for v in d)
        return self.pose_on_ground(model, angles, velocity=(*rng.uniform(-noise, noise, size=2), 0.0))

    def pose_on_ground(self, model, angles, velocity=(0.0, 0.0, 0.0)):
        """Pose dict (see :meth:`Task.reset_world`) of the humanoid at joint
        ``angles`` (``engine.humanoid.pose`` format), lowered until its lowest
        point touches the ground, every body moving with ``velocity`` (m/s)."""
        pos, quat = pose(self.humanoid, model, angles)
        pos = pos.copy()
        lowest = lowest_points(model, pos, quat, self.humanoid_bodies).min()
        pos[self.humanoid_bodies, 2] -= lowest
        n = model.num_bodies
        vel = np.zeros((n, 3))
        vel[self.humanoid_bodies] = np.asarray(velocity, dtype=float)
        return {"position": pos, "orientation": quat, "velocity": vel, "angular_velocity": np.zeros((n, 3))}

    # ------------------------------------------------------------ observe
    def joint_state(self, model, state):
        """Angles and rates (W, A) of the actuated axes."""
        ang = model.joints.angles(state)[:, self.act_joint, self.act_axis]
        rate = model.joints.relative_angular_velocity(state)[:, self.act_joint, self.act_axis]
        return ang, rate

    def com(self, model, state):
        m = np.where(model.dynamic, model.mass, 0.0)
        com = center_of_mass(model, state)
        com_vel = (m[:, None] * state.velocity).sum(axis=1) / m.sum()
        return com, com_vel

    def observe(self, model, state):
        p = self.pelvis
        q = state.orientation[:, p]
        q = np.clip(np.where(q[:, :1] < 0, -q, q), -1.0, 1.0)
        ang, rate = self.joint_state(model, state)
        com, com_vel = self.com(model, state)
        feet_mid = 0.5 * (state.position[:, self.feet[0]] + state.position[:, self.feet[1]])
        contacts = touching_static(model, state)[:, self.feet].astype(np.float64)
        return np.concatenate([
            state.position[:, p, 2:3], q, state.velocity[:, p], state.angular_velocity[:, p],
            ang, rate, com - feet_mid, com_vel, contacts,
        ], axis=-1)

    def evaluate(self, model, state, action):
        pelvis_z = state.position[:, self.pelvis, 2]
        head_z = state.position[:, self.head, 2]
        touching = touching_static(model, state)
        bad_contact = (touching & self.forbidden_contact).any(axis=1)
        healthy = (pelvis_z >= self.healthy_pelvis_height) & (head_z >= self.healthy_head_height)
        if self.terminate_on_contact:
            healthy &= ~bad_contact
        up = math3d.quat_rotate(state.orientation[:, self.chest], np.broadcast_to(_EZ, (state.num_worlds, 3)))
        upright = np.clip(up[:, 2], 0.0, 1.0)
        tall = np.clip(head_z / self.standing_head_height, 0.0, 1.0)
        com, com_vel = self.com(model, state)
        feet_mid = 0.5 * (state.position[:, self.feet[0]] + state.position[:, self.feet[1]])
        d = com[:, :2] - feet_mid[:, :2]
        capture_rel = self.capture_offset(model, com, com_vel, feet_mid)  # ξ - feet midpoint
        capture = np.exp(-(capture_rel[:, 0] ** 2 + capture_rel[:, 1] ** 2) / self.capture_scale ** 2)
        terms = {
            "reward_survive": self.alive_bonus * healthy,
            "reward_upright": self.upright_weight * upright * healthy,
            "reward_height": self.height_weight * tall * healthy,
            "reward_capture": self.capture_weight * capture * healthy,
            "reward_ctrl": -ctrl_cost(self.ctrl_cost_weight, action),
        }
        info = {
            "pelvis_height": pelvis_z,
            "head_height": head_z,
            "com_offset": np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2),
            "capture_offset": np.sqrt(capture_rel[:, 0] ** 2 + capture_rel[:, 1] ** 2),
            "foot_contacts": touching[:, self.feet],
            "other_contact": bad_contact,
        }
        return healthy, terms, info

    @staticmethod
    def capture_offset(model, com, com_vel, feet_mid):
        """(W, 2) horizontal capture point minus the feet midpoint, m: c + ċ/ω,
        ω = √(g / height of c above the feet) (linear inverted pendulum)."""
        g = 9.81 if model.gravity is None else float(np.linalg.norm(model.gravity))
        h = np.maximum(com[:, 2] - feet_mid[:, 2], 0.05)
        omega = np.sqrt(g / h)
        return com[:, :2] - feet_mid[:, :2] + com_vel[:, :2] / omega[:, None]

    def camera_target(self, model, state):
        com, _ = self.com(model, state)
        com[:, 2] = np.clip(com[:, 2], 0.3, 1.0)
        return com

    @property
    def max_reward_per_step(self):
        return self.alive_bonus + self.upright_weight + self.height_weight + self.capture_weight
