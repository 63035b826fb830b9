"""Throughput of batched ragdoll scenes, with MuJoCo's humanoid measured side by side.

    python -m benchmarks.throughput [--worlds 1 16 256 1024 4096] [--scenes ...]
        [--steps N] [--repeats R] [--target-seconds S] [--quick] [--json PATH]
        [--compare-mujoco] [--mujoco-worlds N] [--processes P ...]

For each scene and world count W: world-steps per second, simulated seconds
per wall-clock second (world-steps/s x dt) and bytes per world (the state plus
the tracemalloc peak of one step, both divided by W). Both are measured from
a settled start: ``SETTLE_WORLDS`` worlds stepped ``--settle-seconds`` under
the random torques (on the ground, the ragdolls have fallen and lie on many
contact points), repeated over the W worlds; from the standing start a step
has a few foot contacts and costs less. Without ``--steps`` the
step count is chosen so one timed repeat lasts about ``--target-seconds``.
With ``--processes P`` each W >= P is also stepped by ``engine.ParallelStepper``
in P worker processes (mode ``batched-Pproc``; memory not measured there).
"""

from __future__ import annotations

import argparse
import json
import os
import tracemalloc
import warnings

import numpy as np

from engine import Box, Capsule, Control, ParallelStepper, SceneBuilder, Sphere, step
from engine.humanoid import add_humanoid

from .common import machine_note, measure, positive_float, positive_int, print_table, settings_json, write_json

DEFAULT_WORLDS = (1, 16, 256, 1024, 4096)
QUICK_WORLDS = (1, 8)
QUICK_STEPS = 3
QUICK_REPEATS = 2
CONTROL_BANK = 8
SETTLE_WORLDS = 64
SETTLE_SECONDS = 1.5
MUJOCO_WORLDS = 1024
QUICK_MUJOCO_WORLDS = 32
MUJOCO_EPISODE = 100
RAGDOLL_ENV = "Ragdoll/Balance-v0"
RAGDOLL_VECTOR_ENVS = 64
MUJOCO_VECTOR_ENVS = 8
HUMANOID_SCENES = ("ragdoll_air", "ragdoll_ground")


class Unavailable(Exception):
    """A scene or peer that cannot be measured in this checkout."""


def free_bodies():
    b = SceneBuilder()
    rng = np.random.default_rng(0)
    shapes = (Sphere(0.1), Capsule(0.06, 0.15), Box((0.1, 0.08, 0.05)))
    for i in range(16):
        q = rng.normal(size=4)
        b.add_body(f"body_{i}", shapes[i % 3], position=(i % 4, i // 4, 2.0), orientation=q / np.linalg.norm(q),
                   velocity=rng.normal(0.0, 1.0, 3), angular_velocity=rng.normal(0.0, 3.0, 3))
    return b.build()


def ragdoll(ground: bool):
    b = SceneBuilder()
    if ground:
        b.add_ground()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b)
    model = b.build()
    if ground and model.contacts is None:
        raise Unavailable("contacts are not compiled yet (model.contacts is None)")
    return model


SCENES = {
    "free_bodies": free_bodies,
    "ragdoll_air": lambda: ragdoll(ground=False),
    "ragdoll_ground": lambda: ragdoll(ground=True),
}


def row(engine, mode, scene, worlds, dt, steps, seconds, repeats, bytes_per_world=None, state_bytes=None):
    rate = worlds * steps / seconds
    return {"engine": engine, "mode": mode, "scene": scene, "worlds": worlds, "dt_s": dt,
            "world_steps_per_s": rate, "sim_s_per_s": None if dt is None else rate * dt,
            "bytes_per_world": bytes_per_world, "state_bytes_per_world": state_bytes,
            "steps": steps, "repeats": repeats}


# ------------------------------------------------------------------ ragdoll
def random_controls(model, worlds, seed=0):
    if not model.num_actuators:
        return [None]
    max_torque = np.array([a.max_torque for a in model.actuators])
    rng = np.random.default_rng(seed)
    return [Control(motor=rng.uniform(-1.0, 1.0, (worlds, model.num_actuators)) * max_torque)
            for _ in range(CONTROL_BANK)]


