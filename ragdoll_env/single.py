"""Gymnasium single environments: one world (W = 1) of the batched core.

``gym.make("Ragdoll/Balance-v0", **kwargs)`` builds :class:`BalanceEnv`
(wrapped by Gymnasium in TimeLimit, OrderEnforcing and the passive checker).
``step`` returns a float32 observation, a Python ``float`` reward and Python
``bool`` flags. Actions outside [-1, 1] are clipped; an action of the wrong
shape, NaN or infinite raises ValueError and leaves the state untouched. A
world whose physics turns non-finite ends the episode (``terminated=True``,
``info["nonfinite"]=True``, reward 0, the last finite observation); the next
``reset()`` starts afresh.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from . import options as opt
from .batched import BatchedSim, check_action, world_info
from .core_access import CoreAccess
from .tasks import BalanceTask, InvertedDoublePendulumTask, InvertedPendulumTask, task_class
from .tasks import balance as _balance
from .tasks import inverted_double_pendulum as _idp
from .tasks import inverted_pendulum as _ip


class RagdollEnv(CoreAccess, gym.Env):
    """One world of a task as a ``gymnasium.Env``.

    task: a Task subclass or a registered id (subclasses fix it).
    render_mode: None, "rgb_array" (``render()`` returns (height, width, 3)
    uint8 frames, the camera following the body) or "human" (a window; without
    a display, a RuntimeWarning here and no window).
    **kwargs: the task's, the core's and the engine's keyword arguments (see
    :mod:`ragdoll_env.options`); unknown names raise TypeError.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 25}
    task_class = None

    def __init__(self, render_mode=None, width: int = 640, height: int = 480, task=None, **kwargs):
        tcls = task_class(task if task is not None else self.task_class)
        self.render_mode, self.width, self.height = opt.render_options(render_mode, width, height)
        self.core, _ = BatchedSim.from_kwargs(tcls, 1, kwargs)
        self.metadata = {**type(self).metadata, "render_fps": self.core.render_fps}
        task_ = self.core.task
        self.observation_space = spaces.Box(task_.observation_low, task_.observation_high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.core.num_actuators,), dtype=np.float32)
        self._renderer = None
        self._viewer = None
        if self.render_mode == "human":
            from .render import open_human_viewer

            self._viewer = open_human_viewer(task_.env_id, self.metadata["render_fps"])

    def _episode_steps(self):
        # The task's registered episode length: Gymnasium keeps a length given
        # to gym.make on its TimeLimit wrapper (env.spec.max_episode_steps),
        # which the env under it cannot see.
        return self.core.task.max_episode_steps

    # ------------------------------------------------------------ API
    def reset(self, *, seed=None, options=None):
        if options:
            raise ValueError(f"{self.core.task.env_id}: unknown reset options {sorted(options)}; "
                             f"this env takes none")
        super().reset(seed=seed)
        self.core.rngs[0] = self.np_random
        obs, info = self.core.reset([0])
        if self.render_mode == "human":
            self.render()
        return obs[0], dict(info)

    def step(self, action):
        a = check_action(action, self.action_space.shape)
        obs, reward, terminated, truncated, info = self.core.step(a[None])
        if self.render_mode == "human":
            self.render()
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), world_info(info, 0)

    def push(self, impulse, body=None, point=None):
        """Push the body now: an impulse (N·s, world frame) on ``body``
        (default the first of push_bodies, or the root body)."""
        if body is None:
            body = self.core.push_body_index[0] if self.core.push_body_index else 0
        self.core.push(0, body, impulse, point)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make")
            return None
        if self.render_mode == "human" and self._viewer is None:
            return None  # headless: nothing to show
        if self._renderer is None:
            self._renderer = self.core.make_renderer(self.width, self.height)
        frame = self.core.render(self._renderer, 0)
        if self.render_mode == "human":
            self._viewer.show(frame)
            return None
        return frame

    def close(self):
        self.core.close()
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self._renderer = None


class InvertedPendulumEnv(RagdollEnv):
    __doc__ = _ip.__doc__
    task_class = InvertedPendulumTask


class InvertedDoublePendulumEnv(RagdollEnv):
    __doc__ = _idp.__doc__
    task_class = InvertedDoublePendulumTask


class BalanceEnv(RagdollEnv):
    __doc__ = _balance.__doc__
    task_class = BalanceTask
