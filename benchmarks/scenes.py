"""Hard-case scenes shared by ``benchmarks.stability`` and ``tests/stability``.

Each scene builder returns a :class:`Case`: the compiled model, its initial
state, how long it runs (``duration`` in full, ``quick_duration`` for
``--quick`` and the fast tests), an optional controller (motor torques per
step), and the bounds a stable engine should meet on it (stated with the case,
checked by the tests). :func:`run_case` steps a case and measures, per step:

* the largest body speed |v| (m/s) over worlds and bodies;
* the largest fling speed (m/s): the speed a body has beyond what falling
  from its highest point so far explains, sqrt(max(0, |v|² - 2 g Δh)) (Δh
  the drop from that point along gravity): a solver pushing bodies apart
  shows up here, a box toppling off a pile does not;
* the energy rise E(t) - E(0) - W_motor(t) (J), with E from
  :func:`engine.diagnostics.total_energy` and W_motor the work the motors did
  (each step's torque times the turn its joint made: ``_motor_work``);
* the largest joint anchor error (m, :meth:`engine.joints.JointSet.anchor_error`);
* the deepest penetration (m): -min of ``state.contact_separation`` over its
  valid (finite) entries, 0 when nothing overlaps (the narrow phase runs at the
  start of each step, so this is the overlap of the state the step began from);
* whether any NaN/inf appeared (the engine raises ``SimulationError``; the run
  stops there and reports it).

Energy scale: the start's energy with potentials measured in the scene's own
frame (ground at height 0 before any offset), so the 10 km variants have the
same scale as the near ones; |E_rel(0)| is the scale the relative figures use.

Far variants (``*_far``): every position, joint pin and the ground height are
moved by ``FAR_OFFSET`` = (10 km, 10 km, 10 km); a ground plane is infinite,
so only its height needs to move.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

import engine as e
from engine import math3d
from engine.diagnostics import total_energy
from engine.humanoid import add_humanoid, pose

FAR_OFFSET = np.array([1.0e4, 1.0e4, 1.0e4])  # m


@dataclass
class Case:
    """A hard-case scene and the bounds it is held to.

    duration, quick_duration: simulated seconds of the full and quick runs.
    controller: ``f(step_index, state) -> Control or None`` (None: passive).
    rest_time, rest_speed: by ``rest_time`` s every body's speed is below
        ``rest_speed`` m/s and stays so (None: the scene does not come to rest).
    speed_bound: every fling speed (speed beyond a fall from the body's
        highest point so far, see the module docstring) at every step is below
        this (m/s; None: unchecked).
    energy_tol: J; E(t) - E(0) - W_motor(t) <= energy_tol at every step.
    anchor_bound: m; largest joint anchor error at every step.
    penetration_bound: m; largest penetration at every step from
        ``penetration_after`` seconds on (overlap scenes start overlapped).
    """

    name: str
    description: str
    model: e.Model
    state: e.State
    duration: float
    quick_duration: float
    controller: object = None
    rest_time: float | None = None
    rest_speed: float | None = None
    speed_bound: float | None = None
    energy_tol: float = 1.0
    anchor_bound: float | None = None
    penetration_bound: float | None = None
    penetration_after: float = 0.0
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def dt(self) -> float:
        return self.model.settings.dt

    def steps(self, quick: bool) -> int:
        return int(round((self.quick_duration if quick else self.duration) / self.dt))


@dataclass
class Result:
    name: str
    steps: int
    worlds: int
    sim_time: float
    wall_time: float
    nan: bool
    error: str | None
    max_speed_end: float
    energy_start: float  # J, E_rel(0)
    energy_scale: float  # J, |E_rel(0)| (at least 1e-12)
    energy_rise: float  # J, max over steps of E - E0 - W_motor
    motor_work: float  # J, W_motor at the end
    max_anchor_error: float  # m
    max_penetration: float  # m over all steps
    max_penetration_after: float  # m from the case's penetration_after on
    end_penetration: float  # m at the last step
    rest_speed_max: float  # m/s, largest speed from rest_time on (nan if no rest_time)
    max_speed_all: float  # m/s over all steps
    max_fling_speed: float  # m/s over all steps: speed beyond a fall from the body's highest point so far
    series: dict = field(default_factory=dict, repr=False)

    @property
    def energy_rise_rel(self) -> float:
        return self.energy_rise / self.energy_scale

    def row(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "series"}
        d["energy_rise_rel"] = self.energy_rise_rel
        return d


# ------------------------------------------------------------------ measuring
def _energy_rel(model, state, offset):
    """Total energy with gravity's potential measured from the un-offset frame."""
    E = total_energy(model, state)
    if model.gravity is not None and "gravity" in model.effects:
        m = np.where(model.dynamic, model.mass, 0.0).sum()
        E = E + m * float(np.dot(model.gravity, offset))
    return E


