"""Keyword arguments of the environments: which exist, their defaults, their checks.

Every environment takes three groups of keyword arguments (``gym.make(id, **kwargs)``):

* common ones, handled by the batched core (:mod:`ragdoll_env.batched`):
  ``frame_skip``, ``reset_noise_scale``, ``push_strength``, ``push_interval``,
  ``push_bodies``, ``push_recovery_time``, ``threads`` (and ``processes``,
  its deprecated alias);
* the engine's accuracy settings, every field of :class:`engine.Settings` but
  ``check_finite`` (the environments detect non-finite worlds themselves):
  ``dt``, ``substeps``, ``iterations``, ``relax_iterations``, ``integrator``,
  ``solver``, ``joint_hertz``, ... ;
* the task's own (see each task's ``params``), and the rendering ones
  ``render_mode``, ``width``, ``height`` (handled by the env classes).

An unknown name raises ``TypeError`` naming it and listing the valid ones; a
bad value raises ``ValueError`` naming the argument.
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np

from engine.settings import Settings

#: Engine settings accepted as keyword arguments (check_finite is the env's business).
SETTINGS_KEYS = tuple(f.name for f in fields(Settings) if f.name != "check_finite")

#: Keyword arguments of the batched core, for every task.
COMMON_KEYS = ("frame_skip", "reset_noise_scale", "push_strength", "push_interval", "push_bodies",
               "push_recovery_time", "threads", "processes")  # processes: threads' deprecated alias

#: Rendering keyword arguments (single and vector envs).
RENDER_KEYS = ("render_mode", "width", "height")

RENDER_MODES = (None, "rgb_array", "human")


def split_kwargs(task_cls, kwargs: dict, extra=(), where: str | None = None):
    """Split ``kwargs`` into (settings, common, task, extra) dicts.

    Raises TypeError for names that belong to none of the groups.
    """
    settings, common, task, rest = {}, {}, {}, {}
    task_keys = tuple(task_cls.params)
    for name, value in kwargs.items():
        if name in SETTINGS_KEYS:
            settings[name] = value
        elif name in COMMON_KEYS:
            common[name] = value
        elif name in task_keys:
            task[name] = value
        elif name in extra:
            rest[name] = value
        else:
            valid = sorted(set(SETTINGS_KEYS) | set(COMMON_KEYS) | set(task_keys) | set(extra))
            what = where or task_cls.env_id
            raise TypeError(f"{what}: unknown keyword argument {name!r}; valid keyword arguments: {valid}")
    return settings, common, task, rest


# ----------------------------------------------------------------- checks
def number(name, value, minimum=None, maximum=None, strict_min=False, allow_inf=False) -> float:
    """A real number within bounds, else ValueError naming ``name``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if minimum is not None and (v < minimum or (strict_min and v == minimum)):
        raise ValueError(f"{name} must be {'>' if strict_min else '>='} {minimum:g}, got {value!r}")
    if maximum is not None and v > maximum:
        raise ValueError(f"{name} must be <= {maximum:g}, got {value!r}")
    return v


def integer(name, value, minimum=None) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    try:
        v = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be an integer, got {value!r}") from None
    if v != value:
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if minimum is not None and v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    return v


def flag(name, value) -> bool:
    if not isinstance(value, (bool, int, np.bool_)) or value not in (0, 1, True, False):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def interval(name, value, minimum=0.0, strict_min=False, allow_scalar=True) -> tuple[float, float]:
    """(lo, hi) with minimum <= lo <= hi; a single number means (v, v)."""
    if allow_scalar and not isinstance(value, (tuple, list)) and getattr(value, "ndim", 0) == 0:
        v = number(name, value, minimum=minimum, strict_min=strict_min)
        return v, v
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (lo, hi)" + (" or a number" if allow_scalar else "")
                         + f", got {value!r}") from None
    lo = number(f"{name}[0]", lo, minimum=minimum, strict_min=strict_min)
    hi = number(f"{name}[1]", hi, minimum=minimum, strict_min=strict_min)
    if lo > hi:
        raise ValueError(f"{name} must have lo <= hi, got {value!r}")
    return lo, hi


def names(name, value) -> tuple[str, ...]:
    if isinstance(value, str):
        value = (value,)
    try:
        out = tuple(value)
    except TypeError:
        raise ValueError(f"{name} must be a body name or a sequence of body names, got {value!r}") from None
    if not all(isinstance(v, str) and v for v in out):
        raise ValueError(f"{name} must hold non-empty body names, got {value!r}")
    return out


def render_options(render_mode, width, height):
    if render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    return render_mode, integer("width", width, minimum=1), integer("height", height, minimum=1)