def step_peak_bytes(model, state, control) -> int:
    """Peak bytes numpy allocates during one step (tracemalloc)."""
    s = state.copy()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        step(model, s, control)
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def settled_state(model, seconds):
    """``SETTLE_WORLDS`` worlds after ``seconds`` of the random torques of ``random_controls``."""
    state = model.initial_state(SETTLE_WORLDS)
    controls = random_controls(model, SETTLE_WORLDS, seed=1)
    for i in range(round(seconds / model.settings.dt)):
        step(model, state, controls[i % len(controls)])
    return state


def bench_scene(name, model, worlds, start, args):
    state0 = start.select(np.arange(worlds) % start.num_worlds)
    controls = random_controls(model, worlds)

    def make_run(n):
        state = state0.copy()

        def run():
            for i in range(n):
                step(model, state, controls[i % len(controls)])
        return run

    steps, seconds = measure(make_run, args.repeats, args.steps, args.target_seconds, min_steps=2)
    state_bytes = state0.nbytes() / worlds
    temp_bytes = step_peak_bytes(model, state0, controls[0]) / worlds
    return row("ragdoll", "batched", name, worlds, model.settings.dt, steps, seconds, args.repeats,
               state_bytes + temp_bytes, state_bytes)


def bench_parallel(name, model, worlds, processes, start, args):
    """The same scene and controls stepped by ``engine.ParallelStepper``."""
    state0 = start.select(np.arange(worlds) % start.num_worlds)
    controls = random_controls(model, worlds)
    state = state0.copy()
    with ParallelStepper(model, state, processes) as stepper:
        def make_run(n):
            state.assign(slice(None), state0)

            def run():
                for i in range(n):
                    stepper.step(controls[i % len(controls)])
            return run

        steps, seconds = measure(make_run, args.repeats, args.steps, args.target_seconds, min_steps=2)
    return row("ragdoll", f"batched-{processes}proc", name, worlds, model.settings.dt, steps, seconds,
               args.repeats)


def ragdoll_rows(args, notes):
    rows = []
    if args.settings:
        notes.append(f"ragdoll rows with the engine settings {json.dumps(args.settings)}")
    for name in args.scenes:
        try:
            model = SCENES[name]()
            if args.settings:
                model = model.with_settings(**args.settings)
        except Exception as exc:
            notes.append(f"{name}: skipped, the scene does not build: {exc}")
            continue
        try:
            start = settled_state(model, args.settle_seconds)
        except Exception as exc:
            notes.append(f"{name}: skipped, stepping failed while settling: {type(exc).__name__}: {exc}")
            continue
        for worlds in args.worlds:
            try:
                rows.append(bench_scene(name, model, worlds, start, args))
                print(f"measured {name} W={worlds}", flush=True)
                for processes in args.processes:
                    if 1 < processes <= worlds:
                        rows.append(bench_parallel(name, model, worlds, processes, start, args))
                        print(f"measured {name} W={worlds} in {processes} processes", flush=True)
            except Exception as exc:
                notes.append(f"{name} W={worlds}: skipped, stepping failed: {type(exc).__name__}: {exc}")
                break
    return rows


# ------------------------------------------------------------------- mujoco
def humanoid_xml():
    import gymnasium.envs.mujoco

    return os.path.join(os.path.dirname(gymnasium.envs.mujoco.__file__), "assets", "humanoid.xml")


def mujoco_controls(mj_model, shape, seed=0):
    lo, hi = mj_model.actuator_ctrlrange.T
    return np.random.default_rng(seed).uniform(lo, hi, shape + (mj_model.nu,))


def mujoco_loop(mujoco, m, args):
    d = mujoco.MjData(m)
    u = mujoco_controls(m, (MUJOCO_EPISODE,))

    def make_run(n):
        mujoco.mj_resetData(m, d)

        def run():
            for i in range(n):
                k = i % MUJOCO_EPISODE
                if k == 0:
                    mujoco.mj_resetData(m, d)
                d.ctrl[:] = u[k]
                mujoco.mj_step(m, d)
        return run

    steps, seconds = measure(make_run, args.repeats, args.steps, args.target_seconds)
    return row("mujoco", "loop", "humanoid", 1, m.opt.timestep, steps, seconds, args.repeats,
               bytes_per_world=float(d.nbuffer + d.narena))


