"""Push trials: one push per world from a grid of directions, the same for
every controller, to see exactly which pushes a Balance policy survives.

    python -m training.push_trials runs/Balance-v0-0 --strengths 20 25 --directions 16 \\
        --json docs/push_trials.json --plot docs/push_trials.png

Each trial is one world: it stands for ``--settle`` s under its controller,
gets a single horizontal push of the given impulse at the centre of one of
``--bodies``, towards one of ``--directions`` headings (0: towards the
humanoid's front, +x, shoving it forward; 90°: towards its left, +y), and
counts as survived when the body is still standing ``--watch`` s later. The
worlds start from the same seeded initial states for the agent (the run's
evaluation model, with its residual baseline if it has one) and for each
baseline, and no other push comes, so the same grid gives the same trials to
every controller: unlike :mod:`training.push_sweep` (random headings, a push
every few seconds) the difference between two controllers is not sampling
noise. Reported per strength and controller: falls of the trials (with
those before the push, ``falls_before_push``) and the headings that fell,
per body, and for each baseline the paired comparison over all the trials
(``comparisons``): the trials the agent survives where the baseline falls
(``saved``), those it falls where the baseline survives (``lost``), and the
exact two-sided sign test on them (McNemar's exact test): the chance of a
split at least this uneven if either controller were as likely as the other
to be the one that falls. ``--stochastic`` samples from torch's unseeded
generator.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from . import common as C
from .push_sweep import (
    BASELINES,
    add_output_arguments,
    balance_run,
    controllers,
    plot_sweep,
)


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
    add_output_arguments(p)
    return p


def headings(directions: int) -> np.ndarray:
    """``directions`` evenly spaced headings from 0 (the front, +x), rad."""
    return 2.0 * np.pi * np.arange(directions) / directions


def run_trials(env, core, act, bodies, strength, directions, settle, watch) -> tuple:
    """(fell, fell_before) of the worlds of ``env`` (an SB3 VecEnv of
    len(bodies) x directions worlds over the batched ``core``, a step of
    ``core.dt`` s), each (len(bodies), directions) bool: fell before the push
    or within ``watch`` s after it, and fell before it. World b * directions
    + i is pushed at body index ``bodies[b]`` towards
    ``headings(directions)[i]`` with ``strength`` N·s after ``settle`` s."""
    settle_steps, watch_steps = round(settle / core.dt), max(1, round(watch / core.dt))
    fell = np.zeros(env.num_envs, dtype=bool)
    obs = env.reset()
    for _ in range(settle_steps):
        obs, _, done, _ = env.step(act(obs))
        fell |= done
    before = fell.copy()
    h = headings(directions)
    impulse = strength * np.stack([np.cos(h), np.sin(h), np.zeros_like(h)], axis=1)
    for b, body in enumerate(bodies):
        for i in range(directions):
            core.push(b * directions + i, body, impulse[i])
    for _ in range(watch_steps):
        obs, _, done, _ = env.step(act(obs))
        fell |= done
    shape = (len(bodies), directions)
    return fell.reshape(shape), before.reshape(shape)


def sign_test_p(saved: int, lost: int) -> float:
    """Exact two-sided sign test on the discordant pairs (McNemar's exact
    test): P(a split of ``saved + lost`` fair coin flips at least as uneven)."""
    n, k = saved + lost, min(saved, lost)
    if n == 0:
        return 1.0
    return min(1.0, 2 * sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n)  # exact ints: no overflow


def compare(rows, baseline: str) -> dict:
    """The agent against ``baseline`` over every trial of ``rows``: falls of
    each, ``saved`` (the baseline fell, the agent stood), ``lost`` (the
    reverse) and ``sign_test_p`` (:func:`sign_test_p`)."""
    agent = {r["strength"]: r for r in rows if r["controller"] == "agent"}
    other = {r["strength"]: r for r in rows if r["controller"] == baseline}
    saved = lost = trials = falls_a = falls_b = 0
    for s, a in agent.items():
        b = other[s]
        for body, marks in a["fell"].items():
            for x, y in zip(marks, b["fell"][body]):
                saved += x == "." and y == "X"
                lost += x == "X" and y == "."
        trials += a["trials"]
        falls_a += a["falls"]
        falls_b += b["falls"]
    return {"baseline": baseline, "trials": trials, "agent_falls": falls_a, "baseline_falls": falls_b,
            "saved": saved, "lost": lost, "sign_test_p": sign_test_p(saved, lost)}


def _check(args):
    if args.settle < 0 or args.watch <= 0:
        raise C.TrainingError(f"--settle must be >= 0 and --watch > 0 s, got {args.settle} and {args.watch}")
    if any(s <= 0 for s in args.strengths):
        raise C.TrainingError(f"--strengths must be > 0 N·s, got {args.strengths}")
    if args.bodies is not None and len(set(args.bodies)) != len(args.bodies):
        raise C.TrainingError(f"--bodies names a body twice: {args.bodies}")


def trials(args) -> dict:
    import torch

    from ragdoll_env.tasks import BalanceTask

    torch.set_num_threads(int(args.threads))
    _check(args)
    t0 = time.time()
    run, saved = balance_run(args.run_dir)
    threads = C.run_threads(args.sim_threads, saved)
    bodies = list(args.bodies or BalanceTask.push_bodies)
    # no random pushes (push_bodies only checks the names: movable bodies) and no time limit
    env_kwargs = {**(saved["config"].get("env_kwargs") or {}), "push_strength": 0.0, "push_bodies": bodies,
                  "max_episode_steps": None}
    W = len(bodies) * args.directions
    rows, model_label, model_steps = [], None, None
    for s in dict.fromkeys(args.strengths):
        for ctrl in controllers(run, saved, W, args.seed, env_kwargs, args.baselines, args.deterministic, args.model,
                                threads):
            if ctrl.agent is not None:
                model_label, model_steps = ctrl.agent.label, int(ctrl.agent.model.num_timesteps)
            fell, before = run_trials(ctrl.env, ctrl.core, ctrl.act, ctrl.core.push_body_index, s, args.directions,
                                      args.settle, args.watch)
            rows.append({
                "strength": s,
                "controller": ctrl.name,
                "trials": int(fell.size),
                "falls": int(fell.sum()),
                "falls_before_push": int(before.sum()),
                "fall_rate": float(fell.mean()),
                "fell": {b: "".join("X" if f else "." for f in fell[k]) for k, b in enumerate(bodies)},
            })
        print_rows([r for r in rows if r["strength"] == s], bodies, header=(s == args.strengths[0]))
    comparisons = [compare(rows, b) for b in dict.fromkeys(args.baselines)]
    for c in comparisons:
        print(f"agent against {c['baseline']}: {c['agent_falls']} and {c['baseline_falls']} falls of {c['trials']}; "
              f"the agent stands where {c['baseline']} falls {c['saved']} times and falls where {c['baseline']} "
              f"stands {c['lost']} times (two-sided sign test p = {c['sign_test_p']:.3g})")
    result = {"run_dir": str(run), "env_id": saved["env_id"], "model": model_label, "model_timesteps": model_steps,
              "seed": args.seed, "deterministic": bool(args.deterministic), "bodies": bodies,
              "directions": args.directions, "headings_deg": [round(float(np.degrees(x)), 3)
                                                              for x in headings(args.directions)],
              "settle_s": args.settle, "watch_s": args.watch, "env_kwargs": env_kwargs,
              "residual": saved["config"].get("residual"), "rows": rows, "comparisons": comparisons,
              "wall_time_s": round(time.time() - t0, 3)}
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
        print("pushes towards headings from forward (+x) counter-clockwise seen from above; X: fell")
        print(f"{'N·s':>6}  {'controller':<12}{'falls':>8}" + "".join(f"  {b:<{len(rows[0]['fell'][b])}}" for b in bodies))
    for r in rows:
        maps = "".join(f"  {r['fell'][b]:<{len(b)}}" for b in bodies)
        print(f"{r['strength']:>6.1f}  {r['controller']:<12}{r['falls']:>4}/{r['trials']:<3}{maps}", flush=True)


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: trials(args))


if __name__ == "__main__":
    main()