def _relative_rotation(model, state):
    """Each joint's child frame relative to its parent frame (W, J, 4): q_r =
    q_p* q_c, whose rate is ½ ω ⊗ q_r with ω the relative angular velocity
    in the parent frame."""
    _, _, fpw, fcw, _, _ = model.joints.frames(state, np.arange(model.num_joints))
    return math3d.quat_mul(math3d.quat_conj(fpw), fcw)


def _motor_work(model, q_before, state, u):
    """The work (J, per world) of a step's motor torques u, held for the
    step: τ times the turn about each motor's parent-frame axis, the
    rotation vector of q_r(after) q_r(before)* (∫ω dt exactly while ω keeps
    its direction in the parent frame; a turn of more than π within one
    step would alias, which the humanoid's limited joints do not reach).
    A trapezoid rule on τ·ω at the step's ends missed what happens between
    them: at full torques a thin arm twists 1.39 rad into its limit within
    one step and stops there, and a world's first step from rest gained
    55 J where the rule counted 44 (``ragdoll_max_torque``)."""
    if u is None or model.num_actuators == 0:
        return np.zeros(state.num_worlds)
    js = model.joints
    turn = math3d.quat_mul(_relative_rotation(model, state), math3d.quat_conj(q_before))
    phi = math3d.quat_to_rotation_vector(turn)  # (W, J, 3), rad
    tau = np.clip(u, -js.act_max, js.act_max)
    if js.breakable:
        tau = tau * ~state.joint_broken[:, js.act_joint]
    return (tau * phi[:, js.act_joint, js.act_axis]).sum(axis=-1)


def _penetration(state):
    if "contact_separation" not in state.arrays:
        return 0.0
    sep = state.contact_separation
    finite = np.isfinite(sep)
    if not finite.any():
        return 0.0
    return max(0.0, -float(sep[finite].min()))


def run_case(case: Case, steps: int | None = None, quick: bool = True, state=None) -> Result:
    """Step ``case`` (a copy of its state) and measure; see the module docstring."""
    model = case.model
    st = (case.state if state is None else state).copy()
    n = case.steps(quick) if steps is None else int(steps)
    dt = model.settings.dt
    E0 = _energy_rel(model, st, case.offset)
    work = np.zeros(st.num_worlds)
    speed = np.zeros(n)
    rise = np.zeros(n)
    anchor = np.zeros(n)
    pen = np.zeros(n)
    fling = np.zeros(n)
    g = model.gravity if ("gravity" in model.effects and model.gravity is not None) else np.zeros(3)
    g_mag = float(np.linalg.norm(g))
    up = -np.asarray(g, float) / g_mag if g_mag > 0 else np.zeros(3)
    apex = st.position @ up  # (W, N) highest point so far along -g
    nan, error = False, None
    t0 = time.perf_counter()
    done = 0
    for k in range(n):
        control = case.controller(k, st) if case.controller is not None else None
        u = None if control is None else control.motor
        q_before = _relative_rotation(model, st) if u is not None and model.num_actuators else None
        try:
            e.step(model, st, control)
        except e.SimulationError as exc:
            nan, error = True, str(exc)
            break
        work += _motor_work(model, q_before, st, u)
        if not np.all(np.isfinite(st.position)) or not np.all(np.isfinite(st.velocity)):
            nan, error = True, "non-finite state"
            break
        v2 = (st.velocity ** 2).sum(-1)
        speed[k] = float(np.sqrt(v2).max())
        height = st.position @ up
        apex = np.maximum(apex, height)
        fling[k] = float(np.sqrt(np.maximum(v2 - 2.0 * g_mag * (apex - height), 0.0)).max())
        rise[k] = float((_energy_rel(model, st, case.offset) - E0 - work).max())
        anchor[k] = float(model.joints.anchor_error(st).max()) if model.num_joints else 0.0
        pen[k] = _penetration(st)
        done = k + 1
    wall = time.perf_counter() - t0
    speed, rise, anchor, pen, fling = speed[:done], rise[:done], anchor[:done], pen[:done], fling[:done]
    t = (np.arange(done) + 1) * dt
    after = t >= case.penetration_after - 1e-12
    rest = t >= (case.rest_time if case.rest_time is not None else math.inf) - 1e-12
    scale = max(float(np.abs(E0).max()), 1e-12)
    return Result(
        name=case.name, steps=done, worlds=st.num_worlds, sim_time=done * dt, wall_time=wall,
        nan=nan, error=error,
        max_speed_end=float(speed[-1]) if done else math.nan,
        energy_start=float(E0.max()), energy_scale=scale,
        energy_rise=float(rise.max()) if done else math.nan,
        motor_work=float(work.max()),
        max_anchor_error=float(anchor.max()) if done else math.nan,
        max_penetration=float(pen.max()) if done else math.nan,
        max_penetration_after=float(pen[after].max()) if after.any() else 0.0,
        end_penetration=float(pen[-1]) if done else math.nan,
        rest_speed_max=float(speed[rest].max()) if rest.any() else math.nan,
        max_speed_all=float(speed.max()) if done else math.nan,
        max_fling_speed=float(fling.max()) if done else math.nan,
        series={"t": t, "speed": speed, "fling": fling, "energy_rise": rise, "anchor": anchor, "penetration": pen},
    )


