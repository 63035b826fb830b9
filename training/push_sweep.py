"""Push-strength sweep: how hard a push a trained Balance policy survives,
beside the standing PD baseline.

    python -m training.push_sweep runs/Balance-v0-1 --strengths 0 10 20 30 40 --episodes 20 \\
        --json docs/push_sweep.json --plot docs/push_sweep.png

For each strength s (N·s) every push of the episode has exactly that impulse
(``push_strength=(s, s)``; 0 disables pushes), at the run's push interval
unless ``--push-interval`` is given. The agent (the run's evaluation model,
with its residual baseline if it has one) and the baselines roll out the same
seeds. Reported per strength and controller: fall rate (episodes ended by a
fall before the time limit), mean episode length (s), and pushes survived /
pushes (a push is survived when the body is still standing
``push_recovery_time`` after it; a push in the episode's last
``push_recovery_time`` counts as not survived).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from . import common as C
from .evaluate import _make_venv, load_agent, rollout

BASELINES = ("standing_pd", "zero")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m training.push_sweep", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", metavar="RUN_DIR", help="a Ragdoll/Balance-v0 run written by python -m training.train")
    p.add_argument("--strengths", type=float, nargs="+", default=[0.0, 10.0, 20.0, 30.0, 40.0],
                   help="push impulses to sweep, N·s (default 0 10 20 30 40)")
    p.add_argument("--episodes", type=C.positive_int, default=20,
                   help="episodes per strength and controller (default 20)")
    p.add_argument("--push-interval", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="seconds between pushes (default: the run's)")
    p.add_argument("--baselines", nargs="*", default=list(BASELINES), choices=BASELINES,
                   help="baselines beside the agent (default: standing_pd zero)")
    p.add_argument("--seed", type=int, default=12345, help="seed of the evaluation worlds (default 12345)")
    p.add_argument("--num-envs", type=C.positive_int, default=10,
                   help="worlds stepped together, at most --episodes (default 10)")
    add_output_arguments(p)
    return p


@dataclass
class Controller:
    """One controller on its own batched env: the agent (``agent`` set) or a
    baseline."""

    name: str        # "agent" or a baseline's name
    env: object      # the SB3 VecEnv to roll out (the agent's under its residual wrapper and VecNormalize)
    core: object     # the batched core under it (pushes, dt)
    act: object      # obs -> actions
    agent: object = None


def controllers(run, saved, num_envs, seed, env_kwargs, baselines, deterministic, which="best", threads=None):
    """The run's agent, then each of ``baselines``, each on a fresh env of
    ``num_envs`` worlds seeded from ``seed`` with ``env_kwargs`` (so every
    one meets the same initial states), stepped on ``threads`` physics
    threads (None: all cores), closed once the caller moves on; ``which`` picks the run's
    model (:func:`training.common.model_for_evaluation`)."""
    from ragdoll_env.baselines import make_baseline

    agent = load_agent(run, saved, num_envs, seed, env_kwargs, which, threads)
    try:
        yield Controller("agent", agent.env, agent.venv.core, partial(agent.act, deterministic=deterministic), agent)
    finally:
        agent.env.close()
    env_id, residual = saved["env_id"], saved["config"].get("residual")
    for name in baselines:
        venv = _make_venv(env_id, num_envs, seed, env_kwargs, threads)
        try:
            ctrl = make_baseline(name, venv, **C.baseline_kwargs(name, residual, env_id))
            yield Controller(name, venv, venv.core, ctrl.act)
        finally:
            venv.close()


def add_output_arguments(p) -> None:
    """--model, --stochastic, --json, --plot, --threads and --sim-threads, as
    the push sweep and the push trials take them."""
    C.add_model_argument(p)
    p.add_argument("--stochastic", dest="deterministic", action="store_false",
                   help="sample the policy's actions (default: its mean action)")
    p.add_argument("--json", metavar="PATH", default=None, help="write the rows as JSON here")
    p.add_argument("--plot", metavar="PNG", default=None, help="plot fall rate against strength (matplotlib)")
    p.add_argument("--threads", type=C.positive_int, default=1, help="torch CPU threads (default 1)")
    C.add_sim_threads_argument(p)


def balance_run(run_dir) -> tuple:
    """(run directory, its config.json) of a Ragdoll/Balance-v0 run, else
    TrainingError."""
    run = C.require_run_dir(run_dir)
    saved = C.read_run_config(run)
    if saved["env_id"] != "Ragdoll/Balance-v0":
        raise C.TrainingError(f"{str(run)!r} is a run of {saved['env_id']}; pushes need a Ragdoll/Balance-v0 run")
    return run, saved


def sweep(args) -> dict:
    import torch

    torch.set_num_threads(int(args.threads))
    if args.episodes < 1 or args.num_envs < 1:  # argparse checks both; this is for callers of the function
        raise C.TrainingError("--episodes and --num-envs must be >= 1")
    if any(s < 0 for s in args.strengths):
        raise C.TrainingError(f"--strengths must be >= 0 N·s, got {args.strengths}")
    t0 = time.time()
    run, saved = balance_run(args.run_dir)
    threads = C.run_threads(args.sim_threads, saved)
    env_id = saved["env_id"]
    base_kwargs = dict(saved["config"].get("env_kwargs") or {})
    if args.push_interval is not None:
        base_kwargs["push_interval"] = tuple(args.push_interval)
    num_envs = min(args.num_envs, args.episodes)  # no idle worlds
    strengths = list(dict.fromkeys(args.strengths))
    rows, model_label, model_steps, episode_s = [], None, None, None
    for s in strengths:
        env_kwargs = {**base_kwargs, "push_strength": (s, s) if s > 0 else 0.0}
        results = {}
        for ctrl in controllers(run, saved, num_envs, args.seed, env_kwargs, args.baselines, args.deterministic,
                                args.model, threads):
            results[ctrl.name] = rollout(ctrl.env, ctrl.act, args.episodes)
            if ctrl.agent is not None:
                model_label, model_steps = ctrl.agent.label, int(ctrl.agent.model.num_timesteps)
                dt = ctrl.core.dt  # s per env step
                episode_s = ctrl.core.max_episode_steps * dt if ctrl.core.max_episode_steps else None
        for name, r in results.items():
            rows.append({
                "strength": s,
                "controller": name,
                "episodes": r["episodes"],
                "fall_rate": r["fall_rate"],
                "mean_length": r["mean_length"],
                "mean_length_s": r["mean_length"] * dt,
                "pushes": round(r.get("mean_pushes", 0.0) * r["episodes"]),
                "pushes_survived": round(r.get("mean_pushes_survived", 0.0) * r["episodes"]),
                "mean_return": r["mean_return"],
            })
        print_rows([x for x in rows if x["strength"] == s], header=(s == strengths[0]))
    result = {"run_dir": str(run), "env_id": env_id, "model": model_label, "model_timesteps": model_steps,
              "episodes": args.episodes, "seed": args.seed, "deterministic": bool(args.deterministic),
              "episode_s": episode_s, "push_interval": base_kwargs.get("push_interval"),
              "residual": saved["config"].get("residual"),
              "rows": rows, "wall_time_s": round(time.time() - t0, 3)}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        C.write_json(args.json, result)
    if args.plot:
        plot_sweep(result, args.plot)
    return result


def print_rows(rows, header=True) -> None:
    if header:
        print(f"{'N·s':>6}  {'controller':<12}{'fall rate':>10}{'mean len (s)':>14}{'pushes survived':>17}")
    for r in rows:
        length = f"{r['mean_length_s']:.1f}"
        pushes = f"{r['pushes_survived']:.0f}/{r['pushes']:.0f}" if r["pushes"] else "-"
        print(f"{r['strength']:>6.1f}  {r['controller']:<12}{r['fall_rate']:>10.2f}{length:>14}{pushes:>17}", flush=True)


def plot_sweep(result, path, ylabel=None, xlabel="push impulse (N·s), every push of the episode") -> Path:
    """Fall rate against push strength, a line per controller, as a PNG at
    ``path``; ``ylabel`` by default names the episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=110)
    for name in dict.fromkeys(r["controller"] for r in result["rows"]):
        pts = [(r["strength"], r["fall_rate"]) for r in result["rows"] if r["controller"] == name]
        ax.plot(*zip(*pts), marker="o", label=name)
    ax.set_xlabel(xlabel)
    if ylabel is None:
        length = f" × {result['episode_s']:g} s" if result.get("episode_s") else " episodes"
        ylabel = f"fall rate over {result['episodes']}{length}"
    ax.set_ylabel(ylabel)
    ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title(f"Balance-v0: {result['model']} ({result['model_timesteps']} steps)", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: sweep(args))


if __name__ == "__main__":
    main()
