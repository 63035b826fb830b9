"""Accuracy against cost: error of analytic or converged references next to wall time.

    python -m benchmarks.accuracy [--quick] [--json PATH] [--out-dir DIR]
        [--scenarios ...] [--settings LABEL ...] [--duration-scale X] [--repeats N]
        [--no-mujoco] [--no-plot] [--from-json PATH]

Scenarios (reference in brackets): pendulum period [elliptic integral] and energy
drift, undamped double pendulum energy [conserved], torque-free spinning box
energy and angular momentum [conserved], mass on a spring period [2π√(m/k)] and
energy, bouncing ball apex heights [e^{2n} h], sliding box stop distance
[v²/(2 μk g)], resting 10-box stack penetration and top drift [at rest], and a
ragdoll falling under random torques [joint anchor error, limit violation,
penetration, and trajectory error against the same scene at a much finer step].

Each scenario runs once per setting of the grid (dt, substeps, iterations,
integrator, solver); wall time is taken around ``step`` only, per chunk of
simulated time, and the median chunk gives ``wall_s_per_sim_s``. Always
writes ``OUT_DIR/accuracy.md`` and (unless ``--no-plot``) ``OUT_DIR/accuracy.png``
(error vs cost, Pareto front), ``--out-dir`` defaulting to ``docs``; the rows
{scenario, settings, errors, wall_s_per_sim_s} go to a JSON file only with
``--json PATH``. ``--from-json PATH`` runs nothing: it redraws accuracy.md and
accuracy.png from such a file.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from dataclasses import replace

import numpy as np

import engine as e
from engine import diagnostics as D
from engine.settings import ACCURATE, SOFT_JOINTS, Settings

from . import scenarios as sc
from .common import format_value, machine_note, positive_float, positive_int, print_table, write_json

# ---------------------------------------------------------------- the grid
DEFAULT = Settings()
THESIS = dict(solver="thesis", integrator="euler", free_contact_relax_passes=0)  # the thesis method, fixed

GRID = [
    ("default", {}),
    ("dt=1/30", dict(dt=1 / 30)),
    ("dt=1/120", dict(dt=1 / 120)),
    ("sub=1", dict(substeps=1)),
    ("sub=2", dict(substeps=2)),
    ("sub=8", dict(substeps=8)),
    ("it=2", dict(iterations=2)),
    ("it=4", dict(iterations=4)),
    ("free relax=0", dict(free_contact_relax_passes=0)),
    ("relax=0", dict(relax_iterations=0, free_contact_relax_passes=0)),
    ("greedy", dict(contact_coloring="greedy")),
    ("euler", dict(integrator="euler")),
    ("rk4", dict(integrator="rk4")),
    ("dt=1/30 sub=1", dict(dt=1 / 30, substeps=1)),
    ("sub=1 relax=0", dict(substeps=1, relax_iterations=0, free_contact_relax_passes=0)),
    ("dt=1/30 sub=1 relax=0", dict(dt=1 / 30, substeps=1, relax_iterations=0, free_contact_relax_passes=0)),
    ("dt=1/120 sub=8 it=2", dict(dt=1 / 120, substeps=8, iterations=2)),
    ("accurate", dict(ACCURATE)),
    ("soft joints", dict(SOFT_JOINTS)),
    ("soft joints sub=8", dict(SOFT_JOINTS, substeps=8)),
    ("thesis dt=1/60", dict(substeps=1, **THESIS)),
    ("thesis dt=1/120", dict(dt=1 / 120, substeps=1, **THESIS)),
    ("thesis dt=1/60 sub=4", dict(substeps=4, **THESIS)),
]
QUICK_GRID = ["default", "accurate", "dt=1/30 sub=1", "dt=1/120 sub=8 it=2", "thesis dt=1/60"]

# Simulated seconds per scenario (full, quick).
DURATIONS = {
    "pendulum": (60.0, 10.0),
    "double_pendulum": (20.0, 5.0),
    "spinning_box": (10.0, 5.0),
    "spring": (10.0, 5.0),
    "bouncing_ball": (3.5, 3.5),
    "sliding_box": (2.5, 2.5),
    "box_stack": (10.0, 3.0),
    "ragdoll": (1.0, 0.25),
}
# Durations set by the physics (five bounces, the box coming to rest): --duration-scale leaves them.
FIXED_DURATION = ("bouncing_ball", "sliding_box")
# Runs per setting (the median wall time is kept): the scenarios that take a
# second or less a run, whose costs (a few hundredths of a wall second per
# simulated second, mostly per-step overhead) a single run on this shared
# machine put 10-30% off, enough to swap two settings on the cost axis.
REPEATS = {"bouncing_ball": 5, "sliding_box": 5}
# Ragdoll reference: dt / DIV with SUBSTEPS substeps and 2 iterations (full, quick).
RAGDOLL_REFERENCE = ((8, 8), (4, 8))
SAMPLE_DT = 1 / 30  # trajectory samples and torque schedule: a multiple of every dt in the grid
CHUNK_S = 0.25  # simulated seconds per timing chunk

# Metric plotted per scenario (error vs cost).
PRIMARY = {
    "pendulum": "period_rel_error",
    "double_pendulum": "energy_max_dev",
    "spinning_box": "energy_max_rel_dev",
    "spring": "period_rel_error",
    "bouncing_ball": "apex_worst_rel_error",
    "sliding_box": "stop_distance_rel_error",
    "box_stack": "rest_penetration_m",
    "ragdoll": "bodies_traj_rms_m",
}


def settings_dict(label, s: Settings, **extra):
    d = {"label": label, "default": s == DEFAULT, "dt": s.dt, "substeps": s.substeps, "iterations": s.iterations,
         "relax_iterations": s.relax_iterations, "free_contact_relax_passes": s.free_contact_relax_passes,
         "integrator": s.integrator, "solver": s.solver,
         "joint_hertz": s.joint_hertz, "joint_damping_ratio": s.joint_damping_ratio,
         "free_joint_hertz": s.free_joint_hertz, "free_joint_geometric_stiffness": s.free_joint_geometric_stiffness,
         "joint_relax": s.joint_relax, "joint_projection_passes": s.joint_projection_passes,
         "contact_hertz": s.contact_hertz, "joint_limits_in_tree": s.limits_in_tree,
         "joint_projection_slop": s.joint_projection_slop, "free_joint_projection_slop": s.free_joint_projection_slop,
         "articulated_contacts": s.contacts_articulated, "articulated_contact_sweeps": s.articulated_contact_sweeps,
         "thesis_baseline": s.solver == "thesis" and s.integrator == "euler"}
    d.update(extra)
    return d


# ------------------------------------------------------------- stepping
class Run:
    """Steps a model, timing only ``step`` per chunk of simulated time."""

    def __init__(self, model, worlds=1):
        self.model = model
        self.state = model.initial_state(worlds)
        self.dt = model.settings.dt
        self.chunk_steps = max(1, int(round(CHUNK_S / self.dt)))
        self.chunks = []
        self._acc = 0.0
        self._n = 0
        self.failed = None

    def step(self, control=None):
        t0 = time.perf_counter()
        e.step(self.model, self.state, control)
        self._acc += time.perf_counter() - t0
        self._n += 1
        if self._n == self.chunk_steps:
            self.chunks.append(self._acc / (self._n * self.dt))
            self._acc, self._n = 0.0, 0

    def wall_s_per_sim_s(self):
        if self.chunks:
            return statistics.median(self.chunks)
        return self._acc / max(self._n * self.dt, 1e-12)


def steps_for(seconds, dt):
    return int(round(seconds / dt))


def crossings(t, x):
    """Times where x crosses zero upwards or downwards, linearly interpolated."""
    i = np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0)
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


# ------------------------------------------------------------ scenarios
def pendulum(s, seconds, ctx):
    model = sc.pendulum(settings=s).build()
    r = Run(model)
    n = steps_for(seconds, s.dt)
    e0 = D.total_energy(model, r.state)[0]
    scale = sc.PENDULUM_MASS * sc.G * sc.PENDULUM_LENGTH / 2  # energy of the 90° release above the bottom
    xs, es, anchor = np.empty(n), np.empty(n), 0.0
    for i in range(n):
        r.step()
        xs[i] = r.state.position[0, 0, 0]
        es[i] = D.total_energy(model, r.state)[0]
        anchor = max(anchor, float(model.joints.anchor_error(r.state).max()))
    t = s.dt * np.arange(1, n + 1)
    tc = crossings(t, xs)
    exact = sc.pendulum_exact_period(model)
    period = 2 * float(np.mean(np.diff(tc))) if tc.size > 2 else math.nan
    return {"period_rel_error": abs(period - exact) / exact,
            "energy_drift": abs(es[-1] - e0) / scale,
            "energy_max_dev": float(np.max(np.abs(es - e0))) / scale,
            "anchor_error_max_m": anchor}, r.wall_s_per_sim_s()


def double_pendulum(s, seconds, ctx):
    model = sc.double_pendulum(settings=s).build()
    r = Run(model)
    e0 = D.total_energy(model, r.state)[0]
    scale = 2 * 1.0 * sc.G * 0.5
    worst, anchor = 0.0, 0.0
    for _ in range(steps_for(seconds, s.dt)):
        r.step()
        worst = max(worst, abs(D.total_energy(model, r.state)[0] - e0) / scale)
        anchor = max(anchor, float(model.joints.anchor_error(r.state).max()))
    return {"energy_drift": abs(D.total_energy(model, r.state)[0] - e0) / scale, "energy_max_dev": worst,
            "anchor_error_max_m": anchor}, r.wall_s_per_sim_s()


def spinning_box(s, seconds, ctx):
    model = sc.spinning_box(settings=s).build()
    r = Run(model)
    k0 = D.kinetic_energy(model, r.state)[0]
    l0 = D.angular_momentum(model, r.state)[0]
    dk = dl = 0.0
    for _ in range(steps_for(seconds, s.dt)):
        r.step()
        dk = max(dk, abs(D.kinetic_energy(model, r.state)[0] - k0) / k0)
        dl = max(dl, float(np.linalg.norm(D.angular_momentum(model, r.state)[0] - l0) / np.linalg.norm(l0)))
    return {"energy_max_rel_dev": dk, "angmom_max_rel_dev": dl}, r.wall_s_per_sim_s()


def spring(s, seconds, ctx):
    model = sc.spring_mass(settings=s).build()
    r = Run(model)
    n = steps_for(seconds, s.dt)
    e0 = D.total_energy(model, r.state)[0]
    xs, worst = np.empty(n), 0.0
    for i in range(n):
        r.step()
        xs[i] = r.state.position[0, 0, 0] - 1.0
        worst = max(worst, abs(D.total_energy(model, r.state)[0] - e0) / e0)
    tc = crossings(s.dt * np.arange(1, n + 1), xs)
    exact = 2 * math.pi * math.sqrt(sc.SPRING_M / sc.SPRING_K)
    period = 2 * float(np.mean(np.diff(tc))) if tc.size > 2 else math.nan
    return {"period_rel_error": abs(period - exact) / exact, "energy_max_dev": worst}, r.wall_s_per_sim_s()


def bouncing_ball(s, seconds, ctx, bounces=5):
    model = sc.bouncing_ball(settings=s).build()
    e_r = model.materials.restitution("rubber", "concrete")
    r = Run(model)
    i = model.body_index("ball")
    apexes = []
    z_prev, v_prev = r.state.position[0, i, 2], 0.0
    pen = 0.0
    for k in range(steps_for(seconds, s.dt)):
        r.step()
        z, v = r.state.position[0, i, 2], r.state.velocity[0, i, 2]
        pen = max(pen, sc.BALL_RADIUS - z)
        if k > 0 and v_prev > 0 >= v:  # apex between the two steps: ballistic from the previous
            apexes.append(max(z, z_prev + v_prev ** 2 / (2 * sc.G)) - sc.BALL_RADIUS)
        z_prev, v_prev = z, v
    expected = [e_r ** (2 * n) * sc.BALL_DROP for n in range(1, bounces + 1)]
    got = (apexes + [0.0] * bounces)[:bounces]
    errs = [abs(g - x) / x for g, x in zip(got, expected)]
    return {"apex_worst_rel_error": max(errs), "apex1_rel_error": errs[0], "apexes_found": float(len(apexes)),
            "max_penetration_m": max(pen, 0.0)}, r.wall_s_per_sim_s()


def sliding_box(s, seconds, ctx):
    model = sc.sliding_box(settings=s).build()
    mu_k = model.materials.friction("wood", "wood")[1]
    r = Run(model)
    i = model.body_index("box")
    x0 = r.state.position[0, i, 0]
    pen = 0.0
    for _ in range(steps_for(seconds, s.dt)):
        r.step()
        pen = max(pen, float(sc.ground_penetration(model, r.state)[0]))
    exact = sc.SLIDE_V0 ** 2 / (2 * mu_k * sc.G)
    d = r.state.position[0, i, 0] - x0
    return {"stop_distance_rel_error": abs(d - exact) / exact, "final_speed": float(np.linalg.norm(r.state.velocity[0, i])),
            "max_penetration_m": pen}, r.wall_s_per_sim_s()


def box_stack(s, seconds, ctx, n=10):
    model = sc.box_stack(n, settings=s).build()
    r = Run(model)
    idx = [model.body_index(f"box_{k}") for k in range(n)]
    top0 = r.state.position[0, idx[-1]].copy()
    h = sc.STACK_HALF[2]
    pen = rest_pen = 0.0
    n = steps_for(seconds, s.dt)
    for i in range(n):
        r.step()
        z = r.state.position[0, idx, 2]
        # Box-box overlap from the centre gaps (the column stays upright) and ground penetration.
        p = max(float(np.max(2 * h - np.diff(z), initial=0.0)), float(sc.ground_penetration(model, r.state)[0]))
        pen = max(pen, p)
        if i >= n // 2:  # at rest: the second half of the run
            rest_pen = max(rest_pen, p)
    drift = r.state.position[0, idx[-1]] - top0
    return {"max_penetration_m": pen, "rest_penetration_m": rest_pen, "top_drift_m": float(np.linalg.norm(drift)),
            "top_drift_xy_m": float(np.linalg.norm(drift[:2]))}, r.wall_s_per_sim_s()


def _ragdoll_model(s):
    b, _ = sc.ragdoll(settings=s)
    return b.build()


def _ragdoll_torques(model, seconds, seed=0):
    max_torque = np.array([a.max_torque for a in model.actuators])
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, (int(math.ceil(seconds / SAMPLE_DT)) + 1, model.num_actuators)) * max_torque


def _ragdoll_trajectory(model, seconds, torques, measure=True):
    r = Run(model)
    dt = model.settings.dt
    per_sample = int(round(SAMPLE_DT / dt))
    samples = [r.state.position[0].copy()]
    anchor = limit = pen = 0.0
    for k in range(steps_for(seconds, dt)):
        r.step(e.Control(motor=torques[k // per_sample][None]))
        if measure:
            anchor = max(anchor, float(model.joints.anchor_error(r.state).max()))
            limit = max(limit, float(model.joints.limit_violation(r.state).max()))
            pen = max(pen, float(sc.ground_penetration(model, r.state)[0]))
        if (k + 1) % per_sample == 0:
            samples.append(r.state.position[0].copy())
    return np.array(samples), (anchor, limit, pen), r.wall_s_per_sim_s()


def ragdoll(s, seconds, ctx):
    model = _ragdoll_model(s)
    torques = _ragdoll_torques(model, seconds)
    if "ragdoll_reference" not in ctx:
        div, sub = ctx["ragdoll_reference_spec"]
        # Rigid limits throughout: the soft margin at the limits
        # (``limit_soft_margin``) is an approximation the rows pay for, not physics.
        ref_model = model.with_settings(dt=DEFAULT.dt / div, substeps=sub, iterations=2, limit_soft_margin=0.0)
        t0 = time.perf_counter()
        ctx["ragdoll_reference"] = _ragdoll_trajectory(ref_model, seconds, torques, measure=False)[0]
        print(f"  ragdoll reference dt=1/{round(1 / ref_model.settings.dt)} substeps={sub}: "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    ref = ctx["ragdoll_reference"]
    traj, (anchor, limit, pen), wall = _ragdoll_trajectory(model, seconds, torques)
    m = min(len(ref), len(traj))
    d = np.linalg.norm(traj[:m] - ref[:m], axis=-1)  # (samples, bodies)
    pelvis = model.body_index("pelvis")
    dyn = model.dynamic
    return {"anchor_error_max_m": anchor, "limit_violation_max_rad": limit, "max_penetration_m": pen,
            "pelvis_traj_max_m": float(d[:, pelvis].max()),
            "bodies_traj_rms_m": float(np.sqrt(np.mean(d[:, dyn] ** 2))),
            "bodies_traj_max_m": float(d[:, dyn].max())}, wall


SCENARIOS = {
    "pendulum": pendulum,
    "double_pendulum": double_pendulum,
    "spinning_box": spinning_box,
    "spring": spring,
    "bouncing_ball": bouncing_ball,
    "sliding_box": sliding_box,
    "box_stack": box_stack,
    "ragdoll": ragdoll,
}


# --------------------------------------------------------------- mujoco
MJ_PENDULUM = """
<mujoco>
  <option gravity="0 0 -9.80665" timestep="{timestep}"><flag contact="disable" energy="enable"/></option>
  <worldbody>
    <body name="rod">
      <joint name="pivot" type="hinge" axis="0 1 0" pos="0 0 0"/>
      <geom type="capsule" fromto="0 0 -0.05 0 0 -0.45" size="0.05" mass="1"/>
    </body>
  </worldbody>