# ------------------------------------------------------------------ helpers
def _builder(offset, ground=True, **settings):
    b = e.SceneBuilder(**settings)
    if ground:
        b.add_ground(height=float(offset[2]))
    return b


def _q(axis, angle):
    return math3d.quat_from_axis_angle(np.asarray(axis, dtype=float), angle)


def _make(name, description, b, offset, num_worlds=1, **bounds):
    model = b.build()
    return Case(name, description, model, model.initial_state(num_worlds), offset=np.asarray(offset, float),
                **bounds)


def _energy_tol(scale, floor=0.5):
    """The stated energy tolerance: 1 % of the start's |E| scale, at least ``floor`` J."""
    return max(0.01 * abs(scale), floor)


# ------------------------------------------------------------------ scenes
H = 0.25  # half extent of the standard box, m


def mass_ratio_stack(offset=(0, 0, 0)):
    o = np.asarray(offset, float)
    b = _builder(o)
    b.add_body("light", e.Box((H, H, H)), mass=1.0, position=o + (0, 0, H))
    b.add_body("heavy", e.Box((H, H, H)), mass=100.0, position=o + (0, 0, 3 * H + 0.001))
    return _make("mass_ratio_stack", "100 kg box resting on a 1 kg box", b, o,
                 duration=5.0, quick_duration=2.0, rest_time=1.0, rest_speed=0.05,
                 energy_tol=_energy_tol(101 * 9.81 * 0.5), penetration_bound=0.02)


def mass_ratio_sandwich(offset=(0, 0, 0)):
    o = np.asarray(offset, float)
    b = _builder(o)
    b.add_body("heavy_low", e.Box((H, H, H)), mass=100.0, position=o + (0, 0, H))
    b.add_body("light", e.Box((H, H, H)), mass=1.0, position=o + (0, 0, 3 * H + 0.001))
    b.add_body("heavy_top", e.Box((H, H, H)), mass=100.0, position=o + (0, 0, 5 * H + 0.002))
    return _make("mass_ratio_sandwich", "1 kg box between two 100 kg boxes", b, o,
                 duration=5.0, quick_duration=2.0, rest_time=1.0, rest_speed=0.05,
                 energy_tol=_energy_tol(201 * 9.81 * 0.75), penetration_bound=0.02)


def ball_and_chain(offset=(0, 0, 0), links=10):
    """A 100 kg ball on a chain of 1 kg links, pinned to the world, released horizontal."""
    o = np.asarray(offset, float)
    b = _builder(o, ground=False)
    L, r = 0.2, 0.03
    pin = o + (0, 0, 3.0)
    q = _q((0, 1, 0), math.pi / 2)  # capsule axis along +x
    prev = None
    for i in range(links):
        b.add_body(f"link{i}", e.Capsule(r, L / 2 - r), mass=1.0, position=pin + ((i + 0.5) * L, 0, 0), orientation=q)
        b.add_ball(f"j{i}", prev, f"link{i}", anchor=pin + (i * L, 0, 0))
        prev = f"link{i}"
    R = 0.15
    b.add_body("ball", e.Sphere(R), mass=100.0, position=pin + (links * L + R, 0, 0))
    b.add_ball("j_ball", prev, "ball", anchor=pin + (links * L, 0, 0))
    # energy scale: drop of the ball's centre when it hangs, m g l
    return _make("ball_and_chain", f"100 kg ball on {links} 1 kg links, swinging from horizontal", b, o,
                 duration=10.0, quick_duration=3.0, energy_tol=_energy_tol(100 * 9.81 * 2.15),
                 anchor_bound=0.01)


def box_stack(offset=(0, 0, 0), n=20, half=H, name=None, duration=10.0):
    """A column of ``n`` cubes of half extent ``half`` (m), 1 kg each, 1 mm
    apart, on the ground; ``duration`` s simulated in the full run."""
    o = np.asarray(offset, float)
    b = _builder(o)
    for i in range(n):
        b.add_body(f"box{i}", e.Box((half, half, half)), mass=1.0, position=o + (0, 0, half + i * (2 * half + 0.001)))
    return _make(name or f"stack_{n}", f"vertical stack of {n} boxes ({2 * half:g} m, 1 kg)", b, o,
                 duration=duration, quick_duration=3.0, rest_time=2.0, rest_speed=0.05,
                 energy_tol=_energy_tol(n * 9.81 * half * n), penetration_bound=0.02)


