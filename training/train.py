"""Train PPO (stable-baselines3) on a Ragdoll environment.

    python -m training.train Ragdoll/InvertedPendulum-v0 --timesteps 50000 --num-envs 8 --seed 0
    python -m training.train InvertedPendulum-v0 --out runs/ip --config my_overrides.yaml
    python -m training.train --resume runs/ip --timesteps 100000     # continue to 100k in total

The worlds are stepped as one batch by ``ragdoll_env.sb3`` (an SB3 VecEnv),
wrapped in VecMonitor (``monitor*.csv``) and VecNormalize. A run directory holds:

=========================  ==========================================================
config.json                env id, seed, number of envs, the resolved settings, the engine
                           settings the run was trained with (``training.evaluate`` warns
                           when it steps with others)
summary.json               the above + versions, timesteps, wall time, evaluation history
checkpoints/               ppo_<N>_steps.zip + ppo_vecnormalize_<N>_steps.pkl
best_model.zip             the EvalCallback's best model (+ best_vecnormalize.pkl)
final_model.zip            the model at the end (+ vecnormalize.pkl)
eval/evaluations.npz       the EvalCallback's history
tb/                        TensorBoard logs (tensorboard --logdir DIR/tb)
=========================  ==========================================================

Nothing is written before the environments and the model are built, so a
bad setting leaves no run behind. Ctrl-C saves the run as at its end (a
checkpoint at the step reached, the final model, the summary), prints how to
continue it with ``--resume DIR`` and exits with status 130.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from ragdoll_env.residual import check_residual

from . import common as C
from .configs import check_override, get_config, merge, upgrade


#: PPO settings a --config can change when resuming (the network is fixed by the checkpoint)
RESUMABLE_PPO_KEYS = ("learning_rate", "clip_range", "ent_coef", "vf_coef", "max_grad_norm", "n_epochs",
                      "batch_size", "gamma", "gae_lambda", "n_steps", "target_kl")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m training.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Ctrl-C saves a checkpoint at the step reached (and the final model and "
                                       "summary.json) and exits\nwith status 130; continue with --resume DIR.")
    p.add_argument("env_id", nargs="?", metavar="ENV_ID",
                   help="Ragdoll environment id, e.g. Ragdoll/InvertedPendulum-v0 (optional with --resume)")
    p.add_argument("--timesteps", type=C.positive_int, default=None,
                   help="total timesteps to reach (default: the env's config; with --resume the run's target)")
    p.add_argument("--num-envs", type=C.positive_int, default=None,
                   help="worlds stepped together (default: the config's; with --resume the run's)")
    C.add_sim_threads_argument(p, "physics threads stepping the worlds of the training and evaluation envs "
                                  "(config: threads); the same results bit for bit, only faster on several cores "
                                  "(default: the config's, all cores unless it names a count; with --resume the "
                                  "run's)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0; with --resume the run's)")
    p.add_argument("--out", default=None, help="run directory (default runs/<env-name>-<seed>)")
    p.add_argument("--resume", metavar="DIR", default=None,
                   help="continue the run in DIR from its last checkpoint (model + VecNormalize stats); "
                        "nothing to do (and nothing changed) when it already has --timesteps")
    p.add_argument("--config", metavar="PATH", default=None,
                   help="JSON/YAML merged over the env's settings in training/configs.py")
    p.add_argument("--eval-freq", type=C.non_negative_int, default=None,
                   help="timesteps between evaluations, 0 for none (config: eval.freq)")
    p.add_argument("--eval-episodes", type=C.positive_int, default=None,
                   help="episodes per evaluation (config: eval.episodes)")
    p.add_argument("--checkpoint-freq", type=C.non_negative_int, default=None,
                   help="timesteps between checkpoints, 0 for none but the one at the end of the session "
                        "or at Ctrl-C (config: checkpoint_freq)")
    p.add_argument("--threads", type=C.positive_int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--no-progress-bar", action="store_true", help="no tqdm/rich progress bar")
    p.add_argument("--verbose", type=int, default=0, choices=(0, 1, 2), help="SB3 verbosity (0, 1, 2)")
    return p


def _make_callbacks(run: Path, cfg: dict, num_envs: int, eval_env, history: dict | None) -> list:
    """The checkpoint callback and EvalCallback of a session (each left out when
    its frequency is 0); ``history`` (on resume) keeps the earlier evaluations."""
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

    class SaveVecNormalizeOnBest(BaseCallback):
        """Saves the training VecNormalize stats next to best_model.zip."""

        def _on_step(self) -> bool:
            vn = self.parent.model.get_vec_normalize_env()
            if vn is not None:
                vn.save(str(run / C.BEST_VECNORM))
            return True

    class CheckpointAfterUpdate(BaseCallback):
        """Every ``freq`` timesteps a checkpoint (``_save_checkpoint``), taken
        at the start of the next rollout: after PPO's update on the rollout
        that reached the step count, so that the model, its optimizer's
        moments and its VecNormalize statistics are those a resume goes on
        from. (SB3's CheckpointCallback saves within the rollout's last step,
        before that update, which a resume from it then never makes.)"""

        def __init__(self, freq: int):
            super().__init__()
            self.freq = freq
            self.next = None

        def _on_rollout_start(self) -> None:
            if self.next is None:  # the session's first rollout: the next multiple of freq after the start
                self.next = (self.num_timesteps // self.freq + 1) * self.freq
            elif self.num_timesteps >= self.next:
                _save_checkpoint(self.model, self.model.get_vec_normalize_env(), run, self.num_timesteps)
                self.next = (self.num_timesteps // self.freq + 1) * self.freq

        def _on_step(self) -> bool:
            return True

    callbacks = []
    if cfg["checkpoint_freq"] > 0:
        callbacks.append(CheckpointAfterUpdate(int(cfg["checkpoint_freq"])))
    if cfg["eval"]["freq"] > 0:
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
        callbacks.append(ev)
    return callbacks


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


def _make_envs(env_id, cfg, num_envs, seed, evaluation: bool = True):
    """(training VecMonitor, evaluation VecNormalize or None without
    ``evaluation``, VecNormalize settings). Nothing is written: the training
    VecMonitor logs its episodes once :func:`_log_episodes` gives it a file."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from ragdoll_env.residual import residual_vec_env
    from ragdoll_env.sb3 import make_sb3_vec_env

    env_kwargs = C.with_threads(cfg.get("env_kwargs") or {}, cfg.get("threads"))
    train_kwargs = {**env_kwargs, **(cfg.get("train_env_kwargs") or {})}  # threads never in it (check_override)
    venv = eval_venv = None
    try:
        venv = residual_vec_env(make_sb3_vec_env(env_id, num_envs=num_envs, seed=seed, **train_kwargs),
                                cfg.get("residual"))
        if evaluation:
            n_eval = int(cfg["eval"].get("num_envs", 1))
            eval_kwargs = {**env_kwargs, **(cfg["eval"].get("env_kwargs") or {})}  # no threads in it (check_override)
            eval_venv = residual_vec_env(make_sb3_vec_env(env_id, num_envs=n_eval, seed=seed + 100_000, **eval_kwargs),
                                         cfg.get("residual"))
    except (TypeError, ValueError, RuntimeError, OSError) as exc:
        for v in (venv, eval_venv):
            if v is not None:
                v.close()
        raise C.TrainingError(f"cannot build {env_id}: {exc}") from exc
    venv = VecMonitor(venv)
    norm = dict(cfg.get("normalize") or {})
    eval_env = None
    if evaluation:
        eval_env = VecNormalize(VecMonitor(eval_venv), training=False, norm_obs=norm.get("norm_obs", True),
                                norm_reward=False, clip_obs=norm.get("clip_obs", 10.0))
    return venv, eval_env, norm