</mujoco>
"""

MJ_SLIDE = """
<mujoco>
  <option gravity="0 0 -9.80665" timestep="{timestep}"/>
  <worldbody>
    <geom type="plane" size="20 20 0.1" friction="{mu} 0.005 0.0001"/>
    <body name="box" pos="0 0 {hz}">
      <freejoint/>
      <geom type="box" size="{hx} {hy} {hz}" mass="1" friction="{mu} 0.005 0.0001"/>
    </body>
  </worldbody>
</mujoco>
"""


def _mj_timed(mujoco, m, d, seconds, observe):
    dt = m.opt.timestep
    n = steps_for(seconds, dt)
    chunk = max(1, int(round(CHUNK_S / dt)))
    chunks, acc = [], 0.0
    for k in range(n):
        t0 = time.perf_counter()
        mujoco.mj_step(m, d)
        acc += time.perf_counter() - t0
        observe(k)
        if (k + 1) % chunk == 0:
            chunks.append(acc / (chunk * dt))
            acc = 0.0
    return statistics.median(chunks) if chunks else acc / (n * dt)


def mujoco_pendulum(mujoco, timestep, seconds):
    m = mujoco.MjModel.from_xml_string(MJ_PENDULUM.format(timestep=timestep))
    d = mujoco.MjData(m)
    d.qpos[0] = math.pi / 2
    mujoco.mj_forward(m, d)
    e0 = d.energy.sum()
    n = steps_for(seconds, timestep)
    xs, es = np.empty(n), np.empty(n)

    def observe(k):
        xs[k] = d.xipos[1, 0]
        es[k] = d.energy.sum()

    wall = _mj_timed(mujoco, m, d, seconds, observe)
    mujoco.mj_forward(m, d)
    es[-1] = d.energy.sum()
    # Exact period from MuJoCo's own inertia about the pivot.
    from scipy.special import ellipk

    com = float(np.linalg.norm(m.body_ipos[1]))
    inertia = float(m.body_inertia[1, 1]) + float(m.body_mass[1]) * com ** 2
    small = 2 * math.pi * math.sqrt(inertia / (float(m.body_mass[1]) * sc.G * com))
    exact = small * 2 / math.pi * ellipk(math.sin(math.pi / 4) ** 2)
    tc = crossings(timestep * np.arange(1, n + 1), xs)
    period = 2 * float(np.mean(np.diff(tc)))
    scale = float(m.body_mass[1]) * sc.G * com
    return {"period_rel_error": abs(period - exact) / exact, "energy_drift": abs(es[-1] - e0) / scale,
            "energy_max_dev": float(np.max(np.abs(es - e0))) / scale}, wall


def mujoco_sliding_box(mujoco, timestep, seconds):
    mu = e.MaterialTable().friction("wood", "wood")[1]
    hx, hy, hz = sc.SLIDE_HALF
    m = mujoco.MjModel.from_xml_string(MJ_SLIDE.format(timestep=timestep, mu=mu, hx=hx, hy=hy, hz=hz))
    d = mujoco.MjData(m)
    d.qvel[0] = sc.SLIDE_V0
    x0 = d.qpos[0]
    wall = _mj_timed(mujoco, m, d, seconds, lambda k: None)
    exact = sc.SLIDE_V0 ** 2 / (2 * mu * sc.G)
    return {"stop_distance_rel_error": abs(d.qpos[0] - x0 - exact) / exact,
            "final_speed": float(np.linalg.norm(d.qvel[:3]))}, wall


MUJOCO_NOTE = ("MuJoCo builds the pendulum and the sliding box (friction 0.2 on both geoms), default integrator; "
               "the bouncing ball is not compared (restitution through solref is not the same model).")


def mujoco_rows(scenarios, durations, notes):
    try:
        import mujoco
    except ImportError as exc:
        notes.append(f"MuJoCo rows skipped: {exc}")
        return []
    rows = []
    runners = {"pendulum": mujoco_pendulum, "sliding_box": mujoco_sliding_box}
    for name in scenarios:
        if name not in runners:
            continue
        for timestep in (0.002, 0.0005):
            errors, wall = runners[name](mujoco, timestep, durations[name])
            label = f"mujoco ts={timestep:g}" + (" (default)" if timestep == 0.002 else "")
            rows.append({"scenario": name, "settings": {"engine": "mujoco", "timestep": timestep, "label": label,
                                                        "default": False, "integrator": "Euler"},
                         "errors": errors, "wall_s_per_sim_s": wall})
            print(f"  {name:16s} {label:26s} wall/sim {wall:.3g}", flush=True)
    notes.append(MUJOCO_NOTE)
    return rows


# ---------------------------------------------------------------- output
def pareto(points):
    """Indices of the non-dominated (cost, error) points, by increasing cost."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def _label(r):
    return r["settings"].get("label", "")


