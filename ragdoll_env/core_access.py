"""Read-only shortcuts from an environment to its batched simulation core."""

from __future__ import annotations


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
        return self.core.max_episode_steps or self.core.task.max_episode_steps

    @property
    def max_return(self) -> float:
        """Upper bound of an episode's return: the largest reward per step
        times the episode length."""
        return self.core.task.max_reward_per_step * self._episode_steps()
