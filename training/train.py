"""Train PPO (stable-baselines3) on a Ragdoll environment.

    python -m training.train Ragdoll/InvertedPendulum-v0 --timesteps 50000 --num-envs 8 --seed 0
    python -m training.train InvertedPendulum-v0 --out runs/ip --config my_overrides.yaml
    python -m training.train --resume runs/ip --timesteps 100000     # continue to 100k in total

The worlds are stepped as one batch by ``ragdoll_env.sb3`` (an SB3 VecEnv),
wrapped in VecMonitor (``monitor*.csv``) and VecNormalize. A run directory holds:

=========================  ==========================================================
config.json                env id, seed, number of envs, the resolved settings
summary.json               the above + versions, timesteps, wall time, evaluation history
checkpoints/               ppo_<N>_steps.zip + ppo_vecnormalize_<N>_steps.pkl
best_model.zip             the EvalCallback's best model (+ best_vecnormalize.pkl)
final_model.zip            the model at the end (+ vecnormalize.pkl)
eval/evaluations.npz       the EvalCallback's history
tb/                        TensorBoard logs (tensorboard --logdir DIR/tb)
=========================  ==========================================================
"""

from __future__ import annotations

import argparse
import datetime as _dt
import time
from pathlib import Path

import numpy as np

from ragdoll_env.residual import check_residual

from . import common as C
from .configs import get_config, merge


#: PPO settings a --config can change when resuming (the network is fixed by the checkpoint)
RESUMABLE_PPO_KEYS = ("learning_rate", "clip_range", "ent_coef", "vf_coef", "max_grad_norm", "n_epochs",
                      "batch_size", "gamma", "gae_lambda", "n_steps", "target_kl")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m training.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("env_id", nargs="?", metavar="ENV_ID",
                   help="Ragdoll environment id, e.g. Ragdoll/InvertedPendulum-v0 (optional with --resume)")
    p.add_argument("--timesteps", type=int, default=None,
                   help="total timesteps to reach (default: the env's config; with --resume the run's target)")
    p.add_argument("--num-envs", type=int, default=None, help="worlds stepped together (default: the config's)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0; with --resume the run's)")
    p.add_argument("--out", default=None, help="run directory (default runs/<env-name>-<seed>)")
    p.add_argument("--resume", metavar="DIR", default=None,
                   help="continue the run in DIR from its last checkpoint (model + VecNormalize stats)")
    p.add_argument("--config", metavar="PATH", default=None,
                   help="JSON/YAML merged over the env's settings in training/configs.py")
    p.add_argument("--eval-freq", type=int, default=None, help="timesteps between evaluations (config: eval.freq)")
    p.add_argument("--eval-episodes", type=int, default=None, help="episodes per evaluation (config: eval.episodes)")
    p.add_argument("--checkpoint-freq", type=int, default=None, help="timesteps between checkpoints")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--no-progress-bar", action="store_true", help="no tqdm/rich progress bar")
    p.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")
    return p


