"""Learning curve of a run: ``python -m training.plot RUN_DIR [--out PNG]``.

Plots the EvalCallback's mean return (± std) against timesteps from
``eval/evaluations.npz`` and the training episodes' mean return
(``rollout/ep_rew_mean``) from the TensorBoard logs, or, without them, from
the VecMonitor logs (``*.monitor.csv``, a moving average against the
episodes' cumulative length). Written with matplotlib's Agg backend (no display needed); default
output ``RUN_DIR/learning_curve.png``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from . import common as C


def build_parser():
    p = argparse.ArgumentParser(prog="python -m training.plot", description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", metavar="RUN_DIR")
    p.add_argument("--out", metavar="PNG", default=None, help="output file (default RUN_DIR/learning_curve.png)")
    p.add_argument("--window", type=C.positive_int, default=20,
                   help="moving-average window of training episodes (default 20)")
    return p


def monitor_curve(run: Path):
    """(cumulative timesteps, episode returns) from the run's monitor files, in session order."""
    files = sorted(run.glob("train_*.monitor.csv"), key=lambda f: int(f.name.split("_")[1].split(".")[0]))
    steps, rets, offset = [], [], 0
    for f in files:
        with f.open() as fh:
            lines = [ln for ln in fh if not ln.startswith("#")]
        for row in csv.DictReader(lines):
            offset += int(float(row["l"]))
            steps.append(offset)
            rets.append(float(row["r"]))
    return np.array(steps), np.array(rets)


def tensorboard_curve(run: Path):
    """(timesteps, mean training-episode return) from the TensorBoard scalar
    ``rollout/ep_rew_mean`` (logged by SB3 after each rollout), or None."""
    try:
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    except ImportError:
        return None
    points = {}
    for d in sorted({f.parent for f in (run / "tb").rglob("events.out.tfevents*")}):
        acc = EventAccumulator(str(d), size_guidance={"scalars": 0})
        acc.Reload()
        if "rollout/ep_rew_mean" in acc.Tags().get("scalars", []):
            for ev in acc.Scalars("rollout/ep_rew_mean"):
                points[int(ev.step)] = float(ev.value)
    if not points:
        return None
    steps = np.array(sorted(points))
    return steps, np.array([points[k] for k in steps])


def plot(run_dir, out=None, window=20) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .train import read_evaluations

    run = C.require_run_dir(run_dir)
    env_id = C.read_run_config(run)["env_id"]
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    drew = False
    tb = tensorboard_curve(run)
    if tb is not None:
        ax.plot(tb[0], tb[1], color="tab:blue", label="training episodes (rollout/ep_rew_mean)")
        drew = True
    steps, rets = monitor_curve(run) if tb is None else (np.array([]), np.array([]))
    if len(rets):  # no TensorBoard: x is the episodes' cumulative length (a lower bound on timesteps)
        w = max(1, min(window, len(rets)))
        smooth = np.convolve(rets, np.ones(w) / w, mode="valid")
        ax.plot(steps, rets, ".", ms=2, alpha=0.25, color="tab:blue")
        ax.plot(steps[w - 1:], smooth, color="tab:blue", label=f"training episodes (mean of {w})")
        drew = True
    hist = read_evaluations(run)
    if hist is not None and len(hist["timesteps"]):
        res = np.asarray(hist["results"], dtype=float)
        m, s = res.mean(axis=1), res.std(axis=1)
        t = np.asarray(hist["timesteps"])
        ax.plot(t, m, "o-", color="tab:orange", label="evaluation (deterministic)")
        ax.fill_between(t, m - s, m + s, color="tab:orange", alpha=0.2)
        drew = True
    if not drew:
        plt.close(fig)
        raise C.TrainingError(f"{str(run)!r} has nothing to plot yet: no evaluations.npz and no finished "
                              f"episode in its monitor logs")
    ax.set_xlabel("timesteps")
    ax.set_ylabel("episode return")
    ax.set_title(f"PPO on {env_id} ({run.name})")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    out = Path(out) if out else run / "learning_curve.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    print(f"wrote {out}")
    return out


def main(argv=None):
    args = build_parser().parse_args(argv)
    return C.run_cli(lambda _: plot(args.run_dir, args.out, args.window))


if __name__ == "__main__":
    main()
