"""Residual control: a learned action added to a baseline controller's action.

The policy's action r in [-1, 1] is added to the action of a controller from
:mod:`ragdoll_env.baselines` computed on the same (raw) observation, and the
sum is clipped to the action space::

    a = clip(baseline(obs) + scale * r, -1, 1)       (torque / max torque)

so a policy that outputs zeros is the baseline itself and learning starts
from what the baseline can do (residual policy learning: Silver et al. 2018,
arXiv:1812.06298; Johannink et al. 2019, ICRA). The environment is unchanged:
its action is still every joint's torque, and its reward still charges the
control cost of the summed action ``a``.

* :func:`residual_vec_env` wraps an SB3 ``VecEnv`` (the batched adapter of
  :mod:`ragdoll_env.sb3`, before VecMonitor and VecNormalize, so the
  baseline sees raw observations);
* :class:`ResidualAction` wraps a single Gymnasium env (videos, the checkers).

``training.train`` builds them from a config's ``residual`` entry
(``{"baseline": "standing_pd", "scale": 1.0, "actuators": [...]}``) and
``training.evaluate`` evaluates the policy the same way. ``actuators``
(optional) names the joints the policy acts on, as substrings of the
actuator names (``"hip"`` matches ``hip_l:twist``, ...): the action space
shrinks to those, and the other joints follow the baseline alone.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from .batched import check_action


def check_residual(spec) -> dict | None:
    """The validated residual settings of a config entry (a dict, or None for
    no residual), else ValueError: ``baseline`` (a name of
    ``ragdoll_env.baselines.BASELINES`` but "zero"), ``scale`` (> 0, default
    1), ``kwargs`` (the baseline's keyword arguments, default none) and
    ``actuators`` (name parts, optional)."""
    from .baselines import BASELINES

    if spec is None:
        return None
    if not isinstance(spec, dict):
        raise ValueError(f"residual must be a mapping {{'baseline': name, 'scale': s}} or null, got {spec!r}")
    unknown = set(spec) - {"baseline", "scale", "kwargs", "actuators"}
    if unknown:
        raise ValueError(f"residual: unknown keys {sorted(unknown)}; keys: baseline, scale, kwargs, actuators")
    name = spec.get("baseline")
    if name not in BASELINES or name == "zero":
        raise ValueError(f"residual: baseline must be one of {sorted(set(BASELINES) - {'zero'})}, got {name!r}")
    scale = spec.get("scale", 1.0)
    if not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"residual: scale must be a finite number > 0, got {scale!r}")
    kwargs = spec.get("kwargs") or {}
    if not isinstance(kwargs, dict):
        raise ValueError(f"residual: kwargs must be a mapping of the baseline's keyword arguments, got {kwargs!r}")
    actuators = spec.get("actuators")
    if actuators is not None and (not isinstance(actuators, (list, tuple)) or not actuators
                                  or not all(isinstance(a, str) for a in actuators)):
        raise ValueError(f"residual: actuators must be a non-empty list of name parts, got {actuators!r}")
    out = {"baseline": name, "scale": float(scale), "kwargs": dict(kwargs)}
    if actuators is not None:
        out["actuators"] = list(actuators)
    return out


def actuator_subset(names, parts) -> np.ndarray:
    """Indices of the actuator ``names`` containing any of ``parts`` (all for
    None), in the engine's actuator order (not the order of ``parts``), else
    ValueError naming a part that matches nothing."""
    if parts is None:
        return np.arange(len(names))
    for part in parts:
        if not any(part in n for n in names):
            raise ValueError(f"residual: actuator part {part!r} matches none of {list(names)}")
    return np.array([i for i, n in enumerate(names) if any(part in n for part in parts)], dtype=np.int64)


def residual_action(controller, obs, residual, scale: float, subset=None) -> np.ndarray:
    """clip(controller(obs) + scale * residual, -1, 1) as float32; obs (D,) or
    (W, D); ``residual`` acts on the actuators ``subset`` (all for None)."""
    base = controller.act(obs).astype(np.float64)
    r = np.asarray(residual, dtype=np.float64)
    if subset is not None:
        base[..., subset] += scale * r
    else:
        base += scale * r
    return np.clip(base, -1.0, 1.0).astype(np.float32)


def _residual_parts(env, spec):
    """(baseline controller, actuator subset, the policy's action space,
    scale) of a validated ``spec`` on ``env`` (any env the baselines accept)."""
    from .baselines import make_baseline

    controller = make_baseline(spec["baseline"], env, **spec["kwargs"])
    subset = actuator_subset(controller.core.actuator_names, spec.get("actuators"))
    space = gym.spaces.Box(-1.0, 1.0, shape=(len(subset),), dtype=np.float32)
    return controller, subset, space, spec["scale"]


def residual_vec_env(venv, spec):
    """``venv`` (an SB3 VecEnv on the batched core) with each step's actions
    added to the baseline's (see the module docstring); ``venv`` itself when
    ``spec`` is None."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    spec = check_residual(spec)
    if spec is None:
        return venv

    class ResidualVecEnv(VecEnvWrapper):
        """Actions are residuals on ``controller``; observations pass unchanged."""

        def __init__(self, inner):
            controller, subset, space, scale = _residual_parts(inner, spec)
            super().__init__(inner, action_space=space)
            self.controller, self.subset, self.scale = controller, subset, scale
            self._last_obs = None

        def reset(self):
            self._last_obs = self.venv.reset()
            return self._last_obs

        def step_async(self, actions):
            if self._last_obs is None:
                raise RuntimeError("step_async() called before reset()")
            residual = check_action(actions, (self.num_envs, len(self.subset)))
            self.venv.step_async(residual_action(self.controller, self._last_obs, residual, self.scale, self.subset))

        def step_wait(self):
            obs, rewards, dones, infos = self.venv.step_wait()
            self._last_obs = obs  # after an automatic reset: the new episode's first observation
            return obs, rewards, dones, infos

    return ResidualVecEnv(venv)


class ResidualAction(gym.Wrapper):
    """A single Ragdoll env whose action is a residual on a baseline
    controller (``spec`` as :func:`check_residual`)."""

    def __init__(self, env, spec):
        super().__init__(env)
        spec = check_residual(spec)
        if spec is None:
            raise ValueError("ResidualAction needs a residual spec, got None")
        self.controller, self.subset, self.action_space, self.scale = _residual_parts(env, spec)
        self._last_obs = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._last_obs = obs
        return obs, info

    def step(self, action):
        if self._last_obs is None:
            raise RuntimeError("step() called before reset()")
        residual = check_action(action, self.action_space.shape)
        out = self.env.step(residual_action(self.controller, self._last_obs, residual, self.scale, self.subset))
        self._last_obs = out[0]
        return out
