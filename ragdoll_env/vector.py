"""Native batched ``gymnasium.vector.VectorEnv``: all worlds in one engine call per step.

``gymnasium.make_vec("Ragdoll/Balance-v0", num_envs=W)`` (the registered
``vector_entry_point``) builds :class:`BalanceVectorEnv`. Finished worlds, and
only those, are reset automatically: by default in Gymnasium's next-step mode
(the step after an episode ends returns that world's reset observation with
reward 0 and both flags False), or with ``autoreset_mode="SameStep"`` in the
same step (the final observation and info in ``info["final_obs"]`` and
``info["final_info"]``). Infos are dicts of (W, ...) arrays with ``_key``
masks, as SyncVectorEnv gives.

Seeding follows SyncVectorEnv: ``reset(seed=s)`` seeds world i with s + i
(a list gives one seed per world), so W single envs reset with seeds s + i and
fed the same actions produce bit-identical observations and rewards.
``reset(options={"reset_mask": mask})`` resets only the masked worlds.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import options as opt
from .batched import _DEFAULT, BatchedSim, check_action
from .core_access import CoreAccess
from .tasks import BalanceTask, InvertedDoublePendulumTask, InvertedPendulumTask, task_class


class RagdollVectorEnv(CoreAccess, VectorEnv):
    """W worlds of a task as a Gymnasium VectorEnv.

    num_envs: W. max_episode_steps: truncation length (default: the task's
    registered one; None for no limit). autoreset_mode: an AutoresetMode or
    its value ("NextStep", "SameStep", "Disabled"). render_mode "rgb_array":
    ``render()`` returns a tuple of W frames; "human": a window showing world 0.
    Other keyword arguments as for the single env.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 25,
                "autoreset_mode": AutoresetMode.NEXT_STEP}
    task_class = None

    def __init__(self, num_envs: int = 1, render_mode=None, width: int = 640, height: int = 480,
                 max_episode_steps=_DEFAULT, autoreset_mode=AutoresetMode.NEXT_STEP, task=None, **kwargs):
        tcls = task_class(task if task is not None else self.task_class)
        self.render_mode, self.width, self.height = opt.render_options(render_mode, width, height)
        try:
            self.autoreset_mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, "
                             f"got {autoreset_mode!r}") from None
        if max_episode_steps is _DEFAULT:
            max_episode_steps = tcls.max_episode_steps
        num_envs = opt.integer("num_envs", num_envs, minimum=1)
        self.core, _ = BatchedSim.from_kwargs(tcls, num_envs, kwargs, max_episode_steps=max_episode_steps)
        self.num_envs = self.core.num_worlds
        self.metadata = {**type(self).metadata, "render_fps": self.core.render_fps,
                         "autoreset_mode": self.autoreset_mode}
        task_ = self.core.task
        self.single_observation_space = spaces.Box(task_.observation_low, task_.observation_high, dtype=np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(self.core.num_actuators,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._obs = np.zeros((self.num_envs, self.core.observation_size), dtype=np.float32)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._renderer = None
        self._viewer = None
        if self.render_mode == "human":
            from .render import open_human_viewer

            self._viewer = open_human_viewer(task_.env_id, self.metadata["render_fps"])


    # ------------------------------------------------------------ API
    def _seeds(self, seed):
        W = self.num_envs
        if seed is None:
            return [None] * W
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + i for i in range(W)]
        seeds = list(seed)
        if len(seeds) != W:
            raise ValueError(f"seed must be None, an int or a list of {W} seeds, got {len(seeds)} seeds")
        return seeds

    def reset(self, *, seed=None, options=None):
        unknown = sorted(set(options or {}) - {"reset_mask"})
        if unknown:
            raise ValueError(f"{self.core.task.env_id}: unknown reset options {unknown}; "
                             f"this vector env takes 'reset_mask' alone")
        seeds = self._seeds(seed)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        mask = options.get("reset_mask") if options else None
        if mask is None:
            worlds = np.arange(self.num_envs)
        else:
            mask = np.asarray(mask)
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({self.num_envs},), "
                                 f"got {mask.dtype} {mask.shape}")
            worlds = np.flatnonzero(mask)
        for w in worlds:
            if seeds[w] is not None:
                self.core.rngs[w] = seeding.np_random(seeds[w])[0]
        obs, _ = self.core.reset(worlds)
        self._obs[worlds] = obs
        self._autoreset[worlds] = False
        return self._obs.copy(), {}

    def step(self, actions):
        W = self.num_envs
        a = check_action(actions, (W, self.core.num_actuators))
        mode = self.autoreset_mode
        pending = self._autoreset.copy() if mode == AutoresetMode.NEXT_STEP else np.zeros(W, dtype=bool)
        if mode == AutoresetMode.DISABLED and self._autoreset.any():
            raise RuntimeError(f"worlds {np.flatnonzero(self._autoreset).tolist()} have finished; reset them "
                               "with reset(options={'reset_mask': mask}) before stepping (autoreset is disabled)")
        obs, reward, terminated, truncated, info = self.core.step(a, active=~pending)
        masks = {k: ~pending for k in info}
        if pending.any():
            worlds = np.flatnonzero(pending)
            obs[worlds], _ = self.core.reset(worlds)
            reward[worlds] = 0.0
            terminated[worlds] = False
            truncated[worlds] = False
        done = terminated | truncated
        if mode == AutoresetMode.SAME_STEP and done.any():
            worlds = np.flatnonzero(done)
            final_obs = np.full(W, None, dtype=object)
            for w in worlds:
                final_obs[w] = obs[w].copy()
            final_info = {}
            for k, v in info.items():
                final_info[k] = np.array(v, copy=True)
                final_info["_" + k] = done.copy()
                # As SyncVectorEnv: a reset world's top-level info is its reset info (empty here).
                masks[k] = masks[k] & ~done
            info["final_obs"], masks["final_obs"] = final_obs, done.copy()
            info["final_info"], masks["final_info"] = final_info, done.copy()
            obs[worlds], _ = self.core.reset(worlds)
        self._autoreset = done if mode != AutoresetMode.SAME_STEP else np.zeros(W, dtype=bool)
        self._obs[:] = obs
        out = {}
        for k, v in info.items():
            out[k] = v
            out["_" + k] = masks[k]
        return obs, reward, terminated, truncated, out

    def render(self):
        if self.render_mode is None or (self.render_mode == "human" and self._viewer is None):
            return None
        if self._renderer is None:
            self._renderer = self.core.make_renderer(self.width, self.height)
        if self.render_mode == "human":
            self._viewer.show(self.core.render(self._renderer, 0))
            return None
        return tuple(self.core.render(self._renderer, w) for w in range(self.num_envs))

    def close_extras(self, **kwargs):
        self.core.close()
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self._renderer = None


class InvertedPendulumVectorEnv(RagdollVectorEnv):
    task_class = InvertedPendulumTask


class InvertedDoublePendulumVectorEnv(RagdollVectorEnv):
    task_class = InvertedDoublePendulumTask


class BalanceVectorEnv(RagdollVectorEnv):
    task_class = BalanceTask