def mujoco_rollout(mujoco, m, worlds, nthread, args):
    from mujoco import rollout

    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    x0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, x0, spec)
    initial = np.tile(x0, (worlds, 1))
    nstep = args.steps or MUJOCO_EPISODE
    u = mujoco_controls(m, (worlds, nstep))
    datas = [mujoco.MjData(m) for _ in range(nthread)]
    with rollout.Rollout(nthread=nthread) as pool:
        def make_run(n):
            out = np.empty((worlds, n, x0.size))
            control = np.ascontiguousarray(u[:, :n])
            return lambda: pool.rollout(m, datas, initial, control, state=out)

        steps, seconds = measure(make_run, args.repeats, nstep)
    return row("mujoco", f"rollout-{nthread}thread", "humanoid", worlds, m.opt.timestep, steps, seconds,
               args.repeats)


def bench_env(env_id, vector_envs, vector_kwargs, args, engine):
    import gymnasium

    env = gymnasium.make(env_id)
    dt = getattr(env.unwrapped, "dt", None)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(CONTROL_BANK)]

    def make_env_run(n):
        env.reset(seed=0)

        def run():
            for i in range(n):
                _, _, terminated, truncated, _ = env.step(actions[i % len(actions)])
                if terminated or truncated:
                    env.reset()
        return run

    steps, seconds = measure(make_env_run, args.repeats, args.steps, args.target_seconds)
    rows = [row(engine, "env", env_id, 1, dt, steps, seconds, args.repeats)]
    env.close()

    envs = gymnasium.make_vec(env_id, num_envs=vector_envs, **vector_kwargs)
    envs.action_space.seed(0)
    vec_actions = [envs.action_space.sample() for _ in range(CONTROL_BANK)]

    def make_vec_run(n):
        envs.reset(seed=0)

        def run():
            for i in range(n):
                envs.step(vec_actions[i % len(vec_actions)])
        return run

    steps, seconds = measure(make_vec_run, args.repeats, args.steps, args.target_seconds)
    rows.append(row(engine, "vector-env", env_id, vector_envs, dt, steps, seconds, args.repeats))
    envs.close()
    return rows


def ragdoll_env_rows(args, notes):
    import gymnasium

    try:
        import ragdoll_env  # noqa: F401
    except Exception as exc:
        notes.append(f"{RAGDOLL_ENV}: skipped, ragdoll_env does not import: {exc}")
        return []
    if RAGDOLL_ENV not in gymnasium.envs.registry:
        notes.append(f"{RAGDOLL_ENV}: skipped, not registered by ragdoll_env yet")
        return []
    try:
        return bench_env(RAGDOLL_ENV, RAGDOLL_VECTOR_ENVS, {"vectorization_mode": "vector_entry_point"},
                         args, "ragdoll")
    except Exception as exc:
        notes.append(f"{RAGDOLL_ENV}: skipped, failed: {type(exc).__name__}: {exc}")
        return []


def mujoco_rows(args, notes):
    try:
        import mujoco
        import gymnasium  # noqa: F401
    except ImportError as exc:
        notes.append(f"MuJoCo comparison skipped: {exc} (pip install 'ragdoll[bench]')")
        return []
    m = mujoco.MjModel.from_xml_path(humanoid_xml())
    rows = [mujoco_loop(mujoco, m, args)]
    print("measured mujoco loop", flush=True)
    for nthread in (1, 2):
        rows.append(mujoco_rollout(mujoco, m, args.mujoco_worlds, nthread, args))
        print(f"measured mujoco rollout-{nthread}thread", flush=True)
    rows += bench_env("Humanoid-v5", MUJOCO_VECTOR_ENVS, {}, args, "mujoco")
    print("measured Humanoid-v5 env and vector env", flush=True)
    return rows + ragdoll_env_rows(args, notes)


