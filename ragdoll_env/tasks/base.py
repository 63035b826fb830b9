"""What every task defines: its scene, observation, reward and termination,
written once and batched over the W worlds of a state.

A task knows nothing of Gymnasium: the batched core
(:class:`ragdoll_env.batched.BatchedSim`) builds its scene, resets worlds
through :meth:`Task.reset_world`, steps the engine, and asks the task for
observations (:meth:`Task.observe`) and rewards (:meth:`Task.evaluate`).
"""

from __future__ import annotations

import numpy as np

from .. import options as opt


class Task:
    """Base class of the tasks. Subclasses set the class attributes and
    implement the methods below.

    ``params`` maps each task keyword argument to ``(default, check)`` where
    ``check(name, value)`` returns the validated value or raises ValueError.
    After ``__init__`` every parameter is an attribute of the task.
    """

    env_id = ""
    #: task keyword arguments: name -> (default, check)
    params: dict = {}
    # Defaults of the core's keyword arguments for this task.
    dt = 0.02
    substeps = 4
    frame_skip = 2
    reset_noise_scale = 0.05
    push_strength = 0.0
    push_interval = (1.0, 3.0)
    push_bodies: tuple = ()
    push_recovery_time = 1.0
    #: registered episode length (Gymnasium's TimeLimit)
    max_episode_steps = 1000
    #: orbit camera: distance (m), elevation and azimuth (degrees)
    camera = {"distance": 3.0, "elevation": 10.0, "azimuth": -90.0}

    def __init__(self, **kwargs):
        for name in kwargs:
            if name not in self.params:
                raise TypeError(f"{self.env_id}: unknown task parameter {name!r}; task parameters: "
                                f"{sorted(self.params)}")
        for name, (default, check) in self.params.items():
            setattr(self, name, check(name, kwargs.get(name, default)))
        self.model = None

    # ------------------------------------------------------------ scene
    def build(self, builder) -> None:
        """Add the task's bodies and joints to ``builder``."""
        raise NotImplementedError

    def bind(self, model) -> None:
        """Look up indices in the compiled model; set ``obs_layout``,
        ``observation_low`` and ``observation_high``."""
        self.model = model

    # ------------------------------------------------------------ episodes
    def reset_world(self, model, rng: np.random.Generator, noise: float) -> dict:
        """Initial pose of one world drawn with ``rng``: a dict of
        ``position`` (N, 3), ``orientation`` (N, 4), ``velocity`` (N, 3) and
        ``angular_velocity`` (N, 3) arrays for all N bodies."""
        raise NotImplementedError

    def observe(self, model, state) -> np.ndarray:
        """(W, D) float64 observations."""
        raise NotImplementedError

    def evaluate(self, model, state, action) -> tuple[np.ndarray, dict, dict]:
        """After a step with the clipped ``action`` (W, A) in [-1, 1]:
        ``healthy`` (W,) bool, reward terms {"reward_*": (W,)} that sum to
        the reward, and other info {name: (W, ...)}."""
        raise NotImplementedError

    def camera_target(self, model, state) -> np.ndarray:
        """(W, 3) point the camera looks at."""
        raise NotImplementedError

    @property
    def max_reward_per_step(self) -> float:
        """Upper bound of the reward of one step."""
        raise NotImplementedError

    # ------------------------------------------------------------ helpers
    @property
    def observation_size(self) -> int:
        return int(self.observation_low.size)

    def _layout(self, parts):
        """Set ``obs_layout`` {name: slice} and the bounds from (name, size, low, high) parts."""
        layout, low, high, start = {}, [], [], 0
        for name, size, lo, hi in parts:
            layout[name] = slice(start, start + size)
            low.append(np.broadcast_to(np.asarray(lo, dtype=np.float64), (size,)))
            high.append(np.broadcast_to(np.asarray(hi, dtype=np.float64), (size,)))
            start += size
        self.obs_layout = layout
        self.observation_low = np.concatenate(low).astype(np.float32)
        self.observation_high = np.concatenate(high).astype(np.float32)


def ctrl_cost(weight: float, action: np.ndarray) -> np.ndarray:
    """weight x mean over actuators of a², per world (a in [-1, 1])."""
    return weight * np.mean(np.square(action), axis=-1)


# Parameter checks (name, value) -> value, for Task.params tables.
def nonneg(name, value):
    return opt.number(name, value, minimum=0.0)


def positive(name, value):
    return opt.number(name, value, minimum=0.0, strict_min=True)


def fraction(name, value):
    return opt.number(name, value, minimum=0.0, maximum=1.0, strict_min=True)


def angle(name, value):
    return opt.number(name, value, minimum=0.0, maximum=np.pi, strict_min=True)


def any_number(name, value):
    return opt.number(name, value)


def boolean(name, value):
    return opt.flag(name, value)


def nonneg_pair(name, value):
    try:
        a, b = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair of numbers >= 0, got {value!r}") from None
    return opt.number(f"{name}[0]", a, minimum=0.0), opt.number(f"{name}[1]", b, minimum=0.0)
