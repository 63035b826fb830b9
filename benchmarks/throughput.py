"""Throughput of batched ragdoll scenes, with MuJoCo's humanoid measured side by side.

    python -m benchmarks.throughput [--worlds 1 16 256 1024 4096] [--scenes ...]
        [--steps N] [--repeats R] [--target-seconds S] [--quick] [--json PATH]
        [--compare-mujoco] [--mujoco-worlds N] [--compile] [--threads T ...]

For each scene and world count W: world-steps per second, simulated seconds
per wall-clock second (world-steps/s x dt) and bytes per world (the state plus
the tracemalloc peak of one step, both divided by W). Both are measured from
a settled start: ``SETTLE_WORLDS`` worlds stepped ``--settle-seconds`` under
the random torques (on the ground, the ragdolls have fallen and lie on many
contact points), repeated over the W worlds; from the standing start a step
has a few foot contacts and costs less. Without ``--steps`` the
step count is chosen so one timed repeat lasts about ``--target-seconds``.
Each W is stepped on each thread count T of ``--threads`` (``engine.set_threads``;
default 1 and all cores), mode ``batched-Tthr``; a W below ``SERIAL_BELOW``
steps on the calling thread whatever the count, so it gets one row, at the
smallest T.
"""

from __future__ import annotations

import argparse
import json
import os
import tracemalloc
import warnings

import numpy as np

from engine import Box, Capsule, Control, SceneBuilder, Sphere, get_threads, max_threads, set_threads, step
from engine.core.jit import SERIAL_BELOW
from engine.humanoid import add_humanoid

from .common import machine_note, measure, positive_float, positive_int, print_table, settings_json, write_json

DEFAULT_WORLDS = (1, 16, 256, 1024, 4096)
QUICK_WORLDS = (1, 8)
#: thread counts of the batched rows: 1 and all cores
DEFAULT_THREADS = tuple(sorted({1, max_threads()}))
QUICK_STEPS = 3
QUICK_REPEATS = 2
CONTROL_BANK = 8
SETTLE_WORLDS = 64
SETTLE_SECONDS = 1.5
MUJOCO_WORLDS = 1024
QUICK_MUJOCO_WORLDS = 32
MUJOCO_SETTLE_STEPS = 1500  # 4.5 s at the humanoid's 3 ms: fallen and lying under random controls
MUJOCO_ROLLOUT_STEPS = 200
PYBULLET_SETTLE_STEPS = 1200  # 5 s at 240 Hz
RAGDOLL_ENVS = ("Ragdoll/Balance-v0", "Ragdoll/InvertedPendulum-v0")
#: Each of our env ids and the Gymnasium MuJoCo env it is compared with.
ENV_PEERS = {"Ragdoll/Balance-v0": "Humanoid-v5", "Ragdoll/InvertedPendulum-v0": "InvertedPendulum-v5"}
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


def row(engine, mode, scene, worlds, dt, steps, seconds, repeats, bytes_per_world=None, state_bytes=None,
        threads=None):
    rate = worlds * steps / seconds
    return {"engine": engine, "mode": mode, "scene": scene, "worlds": worlds, "dt_s": dt,
            "world_steps_per_s": rate, "sim_s_per_s": None if dt is None else rate * dt,
            "bytes_per_world": bytes_per_world, "state_bytes_per_world": state_bytes,
            "steps": steps, "repeats": repeats, "threads": threads}


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


def bench_scene(name, model, worlds, start, args, threads):
    """W worlds of the scene stepped on ``threads`` threads (mode ``batched-Tthr``)."""
    state0 = start.select(np.arange(worlds) % start.num_worlds)
    controls = random_controls(model, worlds)

    def make_run(n):
        state = state0.copy()

        def run():
            for i in range(n):
                step(model, state, controls[i % len(controls)])
        return run

    set_threads(threads)
    steps, seconds = measure(make_run, args.repeats, args.steps, args.target_seconds, min_steps=2)
    state_bytes = state0.nbytes() / worlds
    temp_bytes = step_peak_bytes(model, state0, controls[0]) / worlds
    return row("ragdoll", f"batched-{threads}thr", name, worlds, model.settings.dt, steps, seconds, args.repeats,
               state_bytes + temp_bytes, state_bytes, threads=threads)


def thread_counts(worlds, threads):
    """The thread counts W worlds are timed on: all of ``threads``, or below
    ``SERIAL_BELOW`` worlds (stepped on the calling thread) the smallest."""
    return sorted(threads) if worlds >= SERIAL_BELOW else [min(threads)]