def _primary(r, name):
    v = r["errors"].get(PRIMARY[name])
    return v if v is not None and math.isfinite(v) else None


def thesis_dominance(rows):
    """Each thesis-baseline point against this engine's settings, per scenario:
    a list of (scenario, thesis row, the cheapest row of this engine's own
    solver that costs no more and errs less on the scenario's primary metric,
    or None). The acceptance asks for every thesis point to be so dominated."""
    out = []
    for name in dict.fromkeys(r["scenario"] for r in rows):
        sub = [r for r in rows if r["scenario"] == name and r["wall_s_per_sim_s"] is not None
               and r["settings"].get("engine") != "mujoco"]
        ours = [r for r in sub if r["settings"].get("solver") != "thesis" and _primary(r, name) is not None]
        for t in (r for r in sub if r["settings"].get("thesis_baseline")):
            te = _primary(t, name)
            better = [r for r in ours if r["wall_s_per_sim_s"] <= t["wall_s_per_sim_s"]
                      and (te is None or _primary(r, name) < te)]
            out.append((name, t, min(better, key=lambda r: r["wall_s_per_sim_s"]) if better else None))
    return out


def dominance_lines(rows):
    """Markdown lines: the thesis points and what dominates each."""
    found = thesis_dominance(rows)
    if not found:
        return []
    n = sum(1 for *_, d in found if d is not None)
    lines = ["## Against the thesis baseline", "",
             f"{n} of {len(found)} thesis points are dominated: some setting of this engine's solver costs no "
             "more (wall s/sim s) and errs less on the scenario's plotted metric. Costs come from the same run "
             "only where the rows were measured together.", "",
             "| scenario | thesis point | error | wall s/sim s | cheapest dominating setting | its error | its wall s/sim s |",
             "|---|---|---|---|---|---|---|"]
    for name, t, d in found:
        cells = [name, _label(t), format_value(_primary(t, name)), format_value(t["wall_s_per_sim_s"])]
        cells += ([_label(d), format_value(_primary(d, name)), format_value(d["wall_s_per_sim_s"])] if d
                  else ["not dominated", "", ""])
        lines.append("| " + " | ".join(cells) + " |")
    return lines + [""]


