"""Push trials: one push per world from a grid of directions, the same for
every controller, to see exactly which pushes a Balance policy survives.

    python -m training.push_trials runs/Balance-v0-0 --strengths 20 25 --directions 16 \\
        --json docs/push_trials.json --plot docs/push_trials.png

Each trial is one world: it stands for ``--settle`` s under its controller,
gets a single horizontal push of the given impulse at the centre of one of
``--bodies`` (heading 0 is the humanoid's front, +x; 90° its left, +y), and
counts as survived when the body is still standing ``--watch`` s later. The
worlds start from the same seeded initial states for the agent (the run's
evaluation model, with its residual baseline if it has one) and for each
baseline, and no other push comes, so the same grid gives the same trials to
every controller: unlike :mod:`training.push_sweep` (random headings, a push
every few seconds) the difference between two controllers is not sampling
noise. Reported per strength and controller: falls of the trials and the
headings that fell, per body.
"""

from __future__ import annotations

import argparse
import time
from functools import partial
from pathlib import Path

import numpy as np

from . import common as C
from .evaluate import _make_venv, load_agent
from .push_sweep import BASELINES, plot_sweep


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m training.push_trials", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", metavar="RUN_DIR", help="a Ragdoll/Balance-v0 run written by python -m training.train")
    p.add_argument("--strengths", type=float, nargs="+", default=[15.0, 20.0, 25.0],
                   help="push impulses, N·s (default 15 20 25)")
    p.add_argument("--directions", type=C.positive_int, default=16,
                   help="headings per body, evenly spaced from the front (default 16)")
    p.add_argument("--bodies", nargs="+", default=None,
                   help="bodies pushed (default: the environment's push bodies, chest and pelvis)")
    p.add_argument("--settle", type=float, default=1.0, help="seconds standing before the push (default 1)")
    p.add_argument("--watch", type=float, default=4.0,
                   help="seconds after the push the body must stay standing (default 4)")
    p.add_argument("--baselines", nargs="*", default=["standing_pd"], choices=BASELINES,
                   help="baselines beside the agent (default: standing_pd)")
    p.add_argument("--seed", type=int, default=0, help="seed of the worlds' initial states (default 0)")
    p.add_argument("--stochastic", dest="deterministic", action="store_false",
                   help="sample the policy's actions (default: its mean action)")
    p.add_argument("--json", metavar="PATH", default=None, help="write the rows as JSON here")
    p.add_argument("--plot", metavar="PNG", default=None, help="plot falls against strength (matplotlib)")
    p.add_argument("--threads", type=C.positive_int, default=1, help="torch CPU threads (default 1)")
    return p


def headings(directions: int) -> np.ndarray:
    """``directions`` evenly spaced headings from 0 (the front, +x), rad."""
    return 2.0 * np.pi * np.arange(directions) / directions


def run_trials(env, core, act, step_s, bodies, strength, directions, settle, watch) -> np.ndarray:
    """(len(bodies), directions) bool: the worlds of ``env`` (an SB3 VecEnv of
    len(bodies) x directions worlds over the batched ``core``, each policy step
    ``step_s`` seconds) that fell before the push or within ``watch`` s after
    it. World b * directions + i is pushed at ``bodies[b]`` towards
    ``headings(directions)[i]`` with ``strength`` N·s after ``settle`` s."""
    settle_steps, watch_steps = (round(t / step_s) for t in (settle, watch))
    fell = np.zeros(env.num_envs, dtype=bool)
    obs = env.reset()
    for _ in range(settle_steps):
        obs, _, done, _ = env.step(act(obs))
        fell |= done
    h = headings(directions)
    impulse = strength * np.stack([np.cos(h), np.sin(h), np.zeros_like(h)], axis=1)
    for b, body in enumerate(bodies):
        for i in range(directions):
            core.push(b * directions + i, body, impulse[i])
    for _ in range(watch_steps):
        obs, _, done, _ = env.step(act(obs))
        fell |= done
    return fell.reshape(len(bodies), directions)