def _make_callbacks(run: Path, cfg: dict, num_envs: int, eval_env, history: dict | None):
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback

    class SaveVecNormalizeOnBest(BaseCallback):
        """Saves the training VecNormalize stats next to best_model.zip."""

        def _on_step(self) -> bool:
            vn = self.parent.model.get_vec_normalize_env()
            if vn is not None:
                vn.save(str(run / C.BEST_VECNORM))
            return True

    ckpt = CheckpointCallback(save_freq=max(int(cfg["checkpoint_freq"]) // num_envs, 1),
                              save_path=str(run / C.CHECKPOINT_DIR), name_prefix=C.CHECKPOINT_PREFIX,
                              save_vecnormalize=True)
    ev = EvalCallback(eval_env, callback_on_new_best=SaveVecNormalizeOnBest(),
                      n_eval_episodes=int(cfg["eval"]["episodes"]),
                      eval_freq=max(int(cfg["eval"]["freq"]) // num_envs, 1),
                      log_path=str(run / C.EVAL_DIR), best_model_save_path=str(run), deterministic=True,
                      verbose=0)
    if history:  # resume: keep the earlier evaluations in evaluations.npz and the best so far
        ev.evaluations_timesteps = [int(t) for t in history["timesteps"]]
        ev.evaluations_results = [list(r) for r in history["results"]]
        ev.evaluations_length = [list(r) for r in history["ep_lengths"]]
        if len(history["results"]) and (run / C.BEST_MODEL).is_file():
            ev.best_mean_reward = float(np.max(np.mean(history["results"], axis=1)))
    return ckpt, ev


def actor_parameters(policy) -> list:
    """The parameters of an SB3 ActorCriticPolicy's actor (policy layers, action
    layer, log std), not the critic's (the features extractor has none)."""
    import torch

    params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
    log_std = getattr(policy, "log_std", None)
    return params + ([log_std] if isinstance(log_std, torch.nn.Parameter) else [])


def policy_warmup_callback(steps: int):
    """A callback freezing the actor for the first ``steps`` timesteps, so the
    PPO updates of those rollouts train only the critic (the actor's
    parameters get no gradient; the target_kl early stop does not trigger, as
    the policy does not change). A residual policy's first advantages would
    otherwise come from an untrained critic and push the PD off its tuning."""
    from stable_baselines3.common.callbacks import BaseCallback

    class PolicyWarmup(BaseCallback):
        def _on_rollout_end(self) -> None:  # just before PPO.train() on this rollout
            frozen = self.model.num_timesteps <= steps
            for p in actor_parameters(self.model.policy):
                p.requires_grad_(not frozen)

        def _on_step(self) -> bool:
            return True

    return PolicyWarmup()


def read_evaluations(run) -> dict | None:
    """The EvalCallback history of a run as lists, or None if there is none yet."""
    path = Path(run) / C.EVAL_DIR / "evaluations.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            return {k: data[k] for k in ("timesteps", "results", "ep_lengths")}
    except Exception as exc:  # noqa: BLE001
        raise C.TrainingError(f"cannot read {str(path)!r}: {exc}") from exc


def evaluation_summary(history) -> dict:
    if history is None:
        return {"timesteps": [], "mean_return": [], "std_return": [], "mean_length": []}
    res = np.asarray(history["results"], dtype=float)
    lens = np.asarray(history["ep_lengths"], dtype=float)
    return {
        "timesteps": [int(t) for t in history["timesteps"]],
        "mean_return": res.mean(axis=1).tolist() if res.size else [],
        "std_return": res.std(axis=1).tolist() if res.size else [],
        "mean_length": lens.mean(axis=1).tolist() if lens.size else [],
    }


def _make_envs(env_id, cfg, num_envs, seed, run: Path, monitor_name: str):
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from ragdoll_env.residual import residual_vec_env
    from ragdoll_env.sb3 import make_sb3_vec_env

    env_kwargs = dict(cfg.get("env_kwargs") or {})
    train_kwargs = {**env_kwargs, **(cfg.get("train_env_kwargs") or {})}
    try:
        venv = make_sb3_vec_env(env_id, num_envs=num_envs, seed=seed, **train_kwargs)
        n_eval = int(cfg["eval"].get("num_envs", 1))
        eval_venv = make_sb3_vec_env(env_id, num_envs=n_eval, seed=seed + 100_000, **env_kwargs)
        venv = residual_vec_env(venv, cfg.get("residual"))
        eval_venv = residual_vec_env(eval_venv, cfg.get("residual"))
    except (TypeError, ValueError) as exc:
        raise C.TrainingError(f"cannot build {env_id}: {exc}") from exc
    venv = VecMonitor(venv, filename=str(run / monitor_name))
    eval_venv = VecMonitor(eval_venv)
    norm = dict(cfg.get("normalize") or {})
    eval_env = VecNormalize(eval_venv, training=False, norm_obs=norm.get("norm_obs", True), norm_reward=False,
                            clip_obs=norm.get("clip_obs", 10.0))
    return venv, eval_env, norm


def train(args) -> dict:
    """Run one training session from parsed ``args``; returns the summary dict."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(max(int(args.threads), 1))
    started = time.time()
    start_stamp = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    override = C.load_config_file(args.config) if args.config else {}

    if args.resume:
        run = C.require_run_dir(args.resume)
        saved = C.read_run_config(run)
        env_id = saved["env_id"]
        if args.env_id is not None and C.resolve_env_id(args.env_id) != env_id:
            raise C.TrainingError(f"--resume {str(run)!r} is a run of {env_id}, not {args.env_id!r}")
        cfg = merge(saved["config"], override)
        seed = saved["seed"] if args.seed is None else args.seed
        num_envs = args.num_envs or saved["num_envs"]
        total = args.timesteps or saved["timesteps"]
        sessions = list(saved.get("sessions", []))
    else:
        if args.env_id is None:
            raise C.TrainingError("ENV_ID is required (or --resume DIR); known Ragdoll ids: "
                                  + ", ".join(C.known_env_ids()))
        env_id = C.resolve_env_id(args.env_id)
        cfg = merge(get_config(env_id), override)
        seed = 0 if args.seed is None else args.seed
        num_envs = args.num_envs or int(cfg["num_envs"])
        total = args.timesteps or int(cfg["timesteps"])
        run = Path(args.out) if args.out else Path("runs") / f"{C.env_slug(env_id)}-{seed}"
        if (run / C.CONFIG_FILE).exists():
            raise C.TrainingError(f"run directory {str(run)!r} already holds a run; continue it with "
                                  f"--resume {run} or choose another --out")
        sessions = []
    if args.eval_freq:
        cfg["eval"]["freq"] = args.eval_freq
    if args.eval_episodes:
        cfg["eval"]["episodes"] = args.eval_episodes
    if args.checkpoint_freq:
        cfg["checkpoint_freq"] = args.checkpoint_freq
    if num_envs < 1 or total < 1:
        raise C.TrainingError("--num-envs and --timesteps must be positive")
    try:
        check_residual(cfg.get("residual"))
    except ValueError as exc:
        raise C.TrainingError(f"bad residual settings in the config: {exc}") from exc
    warmup = cfg.get("policy_warmup_steps") or 0
    if isinstance(warmup, bool) or not isinstance(warmup, int) or warmup < 0:
        raise C.TrainingError(f"policy_warmup_steps must be a whole number of timesteps >= 0, got {warmup!r}")
    cfg["num_envs"] = num_envs
    run.mkdir(parents=True, exist_ok=True)
    run_cfg = {"env_id": env_id, "seed": seed, "num_envs": num_envs, "timesteps": total, "config": cfg,
               "sessions": sessions}
    C.write_json(run / C.CONFIG_FILE, run_cfg)

    ppo_kwargs = dict(cfg["ppo"])
    policy = ppo_kwargs.pop("policy", "MlpPolicy")
    ppo_kwargs["policy_kwargs"] = C.policy_kwargs(ppo_kwargs.get("policy_kwargs"))

    if args.resume:
        model_path, vn_path = C.last_checkpoint(run)
        venv, eval_env, norm = _make_envs(env_id, cfg, num_envs, seed, run, f"train_{len(sessions)}.monitor.csv")
        vecnorm = C.load_vecnormalize(vn_path, venv)
        vecnorm.training, vecnorm.norm_reward = True, bool(norm.get("norm_reward", vecnorm.norm_reward))
        # scalar PPO settings of a --config given with --resume replace the saved ones
        changed = {k: v for k, v in (override.get("ppo") or {}).items() if k in RESUMABLE_PPO_KEYS}
        model = C.load_ppo(model_path, env=vecnorm, custom_objects=changed or None)
        model.set_random_seed(seed + model.num_timesteps)
        model.tensorboard_log = str(run / "tb")
        resumed_from = str(model_path)
    else:
        venv, eval_env, norm = _make_envs(env_id, cfg, num_envs, seed, run, "train_0.monitor.csv")
        vecnorm = VecNormalize(venv, **norm)
        try:
            model = PPO(policy, vecnorm, seed=seed, device="cpu", tensorboard_log=str(run / "tb"),
                        verbose=args.verbose, **ppo_kwargs)
        except (TypeError, ValueError) as exc:
            raise C.TrainingError(f"bad PPO settings in the config: {exc}") from exc
        if cfg.get("residual"):
            # A residual policy starts as the baseline itself: zero mean action, only the
            # exploration noise on top (orthogonal init's 0.01 gain still gave mean torques
            # that felled the standing PD within a second).
            for p in model.policy.action_net.parameters():
                p.data.zero_()
        resumed_from = None
    eval_env.obs_rms = vecnorm.obs_rms  # shared (EvalCallback also syncs before each evaluation)

    start_steps = int(model.num_timesteps)
    remaining = total - start_steps
    history = read_evaluations(run) if args.resume else None
    if remaining > 0:
        callbacks = list(_make_callbacks(run, cfg, num_envs, eval_env, history))
        if warmup > model.num_timesteps:
            callbacks.append(policy_warmup_callback(warmup))
        model.learn(total_timesteps=remaining, callback=callbacks, tb_log_name="PPO",
                    reset_num_timesteps=not args.resume, progress_bar=not args.no_progress_bar)
    else:
        print(f"{run}: already at {start_steps} timesteps >= the requested {total}; nothing to do")

    end_steps = int(model.num_timesteps)
    model.save(str(run / C.FINAL_MODEL))
    vecnorm.save(str(run / C.FINAL_VECNORM))
    ckdir = run / C.CHECKPOINT_DIR
    ckdir.mkdir(exist_ok=True)
    final_ckpt = ckdir / f"{C.CHECKPOINT_PREFIX}_{end_steps}_steps.zip"
    if not final_ckpt.exists():
        model.save(str(final_ckpt))
        vecnorm.save(str(ckdir / f"{C.CHECKPOINT_PREFIX}_vecnormalize_{end_steps}_steps.pkl"))
    wall = time.time() - started
    sessions.append({"started": start_stamp, "start_timesteps": start_steps, "end_timesteps": end_steps,
                     "wall_time_s": round(wall, 3), "resumed_from": resumed_from})
    run_cfg["sessions"] = sessions
    C.write_json(run / C.CONFIG_FILE, run_cfg)
    evals = evaluation_summary(read_evaluations(run))
    summary = {
        "env_id": env_id,
        "seed": seed,
        "num_envs": num_envs,
        "timesteps_requested": total,
        "num_timesteps": end_steps,
        "wall_time_s": round(wall, 3),
        "total_wall_time_s": round(sum(s["wall_time_s"] for s in sessions), 3),
        "steps_per_second": round((end_steps - start_steps) / wall, 1) if wall > 0 else None,
        "sessions": sessions,
        "config": cfg,
        "versions": C.versions(),
        "evaluations": evals,
        "best_mean_return": max(evals["mean_return"]) if evals["mean_return"] else None,
        "final_eval_mean_return": evals["mean_return"][-1] if evals["mean_return"] else None,
        "files": {"final_model": C.FINAL_MODEL, "vecnormalize": C.FINAL_VECNORM,
                  "best_model": C.BEST_MODEL if (run / C.BEST_MODEL).exists() else None,
                  "checkpoints": C.CHECKPOINT_DIR, "evaluations": f"{C.EVAL_DIR}/evaluations.npz",
                  "tensorboard": "tb"},
    }
    C.write_json(run / C.SUMMARY_FILE, summary)
    venv.close()
    eval_env.close()
    print(f"{env_id}: {end_steps} timesteps in {wall:.1f} s -> {run}"
          + (f"; last eval mean return {summary['final_eval_mean_return']:.2f}"
             if summary["final_eval_mean_return"] is not None else ""))
    summary["run_dir"] = str(run)
    return summary


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: train(args))


if __name__ == "__main__":
    main()