def markdown(rows, notes, durations, quick, scale=1.0):
    repeats = {r["scenario"]: r.get("repeats", 1) for r in rows if r["settings"].get("engine") != "mujoco"}
    cmd = "python -m benchmarks.accuracy" + (" --quick" if quick else "") + \
        (f" --duration-scale {scale:g}" if scale != 1.0 else "")
    lines = ["# Accuracy against cost", "",
             f"Written by `{cmd}`. "
             "Each scenario is run once per setting (one world"
             + "".join(f"; {k} {n} times" for k, n in repeats.items() if n > 1)
             + (", in rounds over the settings, the median kept" if any(n > 1 for n in repeats.values()) else "")
             + "); `wall s/sim s` is the median over "
             f"{CHUNK_S:g} s chunks of the wall time spent in `step` per simulated second. "
             "Errors are relative unless the name ends in a unit (`_m`, `_rad`). "
             "**bold** = default `Settings()`; `thesis` rows use solver=thesis with the explicit Euler "
             "integrator (the thesis's method, the baseline).", ""]
    lines.append("Simulated seconds: " + ", ".join(f"{k} {v:g}" for k, v in durations.items()) + ".")
    lines.append("")
    for name in dict.fromkeys(r["scenario"] for r in rows):
        sub = [r for r in rows if r["scenario"] == name]
        metrics = list(dict.fromkeys(k for r in sub for k in r["errors"]))
        pts = [(r["wall_s_per_sim_s"], r["errors"].get(PRIMARY[name])) for r in sub]
        ok = [i for i, p in enumerate(pts) if p[1] is not None and math.isfinite(p[1])
              and p[0] is not None and sub[i]["settings"].get("engine") != "mujoco"]
        front = {ok[i] for i in pareto([pts[i] for i in ok])}
        lines += [f"## {name}", "", f"Pareto front of this engine's settings (on `{PRIMARY[name]}` vs cost) "
                  "marked ◆.", ""]
        head = ["setting", "dt", "sub", "it", "integrator", "solver"] + metrics + ["wall s/sim s", ""]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "---|" * len(head))
        for i, r in enumerate(sub):
            st = r["settings"]
            if st.get("engine") == "mujoco":
                cells = [_label(r), f"{st['timestep']:g}", "-", "-", st.get("integrator", "-"), "mujoco"]
            else:
                cells = [_label(r), f"1/{round(1 / st['dt'])}", str(st["substeps"]), str(st["iterations"]),
                         st["integrator"], st["solver"]]
            if st.get("default"):
                cells[0] = f"**{cells[0]}**"
            cells += [format_value(r["errors"].get(k)) for k in metrics]
            cells += [format_value(r["wall_s_per_sim_s"]), "◆" if i in front else ""]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    lines += dominance_lines(rows)
    lines.append(machine_note())
    lines += [f"note: {n}" for n in notes]
    return "\n".join(lines) + "\n"


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    names = list(dict.fromkeys(r["scenario"] for r in rows))
    cols = min(4, len(names))
    nrows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.6 * nrows), squeeze=False)
    for ax, name in zip(axes.flat, names):
        sub = [r for r in rows if r["scenario"] == name and r["errors"].get(PRIMARY[name]) is not None
               and math.isfinite(r["errors"][PRIMARY[name]])]
        pts = [(r["wall_s_per_sim_s"], max(r["errors"][PRIMARY[name]], 1e-16)) for r in sub]
        for r, (x, y) in zip(sub, pts):
            st = r["settings"]
            if st.get("engine") == "mujoco":
                style = dict(color="tab:green", marker="s")
            elif st.get("thesis_baseline"):
                style = dict(color="tab:red", marker="^")
            else:
                style = dict(color="tab:blue", marker="o")
            ax.scatter([x], [y], s=30, zorder=3, **style)
            if st.get("default"):
                ax.scatter([x], [y], s=220, marker="*", facecolors="none", edgecolors="black", zorder=4)
            ax.annotate(_label(r), (x, y), fontsize=5, xytext=(2, 2), textcoords="offset points")
        ours = [i for i, r in enumerate(sub) if r["settings"].get("engine") != "mujoco"]
        front = [ours[i] for i in pareto([pts[i] for i in ours])]
        if front:
            ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "k--", lw=0.8, zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("wall s per simulated s", fontsize=7)
        ax.set_ylabel(PRIMARY[name], fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color="tab:blue", marker="o", ls="", label="soft step"),
               Line2D([], [], color="tab:red", marker="^", ls="", label="thesis baseline (euler)"),
               Line2D([], [], color="tab:green", marker="s", ls="", label="MuJoCo"),
               Line2D([], [], color="black", marker="*", ls="", mfc="none", ms=12, label="default Settings()"),
               Line2D([], [], color="black", ls="--", label="Pareto front")]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=7)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------ main