def small_box_stack(offset=(0, 0, 0)):
    """The stack of 20 with 20 cm boxes: a column 4 m tall of boxes a fifth
    of a metre wide, where the 0.5 m boxes' column is 10 m of half-metre ones."""
    return box_stack(offset, half=0.1, name="stack_20_small", duration=5.0)


def pyramid(offset=(0, 0, 0), rows=10):
    o = np.asarray(offset, float)
    b = _builder(o)
    k = 0
    for row in range(rows):
        count = rows - row
        for j in range(count):
            x = (j - (count - 1) / 2) * (2 * H + 0.01)
            b.add_body(f"box{k}", e.Box((H, H, H)), mass=1.0, position=o + (x, 0, H + row * (2 * H + 0.001)))
            k += 1
    return _make(f"pyramid_{rows}", f"pyramid of {rows} rows ({k} boxes)", b, o,
                 duration=10.0, quick_duration=2.0, rest_time=1.5, rest_speed=0.05,
                 energy_tol=_energy_tol(k * 9.81 * 1.5), penetration_bound=0.02)


def _overlap_bounds(n, rest_time=2.5):
    """Bounds of a scene of ``n`` 1 kg boxes created overlapping."""
    # Separating overlap lifts boxes: the solver's push-out does work. Allowance:
    # the potential of lifting every box by its full size, n m g 2H.
    return dict(duration=10.0, quick_duration=3.0, speed_bound=2.0, rest_time=rest_time, rest_speed=0.1,
                energy_tol=n * 1.0 * 9.81 * 2 * H, penetration_bound=0.02, penetration_after=2.0)


def overlap_recovery(offset=(0, 0, 0), base=4, depth=2, overlap=0.25):
    """Solver2D's overlap recovery in 3D: a pyramid ``base`` boxes wide, ``depth``
    deep (4 x 2: 20 boxes), whose neighbours overlap by ``overlap`` of a box's
    size along each axis (Box2D samples, "Robustness / Overlap Recovery": base 4,
    overlap 0.25); the bottom row rests on the ground."""
    o = np.asarray(offset, float)
    b = _builder(o)
    pitch = 2 * H * (1.0 - overlap)
    n = 0
    for row in range(base):
        count = base - row
        for j in range(count):
            for d in range(depth):
                p = ((j - (count - 1) / 2) * pitch, (d - (depth - 1) / 2) * pitch, H + row * pitch)
                b.add_body(f"box{n}", e.Box((H, H, H)), mass=1.0, position=o + p)
                n += 1
    return _make("overlap_recovery", f"pyramid of {n} boxes created overlapping by {overlap:.0%}", b, o,
                 **_overlap_bounds(n))


def overlap_column(offset=(0, 0, 0), n=20, seed=0):
    """Harsher than Solver2D's: 20 boxes created deep inside each other (centres within
    a 0.6 m x 0.6 m x 2 m column, random orientations). Pushed apart, the upper
    boxes fall up to 2 m onto the others (5.4 m/s, most of it the fall: the fling
    speed is about 2 m/s) and tumble off the pile until about 4 s, so rest is
    asked from 4.5 s."""
    o = np.asarray(offset, float)
    rng = np.random.default_rng(seed)
    b = _builder(o)
    for i in range(n):
        p = (rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), H + 0.1 * i)
        qv = rng.normal(size=4)
        b.add_body(f"box{i}", e.Box((H, H, H)), mass=1.0, position=o + p, orientation=qv / np.linalg.norm(qv))
    return _make("overlap_column", f"{n} boxes created deep inside each other", b, o,
                 **_overlap_bounds(n, rest_time=4.5))