def ragdoll_rows(args, notes):
    before = get_threads()
    try:
        return _ragdoll_rows(args, notes)
    finally:
        set_threads(before)  # the env rows step with the engine's count, as an env user would


def _ragdoll_rows(args, notes):
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
                for threads in thread_counts(worlds, args.threads):
                    rows.append(bench_scene(name, model, worlds, start, args, threads))
                    print(f"measured {name} W={worlds} on {threads} thread(s)", flush=True)
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


def mujoco_model(mujoco, integrator):
    """Gymnasium's humanoid.xml as shipped ("rk4": RK4, dt 3 ms) or with
    ``integrator="implicitfast"``."""
    m = mujoco.MjModel.from_xml_path(humanoid_xml())
    if integrator == "implicitfast":
        m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    return m


def mujoco_settled(mujoco, m, worlds):
    """Full-physics states of ``worlds`` humanoids after ``MUJOCO_SETTLE_STEPS``
    steps of random controls from the standing start (each world its own
    controls): fallen and lying on the ground, as the ragdoll is timed."""
    from mujoco import rollout

    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    x0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, x0, spec)
    n = min(worlds, SETTLE_WORLDS)
    u = mujoco_controls(m, (n, MUJOCO_SETTLE_STEPS), seed=1)
    states, _ = rollout.rollout(m, d, np.tile(x0, (n, 1)), u)
    return states[np.arange(worlds) % n, -1]


def _contacts_per_world(mujoco, m, state):
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    counts = []
    for x in state[:16]:
        mujoco.mj_setState(m, d, x, spec)
        mujoco.mj_forward(m, d)
        counts.append(d.ncon)
    return float(np.mean(counts))