def parse_args(argv):
    p = argparse.ArgumentParser(prog="python -m benchmarks.accuracy", description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help=f"{len(QUICK_GRID)} settings, shorter runs")
    p.add_argument("--repeats", type=positive_int, default=None, metavar="N",
                   help="runs per setting, the median wall time kept (default: "
                        + ", ".join(f"{k} {v}" for k, v in REPEATS.items()) + ", the others 1)")
    p.add_argument("--json", metavar="PATH", help="also write the rows as a JSON list to PATH "
                   "(e.g. docs/accuracy.json, which --from-json reads)")
    p.add_argument("--out-dir", metavar="DIR", default="docs",
                   help="where accuracy.md and accuracy.png are written (default docs, the committed report)")
    p.add_argument("--scenarios", nargs="+", choices=list(SCENARIOS), default=list(SCENARIOS))
    p.add_argument("--settings", nargs="+", metavar="LABEL", help="grid rows by label (default: all / quick set)")
    p.add_argument("--duration-scale", type=positive_float, default=1.0, help="multiply the simulated durations (not the bouncing "
                   "ball's or the sliding box's, which the physics sets)")
    p.add_argument("--no-mujoco", action="store_true", help="skip the MuJoCo reference rows")
    p.add_argument("--no-plot", action="store_true", help="skip accuracy.png")
    p.add_argument("--from-json", metavar="PATH", help="run nothing: redraw accuracy.md/.png in --out-dir from rows "
                   "written before with --json (give the same --quick/--duration-scale for the durations line)")
    args = p.parse_args(argv)
    labels = [g[0] for g in GRID]
    args.settings = args.settings or (QUICK_GRID if args.quick else labels)
    unknown = set(args.settings) - set(labels)
    if unknown:
        p.error(f"unknown settings {sorted(unknown)}; choose from {labels}")
    if "default" not in args.settings:
        args.settings = ["default"] + list(args.settings)
    # Checked before the run, not after it: the writes come at the end.
    if os.path.exists(args.out_dir) and not os.path.isdir(args.out_dir):
        p.error(f"--out-dir {args.out_dir}: exists and is not a directory")
    if args.json and os.path.isdir(args.json):
        p.error(f"--json {args.json}: is a directory; give a file path such as {os.path.join(args.json, 'accuracy.json')}")
    args.loaded_rows = None
    if args.from_json:
        if args.json:
            p.error("--json writes the rows of a run, and --from-json runs nothing; give one of them")
        try:
            args.loaded_rows = load_rows(args.from_json)
        except FileNotFoundError:
            p.error(f"--from-json {args.from_json}: no such file (a run writes one with --json PATH)")
        except OSError as exc:
            p.error(f"--from-json {args.from_json}: cannot read it ({exc.strerror or exc})")
        except ValueError as exc:
            p.error(f"--from-json {args.from_json}: {exc}")
        present = {r["scenario"] for r in args.loaded_rows}
        args.scenarios = [name for name in args.scenarios if name in present]
        if not args.scenarios:
            p.error(f"--from-json {args.from_json}: no rows of the chosen scenarios (the file has "
                    f"{sorted(present) or 'none'})")
    return args


