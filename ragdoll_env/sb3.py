"""A Stable-Baselines3 ``VecEnv`` on the batched core: PPO steps all worlds in one engine call.

>>> from ragdoll_env.sb3 import make_sb3_vec_env
>>> venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=16, seed=0)
>>> model = stable_baselines3.PPO("MlpPolicy", venv).learn(100_000)

It follows SB3's VecEnv contract: ``reset()`` returns the observations only
(seeds from ``seed()`` and options from ``set_options()`` apply to the next
reset); ``step_wait()`` returns observations, float32 rewards, bool dones and a
list of info dicts; a finished world is reset at once, its final observation
in ``info["terminal_observation"]`` and ``info["TimeLimit.truncated"]`` set
when the time limit (not a fall) ended it. ``get_attr``, ``set_attr`` and
``env_method`` reach the shared core and task (per-world views for
``render``, ``reset`` and ``np_random``); ``env_is_wrapped`` is False for
every wrapper (nothing wraps the worlds: use SB3's ``VecMonitor`` on top for
episode statistics). stable_baselines3 is imported only when this adapter is
built.
"""

from __future__ import annotations

import math

import numpy as np

from . import options as opt
from .batched import _DEFAULT, BatchedSim, check_action, world_info
from .tasks import task_class

_CLASS = None


class _WorldView:
    """What ``get_attr``/``env_method`` see as one sub-environment: world ``w``
    of the adapter, falling back to the adapter's shared attributes."""

    def __init__(self, venv, w):
        self._venv = venv
        self._w = w

    @property
    def np_random(self):
        return self._venv.core.rng(self._w)

    def render(self):
        return self._venv.render_world(self._w)

    def reset(self, seed=None, options=None):
        from gymnasium.utils import seeding

        if seed is not None:
            self._venv.core.rngs[self._w] = seeding.np_random(seed)[0]
        obs, info = self._venv.core.reset([self._w])
        self._venv._obs[self._w] = obs[0]
        return obs[0].copy(), info

    def __getattr__(self, name):
        return self._venv._shared_attr(name)


