"""Per-environment PPO settings, kept as plain data (read, copy, change).

Each entry has:

* ``num_envs``: worlds stepped together by the batched SB3 VecEnv;
* ``threads`` (optional, default null: all cores): physics threads stepping
  those worlds, for the training and the evaluation env alike (the envs'
  ``threads=``, ``engine.set_threads``: the same results bit for bit, so a
  run's outcome does not depend on it, only its speed). ``processes``, the
  key of the former worker processes, is read as its deprecated alias
  (``processes: P`` is ``threads: min(P, cores)``, :func:`upgrade`), so
  older config files and runs still load;
* ``timesteps``: default training length (``--timesteps`` overrides);
* ``ppo``: keyword arguments of ``stable_baselines3.PPO`` (``policy_kwargs``
  uses names for ``activation_fn``: "tanh", "relu", "elu");
* ``normalize``: keyword arguments of ``VecNormalize`` for the training env;
* ``env_kwargs``: keyword arguments given to the environment (``gym.make``);
* ``train_env_kwargs`` (optional): merged over ``env_kwargs`` for the
  training env only (e.g. harder pushes), while the evaluation env keeps
  ``env_kwargs``;
* ``residual`` (optional): ``{"baseline": name, "scale": s}``, optionally
  with ``"kwargs"`` (the baseline's keyword arguments) and ``"actuators"``
  (name parts: the policy acts on those joints only): the policy's action is
  added (times s) to a controller of ``ragdoll_env.baselines`` and the sum
  clipped (:mod:`ragdoll_env.residual`); absent or null: the policy acts
  alone;
* ``eval``: ``freq`` (timesteps between evaluations; 0: none, so no
  ``best_model.zip``), ``episodes``, ``num_envs`` of the separate
  evaluation env and, optionally, ``env_kwargs`` merged over the entry's
  ``env_kwargs`` for that env only (e.g. harder pushes, so that
  ``best_model.zip`` is the model best at them);
* ``checkpoint_freq``: timesteps between checkpoints (0: none but the one
  saved at the end of each session, or at Ctrl-C);
* ``policy_warmup_steps`` (optional, default 0): for the rollouts collected
  in the first that many timesteps the PPO updates train the critic only
  (the actor's parameters frozen), so the first policy updates follow
  advantages of a fitted value function rather than of a random one.

Starting points (RL Baselines3 Zoo, ``hyperparams/ppo.yml``):

* the pendulums follow the Zoo's InvertedPendulum/InvertedDoublePendulum
  entries (normalised observations, short rollouts per env, batch 64,
  gae_lambda 0.8, gamma 0.98, 20 epochs, [64, 64] networks);
* Balance follows the Zoo's Humanoid entry (normalised observations,
  gae_lambda 0.95, ReLU [256, 256] networks; gamma 0.995, a 3.3 s horizon
  at Balance's 60 Hz control) with more worlds per rollout (128), a small
  step for the actor (lr 1e-4, target_kl 0.02; its critic at 3 times
  that, ``critic_lr_factor`` of :mod:`training.policies`), training
  episodes of push trials (``train_env_kwargs``), and learns a residual,
  bounded to 0.3 of each maximum torque, on the standing PD
  (``ragdoll_env.baselines.StandingPD``):
  ``training.train`` zeroes the action layer of a residual policy, so the
  first policy is the PD plus exploration noise (σ = 0.3 e^-1.8 ≈ 0.05 of
  each maximum torque). Until 2026-12-06 the entry had 32 worlds in one
  process, lr 3e-5, target_kl 0.01, the critic at 10x, σ e^-1.6, the
  residual at 0.1 and the default pushes in training
  (``docs/balance_pd_level.json`` restores it): its policies stayed level
  with the PD.

``--config PATH`` (JSON or YAML) is merged over the entry, key by key (nested
dicts merged recursively), e.g. ``{"ppo": {"learning_rate": 3e-4}}``; a key
that is none of the above (at the top level or in ``eval``) is an error
(:func:`check_override`).
"""

