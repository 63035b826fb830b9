"""PPO time to solve: Ragdoll/InvertedPendulum-v0 against MuJoCo's InvertedPendulum-v5.

::

    python -m benchmarks.ppo_pendulum                       # seeds 0 1 2, both engines
    python -m benchmarks.ppo_pendulum --seeds 0 --json ppo.json

Both environments are trained with the same PPO configuration (the
``Ragdoll/InvertedPendulum-v0`` entry of ``training/configs.py``: 16 worlds,
VecNormalize on observations, the RL Zoo's pendulum hyperparameters), the
same seed and one torch thread. Ours runs as one batched SB3 VecEnv
(``ragdoll_env.sb3``); MuJoCo's as SB3's ``make_vec_env`` of 16 Gymnasium
envs (DummyVecEnv, the usual way it is trained).

Solved: the mean return of ``--eval-episodes`` deterministic evaluation
episodes (fresh worlds, seed + 100000, the training VecNormalize statistics)
reaches ``--threshold`` (95%) of the maximum, 1000 for both ids. Evaluation
runs every ``--eval-freq`` environment steps and its wall time is excluded:
``solved_at_wall_s`` is the training loop's own time (environment stepping plus
PPO updates) up to that evaluation; ``solved_at_steps`` the environment steps.
A run that does not solve within ``--max-steps`` reports null for both.

JSON (``--json PATH``): a list of rows with ``env_id``, ``engine``, ``seed``,
``solved_at_steps``, ``solved_at_wall_s``, ``final_eval_return``,
``train_wall_s`` and ``env_steps``.
"""

from __future__ import annotations

import argparse
import copy
import math
import statistics
import time

import numpy as np

from .common import machine_note, nonnegative_int, positive_int, print_table, write_json

RAGDOLL_ID = "Ragdoll/InvertedPendulum-v0"
MUJOCO_ID = "InvertedPendulum-v5"
MAX_RETURN = 1000.0  # both: reward 1 per step, 1000 steps


def _ppo_config():
    from training.configs import get_config

    return copy.deepcopy(get_config(RAGDOLL_ID))


def _make_venvs(engine: str, num_envs: int, n_eval: int, seed: int):
    if engine == "ragdoll":
        from ragdoll_env.sb3 import make_sb3_vec_env

        return (make_sb3_vec_env(RAGDOLL_ID, num_envs=num_envs, seed=seed),
                make_sb3_vec_env(RAGDOLL_ID, num_envs=n_eval, seed=seed + 100_000))
    from stable_baselines3.common.env_util import make_vec_env

    return (make_vec_env(MUJOCO_ID, n_envs=num_envs, seed=seed),
            make_vec_env(MUJOCO_ID, n_envs=n_eval, seed=seed + 100_000))


def _evaluate(model, train_norm, eval_venv, episodes: int) -> float:
    """Mean return of ``episodes`` deterministic episodes, observations
    normalised with the training statistics."""
    returns = []
    obs = eval_venv.reset()
    ep = np.zeros(eval_venv.num_envs)
    while len(returns) < episodes:
        action, _ = model.predict(train_norm.normalize_obs(obs), deterministic=True)
        obs, reward, done, _ = eval_venv.step(action)
        ep += reward
        for i in np.flatnonzero(done):
            returns.append(float(ep[i]))
            ep[i] = 0.0
    return float(np.mean(returns[:episodes]))


