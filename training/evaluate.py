"""Evaluate a trained run against the shipped baselines.

    python -m training.evaluate runs/InvertedPendulum-v0-0 --episodes 20 --json eval.json
    python -m training.evaluate runs/Balance-v0-0 --push-strength 10 30 --push-interval 1 3
    python -m training.evaluate runs/ip --video videos/ --video-episodes 2

Loads ``best_model.zip`` (else ``final_model.zip``, else the last checkpoint)
and its VecNormalize statistics, runs ``--episodes`` episodes on the batched
SB3 VecEnv with the run's environment settings (plus the push options given
here), and reports mean and std of the return, mean episode length, fall rate
(episodes terminated before the time limit) and, where the environment counts
them, pushes and pushes survived; the same for the baselines of
``ragdoll_env.baselines`` (zero torque; PD standing for Balance; LQR and PD
for the pendulums) on the same seeds. A run trained as a residual on a
baseline (its config's ``residual``, see :mod:`ragdoll_env.residual`) is
evaluated the same way: the policy's action added to the baseline's.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import common as C


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m training.evaluate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run directory written by python -m training.train")
    p.add_argument("--episodes", type=C.positive_int, default=20, help="episodes per controller (default 20)")
    C.add_model_argument(p)
    p.add_argument("--json", metavar="PATH", default=None, help="write the results as JSON here")
    p.add_argument("--video", metavar="DIR", default=None,
                   help="record the agent with gymnasium's RecordVideo (render_mode='rgb_array') into DIR")
    p.add_argument("--video-episodes", type=C.positive_int, default=1,
                   help="episodes to record with --video (default 1)")
    p.add_argument("--stochastic", dest="deterministic", action="store_false",
                   help="sample actions from the policy (default: its mean action, as SB3's evaluate_policy and "
                        "the training run's evaluations)")
    p.add_argument("--deterministic", dest="deterministic", action="store_true",
                   help="act with the policy's mean action (the default)")
    p.add_argument("--seed", type=int, default=12345, help="seed of the evaluation worlds (default 12345)")
    p.add_argument("--num-envs", type=C.positive_int, default=8,
                   help="worlds stepped together, at most --episodes (default 8)")
    p.add_argument("--push-strength", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="push impulse range in N·s (Balance; 0 0 disables pushes)")
    p.add_argument("--push-interval", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="seconds between pushes")
    p.add_argument("--max-episode-steps", type=C.positive_int, default=None, help="override the episode length")
    p.add_argument("--no-baselines", action="store_true", help="evaluate the agent only")
    p.add_argument("--threads", type=C.positive_int, default=1, help="torch CPU threads (default 1)")
    C.add_sim_threads_argument(p)
    return p


def _pushes_enabled(venv) -> bool:
    core = getattr(venv, "core", None) or getattr(getattr(venv, "venv", None), "core", None)
    return bool(getattr(core, "pushes_enabled", False))


def rollout(venv, act, episodes: int) -> dict:
    """Run ``episodes`` episodes on an SB3 VecEnv with ``act(obs) -> actions``;
    episodes are spread over the worlds as in SB3's evaluate_policy."""
    n = venv.num_envs
    targets = np.array([(episodes + i) // n for i in range(n)])
    counts = np.zeros(n, dtype=int)
    ret = np.zeros(n)
    length = np.zeros(n, dtype=int)
    rows = []
    obs = venv.reset()
    while (counts < targets).any():
        obs, reward, done, infos = venv.step(act(obs))
        ret += reward
        length += 1
        for i in np.flatnonzero(done):
            if counts[i] < targets[i]:
                info = infos[i]
                rows.append({
                    "return": float(ret[i]),
                    "length": int(length[i]),
                    "fell": not bool(info.get("TimeLimit.truncated", False)),
                    "pushes": info.get("pushes"),
                    "pushes_survived": info.get("pushes_survived"),
                    "nonfinite": bool(info.get("nonfinite", False)),
                })
                counts[i] += 1
            ret[i], length[i] = 0.0, 0
    return summarize(rows, pushes=_pushes_enabled(venv))


def summarize(rows, pushes: bool = True) -> dict:
    r = np.array([x["return"] for x in rows], dtype=float)
    out = {
        "episodes": len(rows),
        "mean_return": float(r.mean()) if len(r) else float("nan"),
        "std_return": float(r.std()) if len(r) else float("nan"),
        "mean_length": float(np.mean([x["length"] for x in rows])) if rows else float("nan"),
        "fall_rate": float(np.mean([x["fell"] for x in rows])) if rows else float("nan"),
        "returns": r.tolist(),
        "lengths": [x["length"] for x in rows],
    }
    if pushes and rows and all(x["pushes"] is not None for x in rows):
        pushes = np.array([x["pushes"] for x in rows], dtype=float)
        survived = np.array([x["pushes_survived"] for x in rows], dtype=float)
        out["mean_pushes"] = float(pushes.mean())
        out["mean_pushes_survived"] = float(survived.mean())
        out["push_survival_rate"] = float(survived.sum() / pushes.sum()) if pushes.sum() > 0 else None
    if any(x["nonfinite"] for x in rows):
        out["nonfinite_episodes"] = int(sum(x["nonfinite"] for x in rows))
    return out


def baseline_names(env_id: str) -> list[str]:
    if env_id == "Ragdoll/Balance-v0":
        return ["zero", "standing_pd"]
    return ["zero", "pendulum_pd", "lqr"]


def _make_venv(env_id, num_envs, seed, env_kwargs, threads=None):
    from ragdoll_env.sb3 import make_sb3_vec_env

    try:
        return make_sb3_vec_env(env_id, num_envs=num_envs, seed=seed, **C.with_threads(env_kwargs, threads))
    except (TypeError, ValueError) as exc:
        raise C.TrainingError(f"cannot build {env_id} with {env_kwargs}: {exc}") from exc


@dataclass
class Agent:
    """A run's evaluation model on a fresh batched env."""

    label: str             # best_model, final_model or checkpoint_N
    model_path: Path
    vecnorm_path: Path | None
    model: object          # the PPO model
    env: object            # what to roll out: the VecEnv under the residual wrapper and VecNormalize
    vecnorm: object | None
    venv: object           # the bare SB3 VecEnv of the batched core

    def act(self, obs, deterministic=True):
        return self.model.predict(obs, deterministic=deterministic)[0]


def load_agent(run, saved, num_envs, seed, env_kwargs, which="best", threads=None) -> Agent:
    """The run's ``which`` model (see :func:`training.common.model_for_evaluation`) on
    ``num_envs`` worlds seeded from ``seed`` (stepped on ``threads`` physics
    threads, None: all cores), with the run's residual baseline (if any) under its
    observation normalisation, as in training."""
    env_id = saved["env_id"]
    label, model_path, vn_path = C.model_for_evaluation(run, which)
    model = C.load_ppo(model_path)
    venv = _make_venv(env_id, num_envs, seed, env_kwargs, threads)
    try:
        if model.observation_space.shape != venv.observation_space.shape:
            raise C.TrainingError(f"{model_path} expects observations of shape {model.observation_space.shape}, "
                                  f"{env_id} gives {venv.observation_space.shape}")
        vecnorm = None
        env = _residual(venv, saved["config"].get("residual"))
        if vn_path is not None:
            vecnorm = C.load_vecnormalize(vn_path, env)
            vecnorm.training, vecnorm.norm_reward = False, False
            env = vecnorm
    except BaseException:
        venv.close()
        raise
    return Agent(label, model_path, vn_path, model, env, vecnorm, venv)


def _residual(venv, spec):
    from ragdoll_env.residual import residual_vec_env

    try:
        return residual_vec_env(venv, spec)
    except (TypeError, ValueError) as exc:
        raise C.TrainingError(f"bad residual settings in the run's config: {exc}") from exc


def record_video(env_id, env_kwargs, model, vecnorm, folder, episodes, deterministic, seed,
                 residual=None) -> list[str]:
    import gymnasium as gym
    from gymnasium.wrappers import RecordVideo

    import ragdoll_env  # noqa: F401 (registers the ids)
    from ragdoll_env.residual import ResidualAction

    env = gym.make(env_id, render_mode="rgb_array", **env_kwargs)
    if residual is not None:
        env = ResidualAction(env, residual)
    env = RecordVideo(env, str(folder), episode_trigger=lambda i: i < episodes, name_prefix="agent",
                      disable_logger=True)
    try:
        for ep in range(episodes):
            obs, _ = env.reset(seed=seed + ep)
            done = False
            while not done:
                o = vecnorm.normalize_obs(obs) if vecnorm is not None else obs
                action, _ = model.predict(o, deterministic=deterministic)
                obs, _, terminated, truncated, _ = env.step(action)
                done = terminated or truncated
    finally:
        env.close()
    return sorted(str(p) for p in Path(folder).glob("*.mp4"))


def evaluate(args) -> dict:
    import torch

    from ragdoll_env.baselines import make_baseline

    torch.set_num_threads(int(args.threads))
    if args.episodes < 1 or args.num_envs < 1:  # argparse checks both; this is for callers of the function
        raise C.TrainingError("--episodes and --num-envs must be >= 1")
    t0 = time.time()
    run = C.require_run_dir(args.run_dir)
    saved = C.read_run_config(run)
    env_id = saved["env_id"]
    env_kwargs = dict(saved["config"].get("env_kwargs") or {})
    if args.push_strength is not None:
        env_kwargs["push_strength"] = tuple(args.push_strength)
    if args.push_interval is not None:
        env_kwargs["push_interval"] = tuple(args.push_interval)
    if args.max_episode_steps is not None:
        env_kwargs["max_episode_steps"] = args.max_episode_steps
    num_envs = min(args.num_envs, args.episodes)  # no idle worlds

    residual = saved["config"].get("residual")
    threads = C.run_threads(args.sim_threads, saved)
    loaded = load_agent(run, saved, num_envs, args.seed, env_kwargs, args.model, threads)
    try:
        changed = C.settings_changes(saved.get("engine_settings"), C.engine_settings(loaded.venv))
        if changed:
            warnings.warn(f"{run} was trained with other engine settings than this evaluation steps with "
                          f"(field: (trained, now)): {changed}; give the trained values as env_kwargs in the run's "
                          f"config.json to evaluate as trained", stacklevel=2)
        agent = rollout(loaded.env, lambda obs: loaded.act(obs, args.deterministic), args.episodes)
    finally:
        loaded.env.close()
    result = {
        "run_dir": str(run),
        "env_id": env_id,
        "model": loaded.label,
        "model_path": str(loaded.model_path),
        "vecnormalize_path": str(loaded.vecnorm_path) if loaded.vecnorm_path else None,
        "model_timesteps": int(loaded.model.num_timesteps),
        "deterministic": bool(args.deterministic),
        "seed": args.seed,
        "env_kwargs": env_kwargs,
        "engine_settings_changed": {k: list(v) for k, v in changed.items()},
        "residual": residual,
        "max_return": getattr(loaded.venv, "max_return", None),
        **agent,
        "baselines": {},
    }

    if not args.no_baselines:
        for name in baseline_names(env_id):
            bvenv = _make_venv(env_id, num_envs, args.seed, env_kwargs, threads)
            try:
                ctrl = make_baseline(name, bvenv, **C.baseline_kwargs(name, residual, env_id))
                result["baselines"][name] = rollout(bvenv, ctrl.act, args.episodes)
            except Exception as exc:  # noqa: BLE001 - a broken baseline must not hide the agent's figures
                result["baselines"][name] = {"error": f"{type(exc).__name__}: {exc}"}
            finally:
                bvenv.close()

    if args.video:
        folder = Path(args.video)
        try:
            result["videos"] = record_video(env_id, env_kwargs, loaded.model, loaded.vecnorm, folder,
                                            args.video_episodes, args.deterministic, args.seed, residual)
        except Exception as exc:  # noqa: BLE001
            result["videos"] = []
            result["video_error"] = f"{type(exc).__name__}: {exc}"
    result["wall_time_s"] = round(time.time() - t0, 3)
    print_report(result)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        C.write_json(args.json, result)
    return result


def print_report(result) -> None:
    print(f"{result['env_id']}  {result['model']} ({result['model_timesteps']} timesteps)  "
          f"{result['episodes']} episodes  deterministic={result['deterministic']}")
    has_push = "mean_pushes" in result
    head = f"{'controller':<14}{'mean return':>13}{'std':>10}{'mean len':>10}{'fall rate':>11}"
    if has_push:
        head += f"{'pushes':>9}{'survived':>10}"
    print(head)
    rows = [("agent", result)] + list(result["baselines"].items())
    for name, r in rows:
        if "error" in r:
            print(f"{name:<14}  error: {r['error']}")
            continue
        line = (f"{name:<14}{r['mean_return']:>13.2f}{r['std_return']:>10.2f}{r['mean_length']:>10.1f}"
                f"{r['fall_rate']:>11.2f}")
        if has_push and "mean_pushes" in r:
            line += f"{r['mean_pushes']:>9.2f}{r['mean_pushes_survived']:>10.2f}"
        print(line)
    for field, (trained, now) in result.get("engine_settings_changed", {}).items():
        print(f"engine setting {field}: trained with {trained!r}, evaluated with {now!r}")
    if result.get("video_error"):
        print(f"video: {result['video_error']}")
    elif result.get("videos"):
        print("videos: " + ", ".join(result["videos"]))


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: evaluate(args))


if __name__ == "__main__":
    main()