def mujoco_loop(mujoco, m, integrator, start, args):
    """One MjData stepped by ``mj_step`` from a lying start."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    u = mujoco_controls(m, (CONTROL_BANK,))

    def make_run(n):
        mujoco.mj_setState(m, d, start[0], spec)

        def run():
            for i in range(n):
                d.ctrl[:] = u[i % CONTROL_BANK]
                mujoco.mj_step(m, d)
        return run

    steps, seconds = measure(make_run, args.repeats, args.steps, args.target_seconds)
    r = row("mujoco", f"loop-{integrator}", "humanoid_ground", 1, m.opt.timestep, steps, seconds, args.repeats,
            bytes_per_world=float(d.nbuffer + d.narena))
    r["contacts_per_world"] = _contacts_per_world(mujoco, m, start)
    return r


def mujoco_rollout(mujoco, m, integrator, start, nthread, args):
    """``mujoco.rollout`` of W lying humanoids on ``nthread`` threads."""
    from mujoco import rollout

    worlds = start.shape[0]
    nstep = args.steps or MUJOCO_ROLLOUT_STEPS
    u = mujoco_controls(m, (worlds, nstep))
    datas = [mujoco.MjData(m) for _ in range(nthread)]
    initial = np.ascontiguousarray(start)
    with rollout.Rollout(nthread=nthread) as pool:
        def make_run(n):
            out = np.empty((worlds, n, start.shape[1]))
            control = np.ascontiguousarray(u[:, :n])
            return lambda: pool.rollout(m, datas, initial, control, state=out)

        steps, seconds = measure(make_run, args.repeats, nstep)
    r = row("mujoco", f"rollout-{integrator}-{nthread}thread", "humanoid_ground", worlds, m.opt.timestep, steps,
            seconds, args.repeats, threads=nthread)
    r["contacts_per_world"] = _contacts_per_world(mujoco, m, start)
    return r


def pybullet_rows(args, notes):
    """PyBullet's MJCF humanoid (pybullet_data's mjcf/humanoid.xml) on its
    ground plane at 240 Hz, torque-controlled, lying after ``PYBULLET_SETTLE_STEPS``
    steps of random torques: one world (PyBullet has no batching)."""
    try:
        import pybullet as pb
        import pybullet_data
    except ImportError as exc:
        notes.append(f"PyBullet row skipped: {exc} (pip install pybullet)")
        return []
    client = pb.connect(pb.DIRECT)
    try:
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        pb.setTimeStep(1.0 / 240.0, physicsClientId=client)
        pb.loadURDF("plane.urdf", physicsClientId=client)
        body = pb.loadMJCF("mjcf/humanoid.xml", physicsClientId=client)[-1]
        joints = [j for j in range(pb.getNumJoints(body, physicsClientId=client))
                  if pb.getJointInfo(body, j, physicsClientId=client)[2] == pb.JOINT_REVOLUTE]
        # Torque control: the default velocity motors off.
        pb.setJointMotorControlArray(body, joints, pb.VELOCITY_CONTROL, forces=[0.0] * len(joints),
                                     physicsClientId=client)
        rng = np.random.default_rng(0)
        torques = rng.uniform(-40.0, 40.0, (CONTROL_BANK, len(joints)))

        def control(i):
            pb.setJointMotorControlArray(body, joints, pb.TORQUE_CONTROL, forces=torques[i % CONTROL_BANK],
                                         physicsClientId=client)
            pb.stepSimulation(physicsClientId=client)

        for i in range(PYBULLET_SETTLE_STEPS):
            control(i)
        contacts = len(pb.getContactPoints(bodyA=body, physicsClientId=client))

        def make_run(n):
            def run():
                for i in range(n):
                    control(i)
            return run

        steps, seconds = measure(make_run, args.repeats, args.steps, args.target_seconds)
    finally:
        pb.disconnect(client)
    r = row("pybullet", "loop", "humanoid_ground", 1, 1.0 / 240.0, steps, seconds, args.repeats)
    r["contacts_per_world"] = float(contacts)
    print("measured pybullet loop", flush=True)
    return [r]


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
        notes.append(f"ragdoll env rows skipped, ragdoll_env does not import: {exc}")
        return []
    rows = []
    for env_id in RAGDOLL_ENVS:
        try:
            rows += bench_env(env_id, RAGDOLL_VECTOR_ENVS, {"vectorization_mode": "vector_entry_point"},
                              args, "ragdoll")
            print(f"measured {env_id} env and vector env", flush=True)
        except Exception as exc:
            notes.append(f"{env_id}: skipped, failed: {type(exc).__name__}: {exc}")
    return rows


COMPILE_PROBE = """
import time
t0 = time.perf_counter()
import engine
from engine.humanoid import add_humanoid
b = engine.SceneBuilder()
b.add_ground()
add_humanoid(b)
model = b.build()
state = model.initial_state(2)
engine.step(model, state)
print(time.perf_counter() - t0)
"""


def compile_rows(notes):
    """Seconds from a fresh interpreter to the first step of the humanoid on
    the ground: with an empty kernel cache (cold compile) and again with the
    cache it filled (warm start)."""
    import subprocess
    import sys
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for mode in ("cold-compile", "warm-start"):
            out = subprocess.run([sys.executable, "-c", COMPILE_PROBE], env=env, capture_output=True, text=True)
            if out.returncode != 0:
                notes.append(f"{mode}: the probe failed: {out.stderr.strip().splitlines()[-1:]}")
                return rows
            seconds = float(out.stdout.strip().splitlines()[-1])
            rows.append({"engine": "ragdoll", "mode": mode, "scene": "ragdoll_ground", "worlds": 2, "dt_s": None,
                         "world_steps_per_s": None, "sim_s_per_s": None, "bytes_per_world": None,
                         "state_bytes_per_world": None, "steps": 1, "repeats": 1, "threads": None,
                         "seconds": seconds})
            print(f"measured {mode}: {seconds:.1f} s", flush=True)
    return rows


def mujoco_rows(args, notes):
    try:
        import mujoco
        import gymnasium  # noqa: F401
    except ImportError as exc:
        notes.append(f"MuJoCo comparison skipped: {exc} (pip install 'ragdoll[bench]')")
        return []
    rows = []
    for integrator in ("rk4", "implicitfast"):
        m = mujoco_model(mujoco, integrator)
        start = mujoco_settled(mujoco, m, args.mujoco_worlds)
        rows.append(mujoco_loop(mujoco, m, integrator, start, args))
        print(f"measured mujoco loop {integrator}", flush=True)
        for nthread in (1, 2):
            rows.append(mujoco_rollout(mujoco, m, integrator, start, nthread, args))
            print(f"measured mujoco rollout {integrator} {nthread} thread(s)", flush=True)
    rows += bench_env("Humanoid-v5", MUJOCO_VECTOR_ENVS, {}, args, "mujoco")
    print("measured Humanoid-v5 env and vector env", flush=True)
    rows += bench_env("InvertedPendulum-v5", MUJOCO_VECTOR_ENVS, {}, args, "mujoco")
    print("measured InvertedPendulum-v5 env and vector env", flush=True)
    return rows + pybullet_rows(args, notes) + ragdoll_env_rows(args, notes)


# --------------------------------------------------------------------- main
def _find(rows, engine, mode, scene=None):
    return next((r for r in rows if r["engine"] == engine and r["mode"] == mode
                 and (scene is None or r["scene"] == scene)), None)


def ratio_lines(rows):
    """The ratios of simulated seconds per second that compare like with
    like: lying humanoids batched and alone, each env with its MuJoCo peer."""
    lines = []

    def ratio(ours, theirs, label):
        if ours and theirs and ours["sim_s_per_s"] and theirs["sim_s_per_s"]:
            lines.append(f"{label}: {ours['sim_s_per_s'] / theirs['sim_s_per_s']:.3g}x simulated s per s")

    ground = [r for r in rows if r["engine"] == "ragdoll" and r["scene"] == "ragdoll_ground"
              and r["mode"].startswith("batched")]
    for ref_mode in ("rollout-implicitfast-2thread", "rollout-rk4-2thread"):
        ref = _find(rows, "mujoco", ref_mode)
        for r in ground:
            if r["worlds"] >= 16 and ref:
                ratio(r, ref, f"ragdoll_ground {r['mode']} W={r['worlds']} / mujoco humanoid_ground {ref_mode} "
                              f"W={ref['worlds']}")
    one = next((r for r in ground if r["worlds"] == 1), None)
    for ref_mode in ("loop-implicitfast", "loop-rk4"):
        ratio(one, _find(rows, "mujoco", ref_mode), f"ragdoll_ground W=1 / mujoco humanoid_ground {ref_mode}")
    ratio(one, _find(rows, "pybullet", "loop"), "ragdoll_ground W=1 / pybullet humanoid_ground loop")
    for ours_id, theirs_id in ENV_PEERS.items():
        for mode in ("env", "vector-env"):
            ours, theirs = _find(rows, "ragdoll", mode, ours_id), _find(rows, "mujoco", mode, theirs_id)
            if ours and theirs:
                ratio(ours, theirs, f"{ours_id} {mode} (W={ours['worlds']}) / {theirs_id} {mode} "
                                    f"(W={theirs['worlds']})")
    return lines


COLUMNS = [
    ("engine", "engine"), ("mode", "mode"), ("scene", "scene"), ("W", "worlds"), ("steps", "steps"),
    ("dt ms", lambda r: None if r["dt_s"] is None else 1e3 * r["dt_s"]),
    ("world-steps/s", "world_steps_per_s"), ("sim s/s", "sim_s_per_s"),
    ("contacts", lambda r: r.get("contacts_per_world")),
    ("state B/world", "state_bytes_per_world"),
    ("B/world (state + step peak)", "bytes_per_world"),
]


def thread_count(text: str) -> int:
    """argparse type of ``--threads``: an integer in 1..NUMBA_NUM_THREADS."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not 1 <= value <= max_threads():
        raise argparse.ArgumentTypeError(f"must be an integer in 1..{max_threads()} "
                                         f"(NUMBA_NUM_THREADS), got {text!r}")
    return value


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
    p.add_argument("--compare-mujoco", action="store_true",
                   help="measure MuJoCo's humanoid (lying, RK4 and implicitfast, mj_step and rollout), "
                        "Humanoid-v5, InvertedPendulum-v5, PyBullet's humanoid and our envs too")
    p.add_argument("--compile", action="store_true",
                   help="measure the cold compile (empty kernel cache) and the warm start in fresh interpreters")
    p.add_argument("--mujoco-worlds", type=positive_int, help=f"worlds of the MuJoCo rollouts (default {MUJOCO_WORLDS})")
    p.add_argument("--settings", type=settings_json, default={}, metavar="JSON",
                   help="engine settings over each ragdoll scene's own, e.g. '{\"articulated_contacts\": false}'")
    p.add_argument("--threads", type=thread_count, nargs="+", default=None, metavar="T",
                   help=f"step each W on T threads (engine.set_threads), rows of mode batched-Tthr; W below "
                        f"{SERIAL_BELOW} steps on one thread whatever T: one row, at the smallest T (default: 1 and "
                        f"all cores, {' '.join(map(str, DEFAULT_THREADS))})")
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
    args.threads = sorted(set(args.threads or DEFAULT_THREADS))
    args.repeats = args.repeats or 3
    args.mujoco_worlds = args.mujoco_worlds or MUJOCO_WORLDS
    return args


def main(argv=None):
    args = parse_args(argv)
    notes = []
    rows = ragdoll_rows(args, notes)
    if args.compare_mujoco:
        rows += mujoco_rows(args, notes)
    if args.compile:
        rows += compile_rows(notes)
    print()
    print_table(rows, COLUMNS, title="Throughput (median of repeats; B/world = state.nbytes()/W "
                                     "+ tracemalloc peak of one step / W)")
    for r in rows:
        if "seconds" in r:
            print(f"{r['mode']}: {r['seconds']:.2f} s from a fresh interpreter to the first step of {r['scene']}")
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