def _log_episodes(monitor, path: Path, env_id: str) -> None:
    """Start writing the episodes of ``monitor`` (a VecMonitor made without a
    file) to ``path``, SB3's monitor CSV."""
    from stable_baselines3.common.monitor import ResultsWriter

    monitor.t_start = time.time()
    monitor.results_writer = ResultsWriter(str(path), header={"t_start": monitor.t_start, "env_id": env_id})


def _check_settings(cfg: dict) -> int:
    """Validate the run-level settings of a merged config (residual, eval,
    checkpoint and warm-up steps, physics threads) before anything is built;
    returns the policy warm-up steps."""
    try:
        check_residual(cfg.get("residual"))
    except ValueError as exc:
        raise C.TrainingError(f"bad residual settings in the config: {exc}") from exc
    cfg["eval"]["freq"] = C.whole_number(cfg["eval"].get("freq"), "eval.freq (timesteps, 0 for no evaluations)", 0)
    if cfg["eval"]["freq"] > 0:
        cfg["eval"]["episodes"] = C.whole_number(cfg["eval"].get("episodes"), "eval.episodes", 1)
        cfg["eval"]["num_envs"] = C.whole_number(cfg["eval"].get("num_envs", 1), "eval.num_envs", 1)
    cfg["checkpoint_freq"] = C.whole_number(cfg.get("checkpoint_freq"), "checkpoint_freq (timesteps, 0 for none)", 0)
    cfg["threads"] = C.physics_threads(cfg.get("threads"), "threads (physics threads per env)")
    warmup = cfg.get("policy_warmup_steps")
    return 0 if warmup is None else C.whole_number(warmup, "policy_warmup_steps (timesteps)", 0)