def _check(args):
    if args.settle < 0 or args.watch <= 0:
        raise C.TrainingError(f"--settle must be >= 0 and --watch > 0 s, got {args.settle} and {args.watch}")
    if any(s <= 0 for s in args.strengths):
        raise C.TrainingError(f"--strengths must be > 0 N·s, got {args.strengths}")


def trials(args) -> dict:
    import torch

    from ragdoll_env.baselines import make_baseline
    from ragdoll_env.tasks import BalanceTask

    torch.set_num_threads(int(args.threads))
    _check(args)
    t0 = time.time()
    run = C.require_run_dir(args.run_dir)
    saved = C.read_run_config(run)
    env_id = saved["env_id"]
    if env_id != "Ragdoll/Balance-v0":
        raise C.TrainingError(f"{str(run)!r} is a run of {env_id}; push trials need a Ragdoll/Balance-v0 run")
    bodies = list(args.bodies or BalanceTask.push_bodies)
    residual = saved["config"].get("residual")
    # no random pushes and no time limit: each world meets its one push
    env_kwargs = {**(saved["config"].get("env_kwargs") or {}), "push_strength": 0.0, "max_episode_steps": None}
    W = len(bodies) * args.directions
    rows, model_label, model_steps = [], None, None
    for s in dict.fromkeys(args.strengths):
        agent = load_agent(run, saved, W, args.seed, env_kwargs)
        core = agent.venv.core
        try:
            index = [core.model.body_index(b) for b in bodies]
        except KeyError as exc:
            raise C.TrainingError(f"--bodies: {exc.args[0]}") from None
        model_label, model_steps = agent.label, int(agent.model.num_timesteps)
        results = {"agent": run_trials(agent.env, core, partial(agent.act, deterministic=args.deterministic),
                                       core.dt, index, s, args.directions, args.settle, args.watch)}
        agent.env.close()
        for name in args.baselines:
            venv = _make_venv(env_id, W, args.seed, env_kwargs)
            ctrl = make_baseline(name, venv, **C.baseline_kwargs(name, residual, env_id))
            results[name] = run_trials(venv, venv.core, ctrl.act, venv.core.dt, index, s, args.directions,
                                       args.settle, args.watch)
            venv.close()
        for name, fell in results.items():
            rows.append({
                "strength": s,
                "controller": name,
                "trials": int(fell.size),
                "falls": int(fell.sum()),
                "fall_rate": float(fell.mean()),
                "fell": {b: "".join("X" if f else "." for f in fell[k]) for k, b in enumerate(bodies)},
            })
        print_rows([r for r in rows if r["strength"] == s], bodies, header=(s == args.strengths[0]))
    result = {"run_dir": str(run), "env_id": env_id, "model": model_label, "model_timesteps": model_steps,
              "seed": args.seed, "deterministic": bool(args.deterministic), "bodies": bodies,
              "directions": args.directions, "headings_deg": [round(float(np.degrees(x)), 3)
                                                              for x in headings(args.directions)],
              "settle_s": args.settle, "watch_s": args.watch, "residual": residual,
              "rows": rows, "wall_time_s": round(time.time() - t0, 3)}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        C.write_json(args.json, result)
    if args.plot:
        plot_sweep(result, args.plot, ylabel=f"fall rate of {W} single pushes\n({len(bodies)} bodies × "
                   f"{args.directions} headings)", xlabel="push impulse (N·s), one push per world")
    return result


def print_rows(rows, bodies, header=True) -> None:
    """The rows as a table; each body's column marks the headings that fell
    (X), from the front (first) counter-clockwise seen from above."""
    if header:
        print("headings from the front (+x) counter-clockwise seen from above; X: fell")
        print(f"{'N·s':>6}  {'controller':<12}{'falls':>8}" + "".join(f"  {b:<{len(rows[0]['fell'][b])}}" for b in bodies))
    for r in rows:
        maps = "".join(f"  {r['fell'][b]:<{len(b)}}" for b in bodies)
        print(f"{r['strength']:>6.1f}  {r['controller']:<12}{r['falls']:>4}/{r['trials']:<3}{maps}", flush=True)


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: trials(args))


if __name__ == "__main__":
    main()
