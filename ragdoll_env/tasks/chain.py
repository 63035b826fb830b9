"""A planar chain of capsule links on hinges about +y, standing on a hinge
fixed to the world: the scene of both inverted pendulums.

Angles are the engine's hinge angles (right hand about +y): a positive angle
tilts the link's top towards +x. Link k's absolute tilt is the sum of the
hinge angles up to it.
"""

from __future__ import annotations

import numpy as np

from engine import Capsule

AXIS = np.array([0.0, 1.0, 0.0])


def build_chain(builder, names, lengths, masses, radii, max_torques, joint_names, damping=0.0):
    """Links named ``names`` from the origin upwards, joined by hinges about +y
    (the first to the world), each with its ``max_torque`` (N·m)."""
    z = 0.0
    parent = None
    for name, length, mass, radius, torque, joint in zip(names, lengths, masses, radii, max_torques, joint_names):
        half = 0.5 * length - radius
        builder.add_body(name, Capsule(radius, half), mass=mass, position=(0.0, 0.0, z + 0.5 * length))
        builder.add_hinge(joint, parent, name, anchor=(0.0, 0.0, z), axis=tuple(AXIS), max_torque=torque,
                          damping=damping)
        parent = name
        z += length


def chain_pose(lengths, angles, rates):
    """Centres, orientations, velocities and angular velocities (K, ...) of
    the K links for hinge ``angles`` (K,) rad and ``rates`` (K,) rad/s."""
    lengths = np.asarray(lengths, dtype=float)
    tilt = np.cumsum(angles)
    omega = np.cumsum(rates)
    k = len(lengths)
    pos = np.zeros((k, 3))
    vel = np.zeros((k, 3))
    base = np.zeros(3)
    base_vel = np.zeros(3)
    for i in range(k):
        up = np.array([np.sin(tilt[i]), 0.0, np.cos(tilt[i])])
        d_up = omega[i] * np.array([np.cos(tilt[i]), 0.0, -np.sin(tilt[i])])
        pos[i] = base + 0.5 * lengths[i] * up
        vel[i] = base_vel + 0.5 * lengths[i] * d_up
        base = base + lengths[i] * up
        base_vel = base_vel + lengths[i] * d_up
    quat = np.stack([np.cos(0.5 * tilt), np.zeros(k), np.sin(0.5 * tilt), np.zeros(k)], axis=-1)
    angvel = omega[:, None] * AXIS
    return pos, quat, vel, angvel


def chain_tip(lengths, angles):
    """(W, 3) position of the top of the last link for angles (W, K)."""
    tilt = np.cumsum(angles, axis=-1)
    x = (np.asarray(lengths) * np.sin(tilt)).sum(axis=-1)
    z = (np.asarray(lengths) * np.cos(tilt)).sum(axis=-1)
    return np.stack((x, np.zeros_like(x), z), axis=-1)


class ChainTask:
    """Mixin for tasks on a hinge chain: ``links`` and ``lengths`` name the
    links bottom-up; observations are the hinge angles and rates."""

    links: tuple = ()

    @property
    def lengths(self):
        raise NotImplementedError

    def _pose_dict(self, model, pos, quat, vel, angvel):
        n = model.num_bodies
        out = {"position": np.zeros((n, 3)), "orientation": np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
               "velocity": np.zeros((n, 3)), "angular_velocity": np.zeros((n, 3))}
        for k, name in enumerate(self.links):
            i = model.body_index(name)
            out["position"][i], out["orientation"][i] = pos[k], quat[k]
            out["velocity"][i], out["angular_velocity"][i] = vel[k], angvel[k]
        return out

    def reset_world(self, model, rng, noise):
        k = len(self.links)
        angles = rng.uniform(-noise, noise, size=k)
        rates = rng.uniform(-noise, noise, size=k)
        return self._pose_dict(model, *chain_pose(self.lengths, angles, rates))

    def coordinates(self, model, state):
        """Hinge angles (W, K) in rad and rates (W, K) in rad/s."""
        return model.joints.angles(state)[..., 0], model.joints.relative_angular_velocity(state)[..., 0]

    def set_coordinates(self, model, state, worlds, angles, rates):
        """Write hinge angles and rates (len(worlds), K) into ``worlds`` of
        ``state`` (the LQR baseline linearises the engine this way)."""
        for w, a, r in zip(np.atleast_1d(worlds), np.atleast_2d(angles), np.atleast_2d(rates)):
            for key, value in self._pose_dict(model, *chain_pose(self.lengths, a, r)).items():
                state.arrays[key][w] = value

    def observe(self, model, state):
        q, qd = self.coordinates(model, state)
        return np.concatenate((q, qd), axis=-1)

    def tip(self, model, state):
        """(W, 3) top of the last link, m."""
        q, _ = self.coordinates(model, state)
        return chain_tip(self.lengths, q)