def _sb3_class():
    global _CLASS
    if _CLASS is not None:
        return _CLASS
    from gymnasium import spaces
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class RagdollSB3VecEnv(VecEnv):
        """W worlds of a task as an SB3 VecEnv (see the module docstring)."""

        def __init__(self, task, num_envs: int = 8, max_episode_steps=_DEFAULT, render_mode=None,
                     width: int = 640, height: int = 480, **kwargs):
            tcls = task_class(task)
            self.render_mode, self.width, self.height = opt.render_options(render_mode, width, height)
            if self.render_mode == "human":
                raise ValueError("the SB3 adapter renders with render_mode='rgb_array' "
                                 "(VecEnv.render(mode='human') shows those frames)")
            if max_episode_steps is _DEFAULT:
                max_episode_steps = tcls.max_episode_steps
            num_envs = opt.integer("num_envs", num_envs, minimum=1)
            self.core, _ = BatchedSim.from_kwargs(tcls, num_envs, kwargs, max_episode_steps=max_episode_steps,
                                                  where=tcls.env_id)
            t = self.core.task
            self._views = [_WorldView(self, w) for w in range(self.core.num_worlds)]
            self._obs = np.zeros((self.core.num_worlds, self.core.observation_size), dtype=np.float32)
            self._actions = None
            self._renderer = None
            self.spec = None
            obs_space = spaces.Box(t.observation_low, t.observation_high, dtype=np.float32)
            act_space = spaces.Box(-1.0, 1.0, shape=(self.core.num_actuators,), dtype=np.float32)
            super().__init__(self.core.num_worlds, obs_space, act_space)
            self.metadata = {**self.metadata, "render_fps": self.core.render_fps}

        # ---------------------------------------------------- attributes
        def _shared_attr(self, name):
            for owner in (self, self.core, self.core.task):
                try:
                    return object.__getattribute__(owner, name)
                except AttributeError:
                    continue
            raise AttributeError(f"{self.core.task.env_id} has no attribute {name!r}")

        @property
        def max_return(self):
            """The largest reward per step times the episode length (inf without truncation)."""
            steps = math.inf if self.core.max_episode_steps is None else self.core.max_episode_steps
            return self.core.task.max_reward_per_step * steps

        # ---------------------------------------------------- VecEnv API
        def reset(self):
            from gymnasium.utils import seeding

            unknown = sorted({k for options in self._options if options for k in options})
            if unknown:
                raise ValueError(f"{self.core.task.env_id}: unknown reset options {unknown} "
                                 f"(from set_options); this env takes none")
            for w, seed in enumerate(self._seeds):
                if seed is not None:
                    self.core.rngs[w] = seeding.np_random(int(seed))[0]
            obs, _ = self.core.reset(np.arange(self.num_envs))
            self._obs[:] = obs
            self.reset_infos = [{} for _ in range(self.num_envs)]
            self._reset_seeds()
            self._reset_options()
            return self._obs.copy()

        def step_async(self, actions):
            self._actions = actions

        def step_wait(self):
            if self._actions is None:
                raise RuntimeError("step_wait() called without step_async()")
            actions, self._actions = self._actions, None
            a = check_action(actions, (self.num_envs, self.core.num_actuators))
            obs, reward, terminated, truncated, info = self.core.step(a)
            dones = terminated | truncated
            infos = [world_info(info, w) for w in range(self.num_envs)]
            if dones.any():
                worlds = np.flatnonzero(dones)
                for w in worlds:
                    infos[w]["terminal_observation"] = obs[w].copy()
                    infos[w]["TimeLimit.truncated"] = bool(truncated[w] and not terminated[w])
                obs[worlds], _ = self.core.reset(worlds)
                for w in worlds:
                    self.reset_infos[w] = {}
            self._obs[:] = obs
            return obs.copy(), reward.astype(np.float32), dones, infos

        def close(self):
            self.core.close()
            self._renderer = None

        def get_attr(self, attr_name, indices=None):
            return [getattr(self._views[i], attr_name) for i in self._get_indices(indices)]

        def set_attr(self, attr_name, value, indices=None):
            idx = list(self._get_indices(indices))
            for owner in (self.core.task, self.core):
                if attr_name in vars(owner):
                    if sorted(idx) != list(range(self.num_envs)):
                        raise ValueError(f"{attr_name!r} is shared by all {self.num_envs} worlds of the batched "
                                         "env; set it for all indices at once")
                    setattr(owner, attr_name, value)
                    return
            for i in idx:
                setattr(self._views[i], attr_name, value)

        def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
            return [getattr(self._views[i], method_name)(*method_args, **method_kwargs)
                    for i in self._get_indices(indices)]

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False for _ in self._get_indices(indices)]

        def render_world(self, w):
            if self.render_mode != "rgb_array":
                return None
            if self._renderer is None:
                self._renderer = self.core.make_renderer(self.width, self.height)
            return self.core.render(self._renderer, w)

        def get_images(self):
            return [self.render_world(w) for w in range(self.num_envs)]

    _CLASS = RagdollSB3VecEnv
    return _CLASS


def make_sb3_vec_env(env_id, num_envs: int = 8, seed: int | None = None, monitor: bool = False, **kwargs):
    """An SB3 VecEnv of ``num_envs`` worlds of ``env_id`` (a registered id or a
    Task class), stepped as one batch. ``seed`` seeds world i with seed + i at
    the first reset; ``monitor`` wraps it in SB3's VecMonitor (episode
    returns and lengths in ``info["episode"]``). Other keyword arguments as
    for ``gym.make`` (plus ``max_episode_steps``)."""
    venv = _sb3_class()(env_id, num_envs=num_envs, **kwargs)
    if seed is not None:
        venv.seed(seed)
    if monitor:
        from stable_baselines3.common.vec_env import VecMonitor

        venv = VecMonitor(venv)
    return venv


def __getattr__(name):
    if name == "RagdollSB3VecEnv":
        return _sb3_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
