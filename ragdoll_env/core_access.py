"""Read-only shortcuts from an environment to its batched simulation core."""

from __future__ import annotations

import math


class CoreAccess:
    """Mixin for envs holding a :class:`ragdoll_env.batched.BatchedSim` as ``self.core``."""

    @property
    def task(self):
        return self.core.task

    @property
    def model(self):
        return self.core.model

    @property
    def state(self):
        return self.core.state

    @property
    def dt(self) -> float:
        """Seconds per environment step (engine dt × frame_skip)."""
        return self.core.dt

    @property
    def obs_layout(self) -> dict:
        """Observation component name -> slice."""
        return self.core.task.obs_layout

    @property
    def actuator_names(self) -> tuple:
        return self.core.actuator_names

    def _episode_steps(self):
        # None: the episodes are never truncated.
        return math.inf if self.core.max_episode_steps is None else self.core.max_episode_steps

    @property
    def max_reward_per_step(self) -> float:
        """The largest reward one step can give."""
        return self.core.task.max_reward_per_step

    @property
    def max_return(self) -> float:
        """Upper bound of an episode's return: the largest reward per step
        times the episode length (the single env: the task's registered
        length; for another length given to ``gym.make``, multiply
        ``max_reward_per_step`` by ``env.spec.max_episode_steps``)."""
        return self.core.task.max_reward_per_step * self._episode_steps()