def _humanoid_lying(b, prefix, pelvis_pos, yaw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = add_humanoid(b, prefix=prefix, torque_scale=0.0)
    q = math3d.quat_mul(_q((0, 0, 1), yaw), _q((0, 1, 0), math.pi / 2))  # face down, head along +x
    return h, q, np.asarray(pelvis_pos, float)


def _apply_pose(model, state, b, poses):
    """Set the bodies of each humanoid in ``poses`` [(humanoid, root_q, root_pos)]."""
    pos = state.position[0].copy()
    quat = state.orientation[0].copy()
    for h, q, p in poses:
        P, Q = pose(h, b, {}, root_position=p, root_orientation=q)
        idx = np.array(list(h.bodies.values()))
        pos[idx], quat[idx] = P[idx], Q[idx]
    state.position[...] = pos
    state.orientation[...] = quat


def ragdoll_pile(offset=(0, 0, 0), count=10):
    o = np.asarray(offset, float)
    b = _builder(o)
    poses = []
    for k in range(count):
        poses.append(_humanoid_lying(b, f"r{k}_", o + (0.1 * (k % 3), 0.1 * (k % 2), 0.35 + 0.45 * k), 0.7 * k))
    model = b.build()
    state = model.initial_state(1)
    _apply_pose(model, state, b, poses)
    return Case(f"ragdoll_pile_{count}", f"{count} passive ragdolls dropped on each other", model, state,
                duration=6.0, quick_duration=1.0, rest_time=5.0, rest_speed=0.2,
                energy_tol=_energy_tol(count * 75 * 9.81 * (0.35 + 0.45 * (count - 1) / 2)),
                anchor_bound=0.01, penetration_bound=0.05, offset=o)


def sphere_grid(offset=(0, 0, 0), n=10):
    """n x n spheres joined by ball joints to their grid neighbours, pinned at two corners."""
    o = np.asarray(offset, float)
    b = _builder(o, ground=False)
    s = 0.2
    z = 3.0
    for i in range(n):
        for j in range(n):
            b.add_body(f"s{i}_{j}", e.Sphere(0.05), mass=0.1, position=o + (i * s, j * s, z))
    for i in range(n):
        for j in range(n):
            if i + 1 < n:
                b.add_ball(f"x{i}_{j}", f"s{i}_{j}", f"s{i + 1}_{j}", anchor=o + ((i + 0.5) * s, j * s, z))
            if j + 1 < n:
                b.add_ball(f"y{i}_{j}", f"s{i}_{j}", f"s{i}_{j + 1}", anchor=o + (i * s, (j + 0.5) * s, z))
    b.add_ball("pin_a", None, "s0_0", anchor=o + (0, 0, z))
    b.add_ball("pin_b", None, f"s{n - 1}_0", anchor=o + ((n - 1) * s, 0, z))
    return _make("sphere_grid", f"{n}x{n} spheres on ball joints, pinned at two corners", b, o,
                 duration=10.0, quick_duration=2.0, energy_tol=_energy_tol(n * n * 0.1 * 9.81 * z),
                 anchor_bound=0.01)


def chain_loop(offset=(0, 0, 0), links=10):
    """A slack chain of 1 kg links pinned at both ends (a loop through the
    world) with a 20 kg ball hanging from its middle, released lying flat."""
    o = np.asarray(offset, float)
    b = _builder(o, ground=False)
    L, r, span = 0.2, 0.03, 1.6
    half = links // 2
    # A V in the horizontal plane: each half reaches span / 2 along x.
    c = span / 2 / (half * L)
    dirs = (np.array([c, math.sqrt(1 - c * c), 0.0]), np.array([c, -math.sqrt(1 - c * c), 0.0]))
    pin = o + (0, 0, 3.0)
    p = pin.copy()
    prev = None
    for i in range(links):
        d = dirs[0] if i < half else dirs[1]
        axis = np.cross((0.0, 0.0, 1.0), d)
        q = _q(axis / np.linalg.norm(axis), math.pi / 2)  # capsule axis (local z) along d
        b.add_body(f"link{i}", e.Capsule(r, L / 2 - r), mass=1.0, position=p + d * L / 2, orientation=q)
        b.add_ball(f"j{i}", prev, f"link{i}", anchor=p)
        p = p + d * L
        prev = f"link{i}"
        if i == half - 1:
            tip = p.copy()
    b.add_ball(f"j{links}", prev, None, anchor=p)  # the second pin closes the loop
    R = 0.12
    b.add_body("ball", e.Sphere(R), mass=20.0, position=tip + (0, 0, -0.2))
    b.add_ball("j_ball", f"link{half - 1}", "ball", anchor=tip)
    # energy scale: the ball and chain falling about 1.5 m
    return _make("chain_loop", f"{links} 1 kg links pinned at both ends with a 20 kg ball, swinging", b, o,
                 duration=10.0, quick_duration=3.0, energy_tol=_energy_tol(30 * 9.81 * 1.5), anchor_bound=0.01)


def ragdoll_impact(offset=(0, 0, 0), speed=100.0):
    o = np.asarray(offset, float)
    b = _builder(o)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = add_humanoid(b, torque_scale=0.0)
    model = b.build()
    state = model.initial_state(1)
    q = _q(np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0), math.radians(30))
    _apply_pose(model, state, b, [(h, q, o + (0, 0, 1.2))])
    state.velocity[..., 2] = np.where(model.dynamic, -speed, 0.0)
    scale = 0.5 * 75 * speed ** 2
    # Rigid joints (the defaults) keep the tilted body whole: the friction that
    # stops its feet turns the fall into 20 m/s of skid (limited by mu_k times
    # the normal impulse; here ~0.2 of it), which bone on concrete
    # (mu_k 0.63) takes ~3 s more to stop at mu_k g = 6.2 m/s^2: measured 5.8,
    # at rest by 4.5 s, 52 m away. Soft joints (SOFT_JOINTS) absorbed the
    # skid in the joints and rested by 2.7 s.
    return Case(f"ragdoll_impact_{int(speed)}", f"passive ragdoll hitting the ground at {speed:g} m/s", model,
                state, duration=6.0, quick_duration=1.5, rest_time=5.0, rest_speed=0.2,
                energy_tol=_energy_tol(scale), anchor_bound=0.05, penetration_bound=0.05,
                penetration_after=0.2, offset=o)