def load_rows(path):
    """The rows of an earlier ``--json`` file; ``ValueError`` saying what is
    wrong if it is not such a file."""
    with open(path, encoding="utf-8") as f:
        try:
            rows = json.load(f)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"not JSON ({exc})") from None
    if not isinstance(rows, list):
        raise ValueError("not a JSON list of rows (written by --json PATH)")
    for i, r in enumerate(rows):
        if not (isinstance(r, dict) and r.get("scenario") in SCENARIOS and isinstance(r.get("settings"), dict)
                and isinstance(r.get("errors"), dict) and "wall_s_per_sim_s" in r):
            raise ValueError(f"row {i} is not a row of this benchmark ({{scenario, settings, errors, "
                             f"wall_s_per_sim_s}}, scenario one of {list(SCENARIOS)}): {str(r)[:120]}")
    return rows


def main(argv=None):
    args = parse_args(argv)
    pick = 1 if args.quick else 0
    durations = {k: DURATIONS[k][pick] * (1.0 if k in FIXED_DURATION else args.duration_scale)
                 for k in args.scenarios}
    if "ragdoll" in durations:  # whole samples of the torque schedule
        durations["ragdoll"] = max(SAMPLE_DT, round(durations["ragdoll"] / SAMPLE_DT) * SAMPLE_DT)
    grid = dict(GRID)
    ctx = {"ragdoll_reference_spec": RAGDOLL_REFERENCE[pick]}
    rows, notes = [], []
    if args.from_json:
        loaded = args.loaded_rows
        for r in loaded:
            if r.get("note") and r["note"] not in notes:
                notes.append(r["note"])
    for name in ([] if args.from_json else args.scenarios):
        repeats = args.repeats or REPEATS.get(name, 1)
        walls = {label: [] for label in args.settings}
        results = {}
        for _ in range(repeats):  # rounds over the settings, so a slow spell of the machine hits them all
            for label in args.settings:
                s = replace(DEFAULT, **grid[label])
                t0 = time.perf_counter()
                try:
                    errors, wall = SCENARIOS[name](s, durations[name], ctx)
                    note = None
                except e.SimulationError as exc:
                    errors, wall, note = {}, None, f"{name} / {label}: {exc}"
                errors = {k: (None if v is None or not math.isfinite(v) else float(v)) for k, v in errors.items()}
                if label in results and results[label][0] != errors:
                    raise RuntimeError(f"{name} / {label}: a repeat gave other errors (not deterministic)")
                results[label] = (errors, note)
                if wall is not None:
                    walls[label].append(wall)
                print(f"  {name:16s} {label:26s} {PRIMARY[name]} {format_value(errors.get(PRIMARY[name]))}  "
                      f"wall/sim {format_value(wall)}  ({time.perf_counter() - t0:.1f} s)", flush=True)
        for label in args.settings:
            errors, note = results[label]
            wall = statistics.median(walls[label]) if walls[label] else None
            row = {"scenario": name, "settings": settings_dict(label, replace(DEFAULT, **grid[label])),
                   "errors": errors, "wall_s_per_sim_s": wall, "repeats": repeats}
            if note:
                row["note"] = note
                notes.append(note)
            rows.append(row)
    if args.from_json:
        rows = [r for r in loaded if r["scenario"] in args.scenarios]
        if any(r["settings"].get("engine") == "mujoco" for r in rows):
            notes.append(MUJOCO_NOTE)
    elif not args.no_mujoco:
        rows += mujoco_rows(args.scenarios, durations, notes)
    if "ragdoll" in args.scenarios:
        div, sub = ctx["ragdoll_reference_spec"]
        notes.append(f"ragdoll reference: dt = (1/60)/{div}, {sub} substeps, 2 iterations, rigid limits (no soft margin); "
                     f"trajectories sampled "
                     f"every 1/30 s, uniform random torques in ±max per actuator, held for 1/30 s.")
    notes.append("box_stack penetration: ground from the shapes, box-box from the centre gaps of the column.")

    for name in args.scenarios:
        sub = [r for r in rows if r["scenario"] == name]
        metrics = list(dict.fromkeys(k for r in sub for k in r["errors"]))
        print()
        print_table(sub, [("setting", _label)] + [(k, (lambda r, k=k: r["errors"].get(k))) for k in metrics]
                    + [("wall s/sim s", "wall_s_per_sim_s")], title=f"{name} (simulated {durations[name]:g} s)")
    found = thesis_dominance(rows)
    if found:
        print(f"\nthesis points dominated: {sum(1 for *_, d in found if d is not None)} of {len(found)}")
        for name, t, d in found:
            print(f"  {name:16s} {_label(t):22s} " + (f"by {_label(d)}" if d else "not dominated"))
    print(machine_note())
    for n in notes:
        print(f"note: {n}")
    os.makedirs(args.out_dir, exist_ok=True)
    md = os.path.join(args.out_dir, "accuracy.md")
    with open(md, "w", encoding="utf-8") as f:
        f.write(markdown(rows, notes, durations, args.quick, args.duration_scale))
    print(f"wrote {md}")
    if not args.no_plot:
        png = os.path.join(args.out_dir, "accuracy.png")
        plot(rows, png)
        print(f"wrote {png}")
    if args.json:
        write_json(args.json, rows)
        print(f"wrote {args.json}")
    return rows


if __name__ == "__main__":
    main()
