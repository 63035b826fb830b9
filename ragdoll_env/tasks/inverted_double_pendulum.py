"""Ragdoll/InvertedDoublePendulum-v0: two links on hinges, torques at both.

Scene: a standing body as two capsules (the ankle and hip strategies of
balance): ``legs`` (0.9 m, 30 kg, radius 0.06 m) on an ``ankle`` hinge about
+y fixed to the world, ``trunk`` (0.8 m, 45 kg, radius 0.1 m) on a ``hip``
hinge at the top of the legs. Maximum torques: ankle ``ankle_torque_fraction``
(0.25) x g Σ m_i h_i of the upright body (-> 176.5 N·m: it holds a rigid lean
of at most ~14°), hip ``hip_torque_fraction`` (1.0) x m_trunk g l_trunk / 2
(-> 176.5 N·m).

Observation (float32, 4): [θ_ankle, θ_hip, θ̇_ankle, θ̇_hip] (rad, rad/s);
θ_ankle is the legs' tilt, θ_hip the trunk's angle relative to the legs (> 0
leans the top towards +x).
Action (2): [ankle, hip] torque / max torque, in [-1, 1] (clipped).
Reward (MuJoCo InvertedDoublePendulum's terms, zeroed at upright):
``reward_survive`` = alive_bonus (10) while healthy;
``reward_distance`` = -(w_x x_tip² + w_z (z_tip - H)²), distance_weights (0.01, 1), H = 1.7 m upright;
``reward_velocity`` = -(v_1 θ̇_ankle² + v_2 θ̇_hip²), velocity_weights (1e-3, 5e-3);
``reward_ctrl`` = -ctrl_cost_weight (1e-2) · mean(a²).
All penalties vanish for a still, upright pendulum with zero torque, so the
maximum return is alive_bonus per step: 10 000 over the registered 1000 steps.
Termination: tip height below ``healthy_height_fraction`` (0.85) x H, or
|θ_ankle| or the trunk's absolute tilt |θ_ankle + θ_hip| above ``healthy_tilt`` (0.5 rad).
Reset: both angles and rates uniform in ±reset_noise_scale (0.05).
Timing: dt 0.02 s x frame_skip 2 = 0.04 s per step (25 fps).
"""

from __future__ import annotations

import numpy as np

from engine import STANDARD_GRAVITY

from .base import Task, angle, ctrl_cost, fraction, nonneg, nonneg_pair, positive
from .chain import ChainTask, build_chain

RADII = (0.06, 0.1)


class InvertedDoublePendulumTask(ChainTask, Task):
    env_id = "Ragdoll/InvertedDoublePendulum-v0"
    params = {
        "leg_length": (0.9, positive),
        "trunk_length": (0.8, positive),
        "leg_mass": (30.0, positive),
        "trunk_mass": (45.0, positive),
        "ankle_torque_fraction": (0.25, positive),
        "hip_torque_fraction": (1.0, positive),
        "healthy_height_fraction": (0.85, fraction),
        "healthy_tilt": (0.5, angle),
        "alive_bonus": (10.0, nonneg),
        "distance_weights": ((0.01, 1.0), nonneg_pair),
        "velocity_weights": ((1e-3, 5e-3), nonneg_pair),
        "ctrl_cost_weight": (1e-2, nonneg),
    }
    links = ("legs", "trunk")
    dt = 0.02
    substeps = 4
    frame_skip = 2
    reset_noise_scale = 0.05
    push_bodies = ("trunk",)
    max_episode_steps = 1000
    camera = {"distance": 4.0, "elevation": 5.0, "azimuth": -90.0}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name, length, r in (("leg_length", self.leg_length, RADII[0]),
                                ("trunk_length", self.trunk_length, RADII[1])):
            if length <= 2 * r:
                raise ValueError(f"{name} must exceed {2 * r} m (the link's diameter), got {length}")
        g = STANDARD_GRAVITY
        mgh = g * (self.leg_mass * 0.5 * self.leg_length
                   + self.trunk_mass * (self.leg_length + 0.5 * self.trunk_length))
        self.max_torques = (self.ankle_torque_fraction * mgh,
                            self.hip_torque_fraction * self.trunk_mass * g * 0.5 * self.trunk_length)
        self.height = self.leg_length + self.trunk_length

    @property
    def lengths(self):
        return [self.leg_length, self.trunk_length]

    def build(self, builder):
        build_chain(builder, self.links, self.lengths, [self.leg_mass, self.trunk_mass], list(RADII),
                    list(self.max_torques), ["ankle", "hip"])

    def bind(self, model):
        super().bind(model)
        self._layout([("angles", 2, -np.pi, np.pi), ("angular_velocities", 2, -np.inf, np.inf)])

    def evaluate(self, model, state, action):
        q, qd = self.coordinates(model, state)
        tip = self.tip(model, state)
        healthy = ((tip[:, 2] >= self.healthy_height_fraction * self.height)
                   & (np.abs(q[:, 0]) <= self.healthy_tilt) & (np.abs(q[:, 0] + q[:, 1]) <= self.healthy_tilt))
        wx, wz = self.distance_weights
        v1, v2 = self.velocity_weights
        terms = {
            "reward_survive": self.alive_bonus * healthy,
            "reward_distance": -(wx * tip[:, 0] ** 2 + wz * (tip[:, 2] - self.height) ** 2),
            "reward_velocity": -(v1 * qd[:, 0] ** 2 + v2 * qd[:, 1] ** 2),
            "reward_ctrl": -ctrl_cost(self.ctrl_cost_weight, action),
        }
        return healthy, terms, {"tip_x": tip[:, 0], "tip_z": tip[:, 2]}

    def camera_target(self, model, state):
        target = np.zeros((state.num_worlds, 3))
        target[:, 2] = 0.5 * self.height
        return target

    @property
    def max_reward_per_step(self):
        return self.alive_bonus
