"""Helpers shared by the environment tests (imported by name: tests/ has no packages)."""

import gymnasium as gym
import numpy as np

import ragdoll_env  # noqa: F401  (registers the ids)

PENDULUMS = ("Ragdoll/InvertedPendulum-v0", "Ragdoll/InvertedDoublePendulum-v0")
ALL_IDS = PENDULUMS + ("Ragdoll/Balance-v0",)

#: cheap engine settings for Balance in tests that check plumbing, not physics
FAST_BALANCE = {"substeps": 1, "frame_skip": 1}


def fast_kwargs(env_id):
    return dict(FAST_BALANCE) if env_id.endswith("Balance-v0") else {}


def random_actions(seed, steps, shape):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.2, 1.2, size=(steps,) + tuple(shape)).astype(np.float32)


def make(env_id, **kwargs):
    return gym.make(env_id, **{**fast_kwargs(env_id), **kwargs})
