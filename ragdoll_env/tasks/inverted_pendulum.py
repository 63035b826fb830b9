"""Ragdoll/InvertedPendulum-v0: one pole on a torque-limited hinge at its base.

Scene: a capsule pole (``pole_length`` 0.6 m long, ``pole_mass`` 5 kg, radius
0.03 m) standing on a hinge about +y fixed to the world at the origin. The
motor's maximum torque is ``torque_fraction`` x m g l_com (0.3 -> 4.41 N·m),
so it can hold the pole still only up to asin(torque_fraction) of tilt
(17.5°): a pole that has fallen further cannot be brought back.

Observation (float32, 2): [tilt θ (rad, > 0 leans the top towards +x), tilt rate θ̇ (rad/s)].
Action (1): base torque / max torque, in [-1, 1] (values outside are clipped).
Reward: ``reward_survive`` = alive_bonus (1) while healthy, ``reward_ctrl`` =
-ctrl_cost_weight (1e-3) · a²; the maximum return is 1 per step, 1000 over
the registered 1000 steps (up to the tiny control cost).
Termination: |θ| > ``healthy_angle`` (0.2 rad, as MuJoCo's InvertedPendulum).
Reset: θ and θ̇ uniform in ±reset_noise_scale (0.05 rad, rad/s).
Timing: dt 0.02 s x frame_skip 2 = 0.04 s per step (25 fps); 1000 steps = 40 s.
"""

from __future__ import annotations

import numpy as np

from engine import STANDARD_GRAVITY

from .base import Task, angle, ctrl_cost, nonneg, positive
from .chain import ChainTask, build_chain

RADIUS = 0.03


class InvertedPendulumTask(ChainTask, Task):
    env_id = "Ragdoll/InvertedPendulum-v0"
    params = {
        "pole_length": (0.6, positive),
        "pole_mass": (5.0, positive),
        "torque_fraction": (0.3, positive),
        "healthy_angle": (0.2, angle),
        "alive_bonus": (1.0, nonneg),
        "ctrl_cost_weight": (1e-3, nonneg),
    }
    links = ("pole",)
    dt = 0.02
    substeps = 4
    frame_skip = 2
    reset_noise_scale = 0.05
    push_bodies = ("pole",)
    push_interval = (1.0, 3.0)
    max_episode_steps = 1000
    camera = {"distance": 2.0, "elevation": 5.0, "azimuth": -90.0}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        if self.pole_length <= 2 * RADIUS:
            raise ValueError(f"pole_length must exceed {2 * RADIUS} m (the pole's diameter), got {self.pole_length}")
        self.max_torques = (self.torque_fraction * self.pole_mass * STANDARD_GRAVITY * 0.5 * self.pole_length,)

    @property
    def lengths(self):
        return [self.pole_length]

    def build(self, builder):
        build_chain(builder, self.links, self.lengths, [self.pole_mass], [RADIUS], self.max_torques, ["hinge"])

    def bind(self, model):
        super().bind(model)
        self._layout([("angle", 1, -np.pi, np.pi), ("angular_velocity", 1, -np.inf, np.inf)])

    def evaluate(self, model, state, action):
        q, _ = self.coordinates(model, state)
        healthy = np.abs(q[:, 0]) <= self.healthy_angle
        terms = {
            "reward_survive": self.alive_bonus * healthy,
            "reward_ctrl": -ctrl_cost(self.ctrl_cost_weight, action),
        }
        return healthy, terms, {}

    def camera_target(self, model, state):
        target = np.zeros((state.num_worlds, 3))
        target[:, 2] = 0.5 * self.pole_length
        return target

    @property
    def max_reward_per_step(self):
        return self.alive_bonus
