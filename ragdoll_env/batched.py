"""The batched core of every environment: one engine model and a state of W worlds.

:class:`BatchedSim` turns actions in [-1, 1] into joint torques, advances all
worlds ``frame_skip`` engine steps with one engine call per step, applies the
random pushes, resets any subset of worlds, and asks the task for
observations, rewards and termination. The single env (W = 1), the native
Gymnasium vector env and the SB3 VecEnv are thin layers over it, so they
return the same numbers for the same seeds and actions.

Randomness: each world draws from its own ``numpy.random.Generator``
(``rngs[w]``), at reset (initial pose, first push time) and at each push
(body, direction, strength, next push time), always in the same order. A
world's trajectory therefore depends only on its own generator and actions,
not on how many worlds share the batch.

Non-finite physics: the engine runs with ``check_finite=False``; after each
step a world whose state or observation turned NaN or infinite is reported in
``info["nonfinite"]``, terminated with reward 0, given its last finite
observation, and its state is replaced by the scene's initial state so that no
NaN stays in the batch.
"""

from __future__ import annotations

import contextlib
import math
import sys
import warnings

import numpy as np

import engine
from engine.settings import Settings

from . import options as opt
from .tasks import Task, task_class

_DEFAULT = object()


def check_action(action, shape) -> np.ndarray:
    """``action`` as a float64 array of ``shape``; ValueError for a wrong
    shape, a non-numeric value, NaN or infinity."""
    try:
        a = np.asarray(action)
        if a.dtype == object or np.iscomplexobj(a) or not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
            raise TypeError(f"dtype {a.dtype}")
        a = a.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"action must be a numeric array of shape {shape}, got {action!r} ({exc})") from None
    if a.shape != tuple(shape):
        raise ValueError(f"action must have shape {tuple(shape)}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise ValueError(f"action has a NaN or infinite entry at index {bad}: {a[bad]}")
    return a


class BatchedSim:
    """W worlds of one task.

    task: a :class:`~ragdoll_env.tasks.Task` instance.
    num_worlds: W.
    frame_skip: engine steps per env step (task default).
    reset_noise_scale: scale of the random initial state (task default; 0 for none).
    push_strength: N·s, a number or (lo, hi) drawn uniformly; 0 disables pushes.
    push_interval: (lo, hi) seconds between pushes, drawn uniformly; the first
        push comes one interval after the reset.
    push_bodies: names of the bodies pushed (one drawn uniformly per push).
    push_recovery_time: s a world must stay healthy after a push for the push
        to count in ``info["pushes_survived"]``.
    max_episode_steps: truncate episodes after this many env steps (None: never;
        the single env leaves this to Gymnasium's TimeLimit).
    threads: step the worlds on this many threads (1 to
        ``NUMBA_NUM_THREADS``; the same results bit for bit; default None:
        leave the engine's count, all cores unless ``engine.set_threads``
        said otherwise). An int is set with ``engine.set_threads`` at the
        start of each env step and not restored afterwards: numba keeps the
        count per calling thread, so it stays in effect for that thread's
        later steps, this env's or any other's. Batches below
        ``engine.core.jit.SERIAL_BELOW`` worlds step on the calling thread
        whatever the count.
    processes: deprecated alias (the worlds no longer step in worker
        processes): ``processes=P`` warns and means ``threads=min(P,
        NUMBA_NUM_THREADS)``.
    **settings: engine accuracy settings (``dt``, ``substeps``, ... see
        :class:`engine.Settings`), defaults from the task.
    """

    def __init__(self, task: Task, num_worlds: int = 1, *, frame_skip=None, reset_noise_scale=None,
                 push_strength=None, push_interval=None, push_bodies=None, push_recovery_time=None,
                 max_episode_steps=None, threads=None, processes=None, **settings):
        if not isinstance(task, Task):
            raise TypeError(f"task must be a Task instance, got {task!r}")
        for name in settings:
            if name not in opt.SETTINGS_KEYS:
                raise TypeError(f"{task.env_id}: unknown keyword argument {name!r}; engine settings: "
                                f"{list(opt.SETTINGS_KEYS)}")
        self.task = task
        self.num_worlds = W = opt.integer("num_worlds", num_worlds, minimum=1)
        self.frame_skip = opt.integer("frame_skip", task.frame_skip if frame_skip is None else frame_skip, minimum=1)
        self.reset_noise_scale = opt.number(
            "reset_noise_scale", task.reset_noise_scale if reset_noise_scale is None else reset_noise_scale, minimum=0.0)
        self.push_strength = opt.interval(
            "push_strength", task.push_strength if push_strength is None else push_strength, minimum=0.0)
        self.push_interval = opt.interval(
            "push_interval", task.push_interval if push_interval is None else push_interval, minimum=0.0,
            strict_min=True)
        self.push_bodies = opt.names("push_bodies", task.push_bodies if push_bodies is None else push_bodies)
        self.push_recovery_time = opt.number(
            "push_recovery_time", task.push_recovery_time if push_recovery_time is None else push_recovery_time,
            minimum=0.0)
        if max_episode_steps is not None:
            max_episode_steps = opt.integer("max_episode_steps", max_episode_steps, minimum=1)
        self.max_episode_steps = max_episode_steps
        self.threads = thread_count(threads, processes)

        values = {"dt": task.dt, "substeps": task.substeps, **settings, "check_finite": False}
        try:
            self.settings = Settings(**values)
            self.settings.validate()
        except TypeError as exc:
            raise ValueError(str(exc)) from None
        builder = engine.SceneBuilder(settings=self.settings)
        task.build(builder)
        self.model = builder.build()
        task.bind(self.model)
        self.push_body_index = []
        dynamic = [n for n, d in zip(self.model.body_names, self.model.dynamic) if d]
        for name in self.push_bodies:
            try:
                index = self.model.body_index(name)
            except KeyError:
                raise ValueError(f"push_bodies: no body named {name!r}; bodies: {dynamic}") from None
            if not self.model.dynamic[index]:
                raise ValueError(f"push_bodies: {name!r} is static, a push would not move it; bodies: {dynamic}")
            self.push_body_index.append(index)
        if self.pushes_enabled and not self.push_bodies:
            raise ValueError("push_bodies must name at least one body when push_strength > 0")

        self.state = self.model.initial_state(W)
        self._template = self.model.initial_state(1)
        self.num_actuators = self.model.num_actuators
        self.max_torque = np.array([a.max_torque for a in self.model.actuators], dtype=np.float64)
        self.actuator_names = tuple(a.name for a in self.model.actuators)
        self.observation_size = task.observation_size
        self.rngs: list[np.random.Generator | None] = [None] * W
        self.episode_steps = np.zeros(W, dtype=np.int64)
        self.next_push_time = np.full(W, np.inf)
        self.last_push_time = np.full(W, -np.inf)
        self.pushes = np.zeros(W, dtype=np.int64)
        self.pushes_survived = np.zeros(W, dtype=np.int64)
        # Times (s) of each world's pushes not yet survived, NaN in free slots;
        # a column more whenever a world has more pushes pending than slots.
        self.pending_push_times = np.full((W, 1), np.nan)
        self.last_obs = np.zeros((W, self.observation_size), dtype=np.float32)

    # ------------------------------------------------------------ properties
    @property
    def pushes_enabled(self) -> bool:
        return self.push_strength[1] > 0.0

    @property
    def dt(self) -> float:
        """Seconds per env step: engine dt x frame_skip."""
        return self.settings.dt * self.frame_skip

    @property
    def render_fps(self) -> int:
        return int(round(1.0 / self.dt))

    def time(self) -> np.ndarray:
        """(W,) simulated seconds since each world's reset."""
        return self.state.step * self.settings.dt

    @classmethod
    def from_kwargs(cls, task, num_worlds, kwargs, extra=(), max_episode_steps=None, where=None):
        """Build from a task class or id and ``gym.make``-style keyword
        arguments; returns (core, the ``extra`` kwargs found)."""
        tcls = task_class(task)
        settings, common, task_kw, rest = opt.split_kwargs(tcls, kwargs, extra=extra, where=where)
        return cls(tcls(**task_kw), num_worlds, max_episode_steps=max_episode_steps, **common, **settings), rest

    # ------------------------------------------------------------ reset
    def rng(self, world: int) -> np.random.Generator:
        if self.rngs[world] is None:
            from gymnasium.utils import seeding

            self.rngs[world] = seeding.np_random()[0]
        return self.rngs[world]

    def reset(self, worlds) -> tuple[np.ndarray, dict]:
        """Reset ``worlds`` (indices) from their generators; returns their
        observations (len(worlds), D) float32 and an info dict (empty)."""
        worlds = np.atleast_1d(np.asarray(worlds, dtype=np.int64))
        task, model = self.task, self.model
        for w in worlds:
            rng = self.rng(int(w))
            pose = task.reset_world(model, rng, self.reset_noise_scale)
            src = self._template.copy()
            for key, value in pose.items():
                src.arrays[key][0] = value
            self.state.assign([int(w)], src)
            self.next_push_time[w] = rng.uniform(*self.push_interval) if self.pushes_enabled else np.inf
        self.episode_steps[worlds] = 0
        self.last_push_time[worlds] = -np.inf
        self.pushes[worlds] = 0
        self.pushes_survived[worlds] = 0
        self.pending_push_times[worlds] = np.nan
        obs = task.observe(model, self.state.select(worlds)).astype(np.float32)
        if not np.all(np.isfinite(obs)):
            raise FloatingPointError(f"{task.env_id}: the reset state of worlds {worlds.tolist()} is not finite")
        self.last_obs[worlds] = obs
        return obs, {}

    # ------------------------------------------------------------ pushes
    def push(self, world: int, body, impulse, point=None) -> None:
        """Apply an impulse (N·s, world frame) to ``body`` (name or index) of one world now."""
        engine.apply_impulse(self.model, self.state, body, np.asarray(impulse, dtype=float), point=point,
                             worlds=[int(world)])

    def _apply_pushes(self, active):
        W = self.num_worlds
        applied = np.zeros(W, dtype=bool)
        impulse = np.zeros((W, 3))
        body = np.full(W, -1, dtype=np.int64)
        if not self.pushes_enabled:
            return applied, impulse, body
        t = self.time()
        due = np.flatnonzero(active & (t >= self.next_push_time))
        for w in due:
            rng = self.rngs[w]
            k = int(rng.integers(len(self.push_body_index)))
            heading = rng.uniform(0.0, 2.0 * math.pi)
            strength = rng.uniform(*self.push_strength)
            impulse[w] = strength * np.array([math.cos(heading), math.sin(heading), 0.0])
            body[w] = self.push_body_index[k]
            applied[w] = True
            self.next_push_time[w] = t[w] + rng.uniform(*self.push_interval)
        for b in np.unique(body[applied]):
            sel = np.flatnonzero(applied & (body == b))
            engine.apply_impulse(self.model, self.state, int(b), impulse, worlds=sel)
        self.pushes[applied] += 1
        self.last_push_time[applied] = t[applied]
        if applied.any():
            free = np.isnan(self.pending_push_times[applied])
            if not free.any(axis=1).all():
                self.pending_push_times = np.pad(self.pending_push_times, ((0, 0), (0, 1)), constant_values=np.nan)
                free = np.isnan(self.pending_push_times[applied])
            worlds = np.flatnonzero(applied)
            self.pending_push_times[worlds, np.argmax(free, axis=1)] = t[worlds]
        return applied, impulse, body

    def close(self) -> None:
        """Nothing to release: the worlds step on numba's threads, which
        outlive the env (kept for the envs' ``close``)."""

    # ------------------------------------------------------------ step
    def step(self, action, active=None):
        """Advance every world one env step with ``action`` (W, A) in [-1, 1]
        (clipped; ValueError for a wrong shape, NaN or infinity, before
        anything changes).

        active: (W,) bool, worlds whose step counts (others, about to be reset
        by the caller, are stepped but get no pushes and keep their counters).
        Returns obs (W, D) float32, reward (W,) float64, terminated (W,) bool,
        truncated (W,) bool, info {name: (W, ...) array}.
        """
        W = self.num_worlds
        a = check_action(action, (W, self.num_actuators))
        active = np.ones(W, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        a = np.clip(a, -1.0, 1.0)
        applied, impulse, body = self._apply_pushes(active)
        control = engine.Control(motor=a * self.max_torque)
        task, model = self.task, self.model
        if self.threads is not None:
            engine.set_threads(self.threads)  # for this calling thread, left set (see ``threads``)
        with np.errstate(all="ignore"):  # a world blowing up is reported in info["nonfinite"]
            for _ in range(self.frame_skip):
                engine.step(model, self.state, control)
            # The observation and the reward read the same positions: their joint geometry once.
            with model.joints.positions_fixed(self.state) if model.joints is not None else contextlib.nullcontext():
                obs = task.observe(model, self.state).astype(np.float32)
                healthy, terms, extra = task.evaluate(model, self.state, a)
            reward = np.zeros(W)
            for value in terms.values():
                reward = reward + value
        self.episode_steps[active] += 1
        bad = np.zeros(W, dtype=bool)
        bad[self.state.nonfinite_worlds()] = True
        bad |= ~np.all(np.isfinite(obs), axis=1) | ~np.isfinite(reward)
        healthy = np.asarray(healthy, dtype=bool)
        if bad.any():
            obs[bad] = self.last_obs[bad]
            reward[bad] = 0.0
            healthy = healthy & ~bad
            terms = {k: np.where(bad, 0.0, v) for k, v in terms.items()}
            extra = {k: np.where(bad.reshape((W,) + (1,) * (np.ndim(v) - 1)), np.zeros_like(v), v)
                     for k, v in extra.items()}
            self.state.assign(np.flatnonzero(bad), self._template)
        terminated = ~healthy
        t = self.time()
        # Each push counts as survived once its world has stayed healthy for
        # push_recovery_time after it, whatever pushes came since.
        with np.errstate(invalid="ignore"):
            recovered = healthy[:, None] & (t[:, None] - self.pending_push_times >= self.push_recovery_time - 1e-9)
        self.pushes_survived += recovered.sum(axis=1)
        self.pending_push_times[recovered] = np.nan
        if self.max_episode_steps is None:
            truncated = np.zeros(W, dtype=bool)
        else:
            truncated = self.episode_steps >= self.max_episode_steps
        self.last_obs[active] = obs[active]
        info = {**{k: np.asarray(v, dtype=np.float64) for k, v in terms.items()}}
        info.update(extra)
        info.update({
            "healthy": healthy,
            "nonfinite": bad,
            "time": t,
            "push_applied": applied,
            "push_impulse": impulse,
            "push_body": body,
            "pushes": self.pushes.copy(),
            "pushes_survived": self.pushes_survived.copy(),
        })
        return obs, reward, terminated, truncated, info

    # ------------------------------------------------------------ render
    def make_renderer(self, width: int, height: int):
        """A Renderer of the model's shapes, with the task's camera; a scene
        without a ground plane (the pendulums) gets one drawn at z = 0 (for
        the picture only: the physics has none)."""
        from engine.shapes import PLANE

        from .render import Renderer

        types, params = np.asarray(self.model.shape_type), np.asarray(self.model.shape_params)
        self._render_floor = not np.any(types == PLANE)
        if self._render_floor:
            types = np.append(types, PLANE)
            params = np.vstack((params, np.zeros(3)))
        renderer = Renderer(types, params, width=width, height=height)
        cam = self.task.camera
        renderer.distance, renderer.elevation, renderer.azimuth = cam["distance"], cam["elevation"], cam["azimuth"]
        return renderer

    def render(self, renderer, world: int = 0) -> np.ndarray:
        """RGB frame (H, W, 3) uint8 of one world, the camera following the task's target."""
        target = self.task.camera_target(self.model, self.state.select([world]))[0]
        if not np.all(np.isfinite(target)):
            target = None
        pos, quat = self.state.position[world], self.state.orientation[world]
        if getattr(self, "_render_floor", False):
            pos = np.vstack((pos, np.zeros(3)))
            quat = np.vstack((quat, [1.0, 0.0, 0.0, 0.0]))
        return renderer.render(pos, quat, target=target)


def thread_count(threads, processes=None) -> int | None:
    """The ``threads=`` of an env checked (None, or an int in 1 to
    ``NUMBA_NUM_THREADS``, else ValueError naming ``threads``), or the
    deprecated ``processes=P`` mapped to ``min(P, NUMBA_NUM_THREADS)`` with a
    DeprecationWarning."""
    cores = engine.max_threads()
    if processes is not None:
        warnings.warn("processes= is deprecated: the worlds step on threads; use threads=", DeprecationWarning,
                      stacklevel=_caller_level())
        processes = opt.integer("processes", processes, minimum=1)
        if threads is not None:
            raise ValueError(f"give threads= only, not also its deprecated alias processes= (got threads={threads!r}, "
                             f"processes={processes!r})")
        return min(processes, cores)
    if threads is None:
        return None
    n = opt.integer("threads", threads, minimum=1)
    if n > cores:
        raise ValueError(f"threads must be <= {cores} (NUMBA_NUM_THREADS, the threads numba has), got {threads!r}")
    return n


def _caller_level() -> int:
    """``warnings.warn``'s stacklevel naming the first frame outside
    ragdoll_env and gymnasium (the user's ``gym.make``), from the caller of
    :func:`thread_count`."""
    frame, level = sys._getframe(2), 2
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in ("ragdoll_env", "gymnasium"):
        frame, level = frame.f_back, level + 1
    return level


def world_info(info: dict, w: int) -> dict:
    """One world's entries of a batched info dict, as Python scalars
    (bool, int, float) or small numpy arrays."""
    out = {}
    for key, value in info.items():
        v = value[w]
        if isinstance(v, np.ndarray) and v.ndim > 0:
            out[key] = v.copy()
        elif isinstance(v, (np.bool_, bool)):
            out[key] = bool(v)
        elif isinstance(v, (np.integer, int)):
            out[key] = int(v)
        else:
            out[key] = float(v)
    return out