# --------------------------------------------------------------------- main
def ratio_lines(rows):
    reference = next((r for r in rows if r["engine"] == "mujoco" and r["mode"] == "rollout-2thread"), None)
    lines = []
    if reference:
        for r in rows:
            if r["engine"] == "ragdoll" and r["mode"].startswith("batched") and r["scene"] in HUMANOID_SCENES:
                lines.append(f"ragdoll {r['mode']} {r['scene']} W={r['worlds']} / mujoco humanoid rollout-2thread "
                             f"W={reference['worlds']}: {r['sim_s_per_s'] / reference['sim_s_per_s']:.3g}x "
                             f"simulated s per s")
    for mode in ("env", "vector-env"):
        ours = next((r for r in rows if r["engine"] == "ragdoll" and r["mode"] == mode), None)
        theirs = next((r for r in rows if r["engine"] == "mujoco" and r["mode"] == mode), None)
        if ours and theirs and ours["sim_s_per_s"] and theirs["sim_s_per_s"]:
            lines.append(f"{ours['scene']} {mode} (W={ours['worlds']}) / {theirs['scene']} {mode} "
                         f"(W={theirs['worlds']}): {ours['sim_s_per_s'] / theirs['sim_s_per_s']:.3g}x simulated s per s")
    return lines


COLUMNS = [
    ("engine", "engine"), ("mode", "mode"), ("scene", "scene"), ("W", "worlds"), ("steps", "steps"),
    ("dt ms", lambda r: None if r["dt_s"] is None else 1e3 * r["dt_s"]),
    ("world-steps/s", "world_steps_per_s"), ("sim s/s", "sim_s_per_s"),
    ("state B/world", "state_bytes_per_world"),
    ("B/world (state + step peak)", "bytes_per_world"),
]


def parse_args(argv):
    p = argparse.ArgumentParser(prog="python -m benchmarks.throughput", description=__doc__.split("\n")[0])
    p.add_argument("--worlds", type=positive_int, nargs="+", help=f"world counts W (default {' '.join(map(str, DEFAULT_WORLDS))})")
    p.add_argument("--steps", type=positive_int, help="steps per timed repeat (default: enough for --target-seconds)")
    p.add_argument("--repeats", type=positive_int, help="timed repeats; the median is reported (default 3)")
    p.add_argument("--scenes", nargs="+", choices=list(SCENES), default=list(SCENES))
    p.add_argument("--target-seconds", type=positive_float, default=1.0, help="wall time per repeat when --steps is not given")
    p.add_argument("--settle-seconds", type=float, default=SETTLE_SECONDS,
                   help=f"simulated seconds of random torques before timing and measuring memory (default {SETTLE_SECONDS})")
    p.add_argument("--quick", action="store_true", help="small W list, few steps: a smoke test")
    p.add_argument("--json", metavar="PATH", help="write the rows as a JSON list")
    p.add_argument("--compare-mujoco", action="store_true", help="measure MuJoCo's humanoid and Humanoid-v5 too")
    p.add_argument("--mujoco-worlds", type=positive_int, help=f"worlds of the MuJoCo rollouts (default {MUJOCO_WORLDS})")
    p.add_argument("--settings", type=settings_json, default={}, metavar="JSON",
                   help="engine settings over each ragdoll scene's own, e.g. '{\"articulated_contacts\": false}'")
    p.add_argument("--processes", type=positive_int, nargs="+", default=[],
                   help="also step each W >= P in P worker processes (engine.ParallelStepper): "
                        "rows of mode batched-Pproc")
    args = p.parse_args(argv)
    if not args.settle_seconds >= 0:
        p.error(f"--settle-seconds must be >= 0, got {args.settle_seconds}")
    if args.quick:
        args.worlds = args.worlds or list(QUICK_WORLDS)
        args.steps = args.steps or QUICK_STEPS
        args.repeats = args.repeats or QUICK_REPEATS
        args.mujoco_worlds = args.mujoco_worlds or QUICK_MUJOCO_WORLDS
        args.settle_seconds = min(args.settle_seconds, 0.1)
    args.worlds = args.worlds or list(DEFAULT_WORLDS)
    args.repeats = args.repeats or 3
    args.mujoco_worlds = args.mujoco_worlds or MUJOCO_WORLDS
    return args


def main(argv=None):
    args = parse_args(argv)
    notes = []
    rows = ragdoll_rows(args, notes)
    if args.compare_mujoco:
        rows += mujoco_rows(args, notes)
    print()
    print_table(rows, COLUMNS, title="Throughput (median of repeats; B/world = state.nbytes()/W "
                                     "+ tracemalloc peak of one step / W)")
    print(machine_note())
    for line in ratio_lines(rows):
        print(line)
    for note in notes:
        print(f"note: {note}")
    if args.json:
        write_json(args.json, rows)
        print(f"wrote {args.json}")
    return rows


if __name__ == "__main__":
    main()