def _standing_humanoid(offset):
    """The model of a scene with the ground and the humanoid standing on it at ``offset``."""
    b = _builder(offset)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b, position=offset)
    return b.build()


#: (drop height of the soles, m; tilt, rad) of each world of ``ragdoll_drops``
DROPS = ((0.5, 0.0), (1.0, 0.0), (1.5, 0.0), (1.0, 0.15), (1.2, -0.2), (0.8, 0.1))


def _dropped_humanoids(drops, offset):
    """The standing humanoid's model and a state with one drop per world:
    ``drops`` (height of the soles in m, tilt in rad about a horizontal axis)."""
    model = _standing_humanoid(offset)
    state = model.initial_state(len(drops))
    dyn = model.dynamic
    axis = np.array([1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3)
    for w, (height, tilt) in enumerate(drops):
        q = np.broadcast_to(_q(axis, tilt), (int(dyn.sum()), 4))
        p = state.position[w, dyn]
        centre = p.mean(axis=0)
        state.position[w, dyn] = centre + math3d.quat_rotate(q, p - centre) + (0.0, 0.0, height)
        state.orientation[w, dyn] = math3d.quat_mul(q, state.orientation[w, dyn])
    return model, state


def ragdoll_drops(offset=(0, 0, 0)):
    """The standing humanoid, limp (no motor torque needed), dropped from
    0.5-1.5 m, upright or tilted about a horizontal axis, one drop per world:
    does it land and come to rest? For 7 s, every speed under 2 cm/s from
    5 s: a crumpled ragdoll may still tip over or let a limb slide 3-4.5 s
    after the drop (random drops: 0.69 m/s at 3-3.5 s, at rest by 4.5 s),
    while a limb twitching for good against its limit shows at the end."""
    o = np.asarray(offset, float)
    model, state = _dropped_humanoids(DROPS, o)
    return Case("ragdoll_drops", f"the humanoid dropped {len(DROPS)} ways from 0.5-1.5 m, one per world", model,
                state, duration=7.0, quick_duration=7.0, rest_time=5.0, rest_speed=0.02,
                energy_tol=_energy_tol(75 * 9.81 * 2.5), anchor_bound=0.01, penetration_bound=0.05, offset=o)


def ragdoll_drops_random(offset=(0, 0, 0), seed=2, count=8):
    """``ragdoll_drops`` with drops drawn at random (heights 0.5-1.5 m, tilts
    within ±0.3 rad; seed 2 by default), for 7 s, rest asserted from 5 s as
    in ``ragdoll_drops``: more poses in which a limb could keep twitching
    against its limit."""
    o = np.asarray(offset, float)
    rng = np.random.default_rng(seed)
    drops = [(float(rng.uniform(0.5, 1.5)), float(rng.uniform(-0.3, 0.3))) for _ in range(count)]
    model, state = _dropped_humanoids(drops, o)
    return Case("ragdoll_drops_random", f"the humanoid dropped {count} random ways from 0.5-1.5 m (seed {seed})",
                model, state, duration=7.0, quick_duration=7.0, rest_time=5.0, rest_speed=0.02,
                energy_tol=_energy_tol(75 * 9.81 * 2.5), anchor_bound=0.01, penetration_bound=0.05, offset=o)


class RandomMaxTorque:
    """Every actuated axis at ± its maximum torque, signs redrawn every ``hold`` steps."""

    def __init__(self, model, num_worlds, seed=0, hold=4):
        self.rng = np.random.default_rng(seed)
        self.max = np.asarray(model.joints.act_max, dtype=float)
        self.W = num_worlds
        self.hold = hold
        self.control = e.Control(motor=np.zeros((num_worlds, model.num_actuators)))

    def __call__(self, k, state):
        if k % self.hold == 0:
            self.control.motor = self.rng.choice((-1.0, 1.0), size=(self.W, self.max.size)) * self.max
        return self.control


def ragdoll_max_torque(offset=(0, 0, 0), num_worlds=1, seed=0):
    o = np.asarray(offset, float)
    model = _standing_humanoid(o)
    case = Case("ragdoll_max_torque", "standing ragdoll, every joint at a random ± maximum torque", model,
                model.initial_state(num_worlds), duration=100_000 / 60, quick_duration=2_000 / 60,
                energy_tol=_energy_tol(75 * 9.81 * 1.0), anchor_bound=0.01, penetration_bound=0.05,
                offset=o)
    case.controller = RandomMaxTorque(model, num_worlds, seed)
    return case


def large_dt_ragdoll(offset=(0, 0, 0)):
    o = np.asarray(offset, float)
    b = _builder(o, dt=1 / 30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b, position=o + (0, 0, 0.5), torque_scale=0.0)
    return _make("large_dt_ragdoll", "passive ragdoll dropped from 0.5 m, dt = 1/30 s", b, o,
                 duration=6.0, quick_duration=3.0, rest_time=4.0, rest_speed=0.1,
                 energy_tol=_energy_tol(75 * 9.81 * 1.5), anchor_bound=0.01, penetration_bound=0.03)


def large_dt_stack(offset=(0, 0, 0), n=10):
    o = np.asarray(offset, float)
    b = _builder(o, dt=1 / 30)
    for i in range(n):
        b.add_body(f"box{i}", e.Box((H, H, H)), mass=1.0, position=o + (0, 0, H + i * (2 * H + 0.001)))
    return _make("large_dt_stack", f"stack of {n} boxes, dt = 1/30 s", b, o,
                 duration=10.0, quick_duration=3.0, rest_time=2.0, rest_speed=0.05,
                 energy_tol=_energy_tol(n * 9.81 * H * n), penetration_bound=0.02)


def tiny_bodies(offset=(0, 0, 0)):
    """1 cm boxes stacked five high and 1 cm spheres dropped beside them."""
    o = np.asarray(offset, float)
    b = _builder(o)
    h = 0.005
    for i in range(5):
        b.add_body(f"box{i}", e.Box((h, h, h)), density=700.0, position=o + (0, 0, h + i * (2 * h + 1e-4)))
    for i in range(4):
        b.add_body(f"ball{i}", e.Sphere(h), density=700.0, position=o + (0.05 + 0.03 * i, 0, 0.02 + 0.01 * i))
    return _make("tiny_bodies", "1 cm boxes stacked 5 high and 1 cm spheres dropped", b, o,
                 duration=5.0, quick_duration=2.0, rest_time=1.5, rest_speed=0.01,
                 energy_tol=_energy_tol(1e-4, floor=1e-5), penetration_bound=0.002)


def huge_bodies(offset=(0, 0, 0)):
    """10 m boxes stacked three high and a 10 m sphere dropped beside them."""
    o = np.asarray(offset, float)
    b = _builder(o)
    h = 5.0
    for i in range(3):
        b.add_body(f"box{i}", e.Box((h, h, h)), density=700.0, position=o + (0, 0, h + i * (2 * h + 0.01)))
    b.add_body("ball", e.Sphere(h), density=700.0, position=o + (20.0, 0, h + 2.0))
    m = 700 * 1000
    return _make("huge_bodies", "10 m boxes stacked 3 high and a 10 m sphere dropped", b, o,
                 duration=10.0, quick_duration=4.0, rest_time=3.0, rest_speed=0.1,
                 energy_tol=_energy_tol(4 * m * 9.81 * 10), penetration_bound=0.1)


def stiff_spring(offset=(0, 0, 0)):
    """Springs with k dt²/m >> 1: a 1 kg ball on k = 1e6 N/m (k dt²/m = 278 at 60 Hz)
    stretched 0.1 m, and two 1 kg balls joined by k = 1e7 N/m compressed 0.05 m."""
    o = np.asarray(offset, float)
    b = _builder(o, ground=False)
    b.add_body("bob", e.Sphere(0.05), mass=1.0, position=o + (0, 0, 2.0))
    b.add_spring("hang", None, "bob", anchor_a=o + (0, 0, 3.0), stiffness=1e6, rest_length=0.9)
    b.add_body("a", e.Sphere(0.05), mass=1.0, position=o + (1.0, 0, 2.0))
    b.add_body("c", e.Sphere(0.05), mass=1.0, position=o + (1.25, 0, 2.0))
    b.add_spring("pair", "a", "c", stiffness=1e7, rest_length=0.3)
    scale = 0.5 * 1e6 * 0.1 ** 2 + 0.5 * 1e7 * 0.05 ** 2 + 3 * 9.81 * 2.0
    return _make("stiff_spring", "springs with k dt²/m = 278 and 2778", b, o,
                 duration=5.0, quick_duration=2.0, energy_tol=_energy_tol(scale))


def degenerate_capsules(offset=(0, 0, 0)):
    o = np.asarray(offset, float)
    b = _builder(o)
    q = _q((0, 1, 0), math.pi / 2)
    r = 0.1
    b.add_body("low", e.Capsule(r, 0.4), mass=1.0, position=o + (0, 0, r), orientation=q)
    b.add_body("high", e.Capsule(r, 0.4), mass=1.0, position=o + (0, 0, 3 * r), orientation=q)
    return _make("degenerate_capsules", "two parallel capsules lying on each other", b, o,
                 duration=5.0, quick_duration=2.0, rest_time=2.0, rest_speed=0.05,
                 energy_tol=_energy_tol(2 * 9.81 * 0.4), penetration_bound=0.01)


def degenerate_edges(offset=(0, 0, 0)):
    """A box standing on its edge on a static box's edge, crossed at 90 degrees."""
    o = np.asarray(offset, float)
    b = _builder(o)
    qa = _q((1, 0, 0), math.pi / 4)
    qb = _q((0, 1, 0), math.pi / 4)
    d = H * math.sqrt(2.0)
    b.add_body("base", e.Box((H, H, H)), position=o + (0, 0, d), orientation=qa, static=True)
    b.add_body("top", e.Box((H, H, H)), mass=1.0, position=o + (0, 0, 3 * d + 1e-4), orientation=qb)
    b.add_body("left", e.Box((H, H, H)), mass=1.0, position=o + (2.0, 0, H))
    b.add_body("right", e.Box((H, H, H)), mass=1.0, position=o + (2.0, 0, 3 * H), orientation=_q((0, 0, 1), math.pi / 4))
    b.add_body("edge_a", e.Box((H, H, H)), mass=1.0, position=o + (4.0, 0, H))
    b.add_body("edge_b", e.Box((H, H, H)), mass=1.0, position=o + (4.0 + 2 * H, 0, H))  # face to face at the edge line
    return _make("degenerate_edges", "boxes touching edge to edge (crossed edges, 45° on face, side by side)", b, o,
                 duration=5.0, quick_duration=2.5, rest_time=2.5, rest_speed=0.05,
                 energy_tol=_energy_tol(4 * 9.81 * 1.0), penetration_bound=0.02)


def degenerate_coincident(offset=(0, 0, 0)):
    o = np.asarray(offset, float)
    b = _builder(o)
    b.add_body("a", e.Sphere(0.1), mass=1.0, position=o + (0, 0, 0.5))
    b.add_body("b", e.Sphere(0.1), mass=1.0, position=o + (0, 0, 0.5))
    b.add_body("c", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=o + (1.0, 0, 0.5))
    b.add_body("d", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=o + (1.0, 0, 0.5))
    return _make("degenerate_coincident", "two spheres (and two boxes) with coincident centres", b, o,
                 duration=5.0, quick_duration=3.0, speed_bound=3.0, rest_time=2.5, rest_speed=0.05,
                 energy_tol=4 * 9.81 * 0.2 + 1.0, penetration_bound=0.02, penetration_after=1.5)


#: name -> builder(offset) for the scenes that get a 10 km far variant.
SCENES = {
    "mass_ratio_stack": mass_ratio_stack,
    "mass_ratio_sandwich": mass_ratio_sandwich,
    "ball_and_chain": ball_and_chain,
    "stack_20": box_stack,
    "stack_20_small": small_box_stack,
    "pyramid_10": pyramid,
    "overlap_recovery": overlap_recovery,
    "overlap_column": overlap_column,
    "ragdoll_pile_10": ragdoll_pile,
    "sphere_grid": sphere_grid,
    "chain_loop": chain_loop,
    "ragdoll_impact_100": ragdoll_impact,
    "ragdoll_drops": ragdoll_drops,
    "ragdoll_drops_random": ragdoll_drops_random,
    "ragdoll_max_torque": ragdoll_max_torque,
    "large_dt_ragdoll": large_dt_ragdoll,
    "large_dt_stack": large_dt_stack,
    "tiny_bodies": tiny_bodies,
    "huge_bodies": huge_bodies,
    "stiff_spring": stiff_spring,
    "degenerate_capsules": degenerate_capsules,
    "degenerate_edges": degenerate_edges,
    "degenerate_coincident": degenerate_coincident,
}

#: scenes that also run 10 km from the origin (all the static-scene cases)
FAR_SCENES = ("mass_ratio_stack", "mass_ratio_sandwich", "ball_and_chain", "stack_20", "pyramid_10",
              "overlap_recovery", "overlap_column", "ragdoll_pile_10", "sphere_grid", "chain_loop",
              "ragdoll_impact_100",
              "ragdoll_max_torque", "degenerate_capsules", "degenerate_edges", "degenerate_coincident")


def case_names() -> list[str]:
    return list(SCENES) + [f"{n}_far" for n in FAR_SCENES]


def make_case(name: str) -> Case:
    """The case of that name; ``<scene>_far`` is the scene moved by FAR_OFFSET."""
    far = name.endswith("_far")
    base = name[:-4] if far else name
    if base not in SCENES or (far and base not in FAR_SCENES):
        raise KeyError(f"unknown stability case {name!r}; cases: {case_names()}")
    case = SCENES[base](FAR_OFFSET if far else (0.0, 0.0, 0.0))
    case.name = name
    return case