def _save_atomic(save, path: Path) -> None:
    """``save(str(tmp))`` then rename to ``path``: never a half-written file."""
    tmp = path.with_name(path.name + ".tmp")
    save(str(tmp))
    os.replace(tmp, path)


def _save_checkpoint(model, vecnorm, run: Path, steps: int) -> Path:
    """The model and its VecNormalize statistics as a checkpoint (what
    --resume loads), the statistics first, replacing any of the same step
    count; returns the model's path."""
    ckdir = run / C.CHECKPOINT_DIR
    ckdir.mkdir(exist_ok=True)
    path = ckdir / f"{C.CHECKPOINT_PREFIX}_{steps}_steps.zip"
    _save_atomic(vecnorm.save, ckdir / f"{C.CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl")
    _save_atomic(model.save, path)
    return path


def _stored_summary(run: Path, env_id: str, steps: int, total: int) -> dict:
    """The run's summary.json (when readable), else the little known about it."""
    try:
        summary = C.floats_from_json(json.loads((run / C.SUMMARY_FILE).read_text()))
    except (OSError, ValueError):
        summary = {"env_id": env_id, "num_timesteps": steps, "timesteps_requested": total}
    summary["run_dir"] = str(run)
    return summary


def _close_progress_bar(callback) -> None:
    pbar = getattr(callback, "pbar", None)
    if pbar is not None:
        pbar.close()