def train_until_solved(engine: str, seed: int, max_steps: int, eval_freq: int, eval_episodes: int,
                       threshold: float) -> dict:
    """One PPO run; returns the row described in the module docstring."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecNormalize

    from training.common import ppo_arguments

    torch.set_num_threads(1)
    cfg = _ppo_config()
    num_envs = int(cfg["num_envs"])
    venv, eval_venv = _make_venvs(engine, num_envs, int(cfg["eval"]["num_envs"]), seed)
    norm = dict(cfg["normalize"])
    venv = VecNormalize(venv, **norm)
    policy, ppo = ppo_arguments(cfg["ppo"])
    model = PPO(policy, venv, seed=seed, device="cpu", verbose=0, **ppo)
    model.set_logger(Logger(folder=None, output_formats=[]))  # SB3's default makes a /tmp/SB3-<date> folder per run
    result = {"solved_at_steps": None, "solved_at_wall_s": None, "final_eval_return": None}

    class SolveCheck(BaseCallback):
        def __init__(self):
            super().__init__()
            self.next_eval = eval_freq
            self.eval_wall = 0.0
            self.t0 = time.perf_counter()

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_eval:
                return True
            self.next_eval += eval_freq
            t = time.perf_counter()
            mean = _evaluate(self.model, venv, eval_venv, eval_episodes)
            self.eval_wall += time.perf_counter() - t
            result["final_eval_return"] = mean
            if mean >= threshold * MAX_RETURN:
                result["solved_at_steps"] = int(self.num_timesteps)
                result["solved_at_wall_s"] = time.perf_counter() - self.t0 - self.eval_wall
                return False
            return True

    check = SolveCheck()
    model.learn(total_timesteps=max_steps, callback=check)
    train_wall = time.perf_counter() - check.t0 - check.eval_wall
    venv.close()
    eval_venv.close()
    return {"env_id": RAGDOLL_ID if engine == "ragdoll" else MUJOCO_ID, "engine": engine, "seed": seed,
            **result, "train_wall_s": train_wall, "env_steps": int(model.num_timesteps)}


def _fraction(text: str) -> float:
    """argparse type: a finite number >= 0 (above 1: never solved, the run goes to --max-steps)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="python -m benchmarks.ppo_pendulum", description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=nonnegative_int, nargs="+", default=[0, 1, 2])
    p.add_argument("--engines", nargs="+", choices=("ragdoll", "mujoco"), default=["ragdoll", "mujoco"])
    p.add_argument("--max-steps", type=positive_int, default=100_000, help="environment steps before giving up")
    p.add_argument("--eval-freq", type=positive_int, default=2_048, help="environment steps between evaluations")
    p.add_argument("--eval-episodes", type=positive_int, default=10)
    p.add_argument("--threshold", type=_fraction, default=0.95,
                   help="fraction of the maximum return that counts as solved (>= 0; above 1 never)")
    p.add_argument("--json", metavar="PATH")
    return p.parse_args(argv)


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def main(argv=None) -> int:
    args = parse_args(argv)
    if "mujoco" in args.engines:
        try:
            import mujoco  # noqa: F401
        except ImportError as exc:
            raise SystemExit(f"MuJoCo is not installed ({exc}); pip install -e '.[bench]' or --engines ragdoll")
    rows = []
    for seed in args.seeds:
        for engine in args.engines:
            row = train_until_solved(engine, seed, args.max_steps, args.eval_freq, args.eval_episodes,
                                     args.threshold)
            rows.append(row)
            print(f"{row['env_id']} seed {seed}: solved at {row['solved_at_steps']} steps, "
                  f"{row['solved_at_wall_s'] if row['solved_at_wall_s'] is None else round(row['solved_at_wall_s'], 1)} s",
                  flush=True)
    cols = ["env_id", "engine", "seed", "solved_at_steps", "solved_at_wall_s", "final_eval_return", "train_wall_s",
            "env_steps"]
    print_table(rows, [(c, c) for c in cols], title="PPO time to solve (same config, same seeds)")
    summary = []
    for engine in args.engines:
        mine = [r for r in rows if r["engine"] == engine]
        summary.append({"engine": engine, "solved": f"{sum(r['solved_at_steps'] is not None for r in mine)}/{len(mine)}",
                        "median_steps": _median([r["solved_at_steps"] for r in mine]),
                        "median_wall_s": _median([r["solved_at_wall_s"] for r in mine])})
    if len(summary) == 2 and all(s["median_wall_s"] for s in summary):
        ratio = summary[1]["median_wall_s"] / summary[0]["median_wall_s"]
        summary[0]["mujoco_wall_over_ours"] = ratio
    print_table(summary, [(c, c) for c in summary[0]], title="medians over seeds (wall ratio > 1: ours solves faster)")
    print(machine_note())
    if args.json:
        write_json(args.json, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