from __future__ import annotations

import copy

_PENDULUM_PPO = {
    "policy": "MlpPolicy",
    "n_steps": 128,          # x num_envs 16 = 2048 transitions per rollout
    "batch_size": 64,
    "n_epochs": 20,
    "gamma": 0.98,
    "gae_lambda": 0.8,
    "learning_rate": 1e-3,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
    "policy_kwargs": {"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "activation_fn": "tanh"},
}

CONFIGS = {
    "Ragdoll/InvertedPendulum-v0": {
        "num_envs": 16,       # the batched core steps 16 worlds ~10x faster than 16 single envs
        "timesteps": 100_000,
        "ppo": copy.deepcopy(_PENDULUM_PPO),
        "normalize": {"norm_obs": True, "norm_reward": False, "clip_obs": 10.0, "gamma": 0.98},
        "env_kwargs": {},
        "eval": {"freq": 10_000, "episodes": 8, "num_envs": 8},
        "checkpoint_freq": 20_000,
    },
    "Ragdoll/InvertedDoublePendulum-v0": {
        "num_envs": 16,
        "timesteps": 500_000,
        "ppo": {**copy.deepcopy(_PENDULUM_PPO), "learning_rate": 3e-4},
        "normalize": {"norm_obs": True, "norm_reward": True, "clip_obs": 10.0, "gamma": 0.98},
        "env_kwargs": {},
        "eval": {"freq": 20_000, "episodes": 8, "num_envs": 8},
        "checkpoint_freq": 50_000,
    },
    "Ragdoll/Balance-v0": {
        "num_envs": 128,
        "threads": None,         # physics threads: all cores
        "timesteps": 5_000_000,
        "ppo": {
            "policy": "MlpPolicy",
            "n_steps": 64,       # x num_envs 128 = 8192 transitions per rollout
            "batch_size": 512,
            "n_epochs": 5,
            "gamma": 0.995,     # 200 steps, 3.3 s at 60 Hz (0.99 at the former 30 Hz)
            "gae_lambda": 0.95,
            # The actor at 1e-4 with target_kl 0.02, the critic at 3 times that: at 3e-5 and 0.01
            # with the critic at 10x (the config until 2026-12-06) the policy stayed level with the
            # PD it starts from; at 2.5e-4 (30 Hz, 0.7 s episodes) it wrecked the PD within 3
            # minutes. docs/balance_training.md has every run.
            "learning_rate": 1e-4,
            "target_kl": 0.02,
            "clip_range": 0.2,
            "ent_coef": 0.0,
            "vf_coef": 0.5,
            "max_grad_norm": 0.5,
            # σ e^-1.8 = 0.17 of the residual's range, 0.05 of each maximum torque.
            "policy_kwargs": {"net_arch": {"pi": [256, 256], "vf": [256, 256]}, "activation_fn": "relu",
                              "log_std_init": -1.8, "ortho_init": True, "critic_lr_factor": 3},
        },
        "normalize": {"norm_obs": True, "norm_reward": True, "clip_obs": 10.0, "gamma": 0.995},
        "env_kwargs": {},
        # Training episodes are push trials: 3 s with a push of 15-28 N·s every 1-1.5 s, where
        # the PD is at its limit (it falls from most chest pushes of 25 N·s). The evaluations
        # keep the default env (20 s, 5-20 N·s every 2-4 s).
        "train_env_kwargs": {"max_episode_steps": 180, "push_interval": [1.0, 1.5], "push_strength": [15, 28]},
        # Recorded with the run: runs that did not record lifted_ankle step on the PD before it (1.0).
        "residual": {"baseline": "standing_pd", "scale": 0.3, "kwargs": {"lifted_ankle": 0.25}},
        "eval": {"freq": 250_000, "episodes": 16, "num_envs": 16},
        "checkpoint_freq": 250_000,
    },
}


#: the keys an entry (and the top level of a --config file) may have
KEYS = ("num_envs", "threads", "timesteps", "ppo", "normalize", "env_kwargs", "train_env_kwargs", "residual", "eval",
        "checkpoint_freq", "policy_warmup_steps")
#: deprecated top-level keys still read (config files and runs written before), and what replaced them
DEPRECATED_KEYS = {"processes": "threads"}
#: the keys of ``eval``
EVAL_KEYS = ("freq", "episodes", "num_envs", "env_kwargs")
#: entries whose value is a mapping: True where null is allowed as well
MAPPINGS = {"ppo": False, "eval": False, "normalize": True, "env_kwargs": True, "train_env_kwargs": True,
            "residual": True}


def check_override(override: dict) -> None:
    """ValueError naming an unknown key of a --config mapping (at its top level
    or in ``eval``) and the valid ones, or an entry that must be a mapping and
    is not. The keys within ``ppo``, ``normalize``, ``env_kwargs`` and
    ``residual`` are checked where they are used (PPO, VecNormalize, the
    environment, :func:`ragdoll_env.residual.check_residual`)."""
    unknown = [k for k in override if k not in KEYS and k not in DEPRECATED_KEYS]
    if unknown:
        ppo_keys = {k for entry in CONFIGS.values() for k in entry["ppo"]}
        hint = " (PPO settings go under \"ppo\")" if ppo_keys & set(unknown) else ""
        raise ValueError(f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}{hint}; "
                         f"the top-level keys are {', '.join(KEYS)}")
    for key, nullable in MAPPINGS.items():
        if key in override and not (isinstance(override[key], dict) or (nullable and override[key] is None)):
            raise ValueError(f"{key!r} must be a mapping{' or null' if nullable else ''}, got {override[key]!r}")
    unknown = [k for k in override.get("eval") or {} if k not in EVAL_KEYS]
    if unknown:
        raise ValueError(f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} in "
                         f"\"eval\"; its keys are {', '.join(EVAL_KEYS)}")
    eval_kwargs = (override.get("eval") or {}).get("env_kwargs")
    if eval_kwargs is not None and not isinstance(eval_kwargs, dict):
        raise ValueError(f"'eval.env_kwargs' must be a mapping or null, got {eval_kwargs!r}")
    for key, kwargs in (("env_kwargs", override.get("env_kwargs")), ("train_env_kwargs", override.get("train_env_kwargs")),
                        ("eval.env_kwargs", eval_kwargs)):
        for name in ("threads", "processes"):
            if name in (kwargs or {}):
                raise ValueError(f"{name} goes at the top level of the config, not in {key!r}: "
                                 f"{{\"threads\": N}} steps the training and the evaluation env alike")


def upgrade(config: dict) -> dict:
    """A copy of ``config`` (a --config mapping, an entry or a run's recorded
    config) with the deprecated ``"processes": P`` (the worker processes of
    runs before the worlds stepped on threads) as ``"threads": min(P,
    NUMBA_NUM_THREADS)``. ValueError naming ``processes`` if P is not a whole
    number >= 1, or if ``threads`` is given as well."""
    if "processes" not in (config or {}):
        return config
    out = dict(config)
    value = out.pop("processes")
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"processes (deprecated: threads) must be a whole number >= 1, got {value!r}")
    if out.get("threads") is not None:
        raise ValueError(f"give threads only, not also processes, its deprecated alias (threads {out['threads']!r}, "
                         f"processes {value!r})")
    from engine import max_threads

    out["threads"] = min(value, max_threads())
    return out


def merge(base: dict, override: dict) -> dict:
    """A copy of ``base`` with ``override`` merged in, nested dicts recursively."""
    out = copy.deepcopy(base)
    for key, value in (override or {}).items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def get_config(env_id: str) -> dict:
    """A fresh copy of the tuned settings of a (resolved) environment id."""
    return copy.deepcopy(CONFIGS[env_id])