def train(args) -> dict:
    """Run one training session from parsed ``args``; returns the summary dict.
    Raises :class:`training.common.TrainingInterrupted` after saving the run
    when interrupted (Ctrl-C)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import ProgressBarCallback
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(int(args.threads))
    started = time.time()
    start_stamp = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    override = C.load_config_file(args.config) if args.config else {}
    try:
        check_override(override)
        override = upgrade(override)  # a deprecated "processes" as "threads"
    except ValueError as exc:
        raise C.TrainingError(f"config file {str(args.config)!r}: {exc}") from exc

    if args.resume:
        run = C.require_run_dir(args.resume)
        saved = C.read_run_config(run)
        env_id = saved["env_id"]
        if args.env_id is not None and C.resolve_env_id(args.env_id) != env_id:
            raise C.TrainingError(f"--resume {str(run)!r} is a run of {env_id}, not {args.env_id!r}")
        cfg = merge(saved["config"], override)
        seed = saved["seed"] if args.seed is None else args.seed
        num_envs = saved["num_envs"] if args.num_envs is None else args.num_envs
        total = saved["timesteps"] if args.timesteps is None else args.timesteps
        sessions = list(saved.get("sessions", []))
        done, model_path, vn_path = C.last_checkpoint(run)
    else:
        if args.env_id is None:
            raise C.TrainingError("ENV_ID is required (or --resume DIR); known Ragdoll ids: "
                                  + ", ".join(C.known_env_ids()))
        env_id = C.resolve_env_id(args.env_id)
        cfg = merge(get_config(env_id), override)
        seed = 0 if args.seed is None else args.seed
        num_envs = C.whole_number(cfg["num_envs"], "num_envs", 1) if args.num_envs is None else args.num_envs
        total = C.whole_number(cfg["timesteps"], "timesteps", 1) if args.timesteps is None else args.timesteps
        run = Path(args.out) if args.out else Path("runs") / f"{C.env_slug(env_id)}-{seed}"
        if run.exists() and not run.is_dir():
            raise C.TrainingError(f"--out {str(run)!r} is a file, not a directory")
        models = C.saved_models(run)
        if models:
            raise C.TrainingError(f"run directory {str(run)!r} already holds a run ({models[-1]}); continue it "
                                  f"with --resume {run} or choose another --out")
        sessions = []
    if args.eval_freq is not None:
        cfg["eval"]["freq"] = args.eval_freq
    if args.eval_episodes is not None:
        cfg["eval"]["episodes"] = args.eval_episodes
    if args.checkpoint_freq is not None:
        cfg["checkpoint_freq"] = args.checkpoint_freq
    if args.sim_threads is not None:
        cfg["threads"] = args.sim_threads
    warmup = _check_settings(cfg)
    if args.resume and total <= done:
        print(f"{run}: already at {done} timesteps, the requested total is {total}: nothing to do, the run is "
              f"unchanged (continue it with --timesteps N, N > {done})")
        return _stored_summary(run, env_id, done, saved["timesteps"])
    cfg["num_envs"] = num_envs
    policy, ppo_kwargs = C.ppo_arguments(cfg["ppo"])
    if args.resume:
        # The model's own settings (its policy, network, critic rate) come from its file.
        fixed = sorted(k for k in cfg["ppo"] if k not in RESUMABLE_PPO_KEYS
                       and cfg["ppo"][k] != (saved["config"].get("ppo") or {}).get(k))
        if fixed:
            raise C.TrainingError(f"--resume {str(run)!r}: {', '.join(fixed)} cannot change once a run has a "
                                  f"model; a --config given with --resume may change "
                                  f"{', '.join(RESUMABLE_PPO_KEYS)}")

    # build everything before writing anything: a bad setting leaves no run behind
    venv, eval_env, norm = _make_envs(env_id, cfg, num_envs, seed, evaluation=cfg["eval"]["freq"] > 0)
    try:
        if args.resume:
            vecnorm = C.load_vecnormalize(vn_path, venv)
            vecnorm.training, vecnorm.norm_reward = True, bool(norm.get("norm_reward", vecnorm.norm_reward))
            # scalar PPO settings of a --config given with --resume replace the saved ones
            changed = {k: v for k, v in (override.get("ppo") or {}).items() if k in RESUMABLE_PPO_KEYS}
            model = C.load_ppo(model_path, env=vecnorm, custom_objects=changed or None)
            model.set_random_seed(seed + model.num_timesteps)
            model.tensorboard_log = str(run / "tb")
            resumed_from = str(model_path)
        else:
            try:
                vecnorm = VecNormalize(venv, **norm)
            except (TypeError, ValueError) as exc:
                raise C.TrainingError(f"bad normalize settings in the config: {exc}") from exc
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
    except BaseException:
        venv.close()
        if eval_env is not None:
            eval_env.close()
        raise
    if eval_env is not None:
        eval_env.obs_rms = vecnorm.obs_rms  # shared (EvalCallback also syncs before each evaluation)

    start_steps = int(model.num_timesteps)
    history = read_evaluations(run) if args.resume else None
    if not args.resume and (run / C.CONFIG_FILE).exists():
        print(f"{run}: its {C.CONFIG_FILE} is of a run that stopped before its first checkpoint; starting afresh")
    run.mkdir(parents=True, exist_ok=True)
    settings = C.engine_settings(venv)
    if args.resume:
        changed = C.settings_changes(saved.get("engine_settings"), settings)
        if changed:
            warnings.warn(f"{run}: resumed with engine settings other than the run's first session's "
                          f"(field: (recorded, now)): {changed}", stacklevel=2)
    run_cfg = {"env_id": env_id, "seed": seed, "num_envs": num_envs, "timesteps": total, "config": cfg,
               "engine_settings": saved.get("engine_settings") if args.resume else settings,
               "sessions": sessions}
    C.write_json(run / C.CONFIG_FILE, run_cfg)
    _log_episodes(venv, run / f"train_{len(sessions)}.monitor.csv", env_id)

    callbacks = _make_callbacks(run, cfg, num_envs, eval_env, history)
    if warmup > start_steps:
        callbacks.append(policy_warmup_callback(warmup))
    progress = None if args.no_progress_bar else ProgressBarCallback()
    interrupted = False
    try:
        model.learn(total_timesteps=total - start_steps, callback=callbacks + ([progress] if progress else []),
                    tb_log_name="PPO", reset_num_timesteps=not args.resume, progress_bar=False)
    except KeyboardInterrupt:  # Ctrl-C: save the run as at its end, then say how to continue it
        interrupted = True
    finally:
        _close_progress_bar(progress)

    with C.sigint_ignored():  # a second Ctrl-C must not cut the saving short
        end_steps = int(model.num_timesteps)
        _save_atomic(vecnorm.save, run / C.FINAL_VECNORM)
        _save_atomic(model.save, run / C.FINAL_MODEL)
        ckpt = _save_checkpoint(model, vecnorm, run, end_steps)
        wall = time.time() - started
        sessions.append({"started": start_stamp, "start_timesteps": start_steps, "end_timesteps": end_steps,
                         "wall_time_s": round(wall, 3), "resumed_from": resumed_from, "interrupted": interrupted})
        run_cfg["sessions"] = sessions
        C.write_json(run / C.CONFIG_FILE, run_cfg)
        try:
            history = read_evaluations(run)
        except C.TrainingError:
            if not interrupted:
                raise
            history = None  # cut mid-write by the Ctrl-C
        evals = evaluation_summary(history)
        files = {"final_model": C.FINAL_MODEL, "vecnormalize": C.FINAL_VECNORM, "best_model": C.BEST_MODEL,
                 "best_vecnormalize": C.BEST_VECNORM, "checkpoints": C.CHECKPOINT_DIR,
                 "evaluations": f"{C.EVAL_DIR}/evaluations.npz", "tensorboard": "tb"}
        summary = {
            "env_id": env_id,
            "seed": seed,
            "num_envs": num_envs,
            "timesteps_requested": total,
            "num_timesteps": end_steps,
            "interrupted": interrupted,
            "wall_time_s": round(wall, 3),
            "total_wall_time_s": round(sum(s["wall_time_s"] for s in sessions), 3),
            "steps_per_second": round((end_steps - start_steps) / wall, 1) if wall > 0 else None,
            "sessions": sessions,
            "config": cfg,
            "versions": C.versions(),
            "evaluations": evals,
            "best_mean_return": max(evals["mean_return"]) if evals["mean_return"] else None,
            "final_eval_mean_return": evals["mean_return"][-1] if evals["mean_return"] else None,
            "files": {k: f for k, f in files.items() if (run / f).exists()},  # only those written
        }
        C.write_json(run / C.SUMMARY_FILE, summary)
    for env in (venv, eval_env):
        try:
            if env is not None:
                env.close()
        except Exception:  # noqa: BLE001 - closing may fail after Ctrl-C; the run is saved anyway
            if not interrupted:
                raise
    summary["run_dir"] = str(run)
    if interrupted:
        raise C.TrainingInterrupted(f"{env_id} stopped at {end_steps} of {total} timesteps; saved "
                                    f"{ckpt.relative_to(run)} in {run}; continue with: "
                                    f"python -m training.train --resume {run}", summary)
    print(f"{env_id}: {end_steps} timesteps in {wall:.1f} s -> {run}"
          + (f"; last eval mean return {summary['final_eval_mean_return']:.2f}"
             if summary["final_eval_mean_return"] is not None else ""))
    return summary


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: train(args))


if __name__ == "__main__":
    main()
