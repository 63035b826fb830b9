"""Baseline controllers: each maps observations to actions in [-1, 1].

``controller.act(obs)`` takes one observation (D,) or a batch (W, D) and
returns the action (A,) or (W, A), so it drives the single env, the vector
env and the SB3 VecEnv alike. Build one from any of them with
:func:`make_baseline` (or the classes directly)::

    env = gym.make("Ragdoll/InvertedPendulum-v0")
    lqr = make_baseline("lqr", env)
    obs, _ = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(lqr.act(obs))

* :class:`ZeroTorque` — all zeros: the passive ragdoll / falling pendulum.
* :class:`LQR` — pendulums: discrete-time LQR on a linearisation of the
  engine itself (finite differences of one env step around upright, all
  perturbed worlds in one batched step), saturated to [-1, 1].
* :class:`PendulumPD` — pendulums: a PD on the hinge angles.
* :class:`StandingPD` — Balance: holds the standing pose (every joint angle
  0) with a PD per actuated axis on top of gravity compensation and a
  centre-of-mass balance term and frontal-plane load sharing between the
  legs (see the class); at Balance's 60 Hz control it stands through whole
  20 s episodes without pushes, survives single pushes of 10 and 15 N·s from
  every direction, 13 of 16 at 20 N·s and 11 of 16 at 25 N·s (8 directions,
  chest and pelvis; those measured before 2026-12-05), and, since its
  lifted-foot ankle gains of 2026-12-05, 96.25% of its 20 s episodes under
  the default pushes (12 of 320 fall; figures in the README).

scipy is optional: with it the LQR's Riccati equation is solved by
``scipy.linalg.solve_discrete_are``, without it by fixed-point iteration.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from engine import math3d
from engine.humanoid import pose, standing_pose

from .batched import BatchedSim
from .tasks import BalanceTask
from .tasks.chain import ChainTask


def core_of(env) -> BatchedSim:
    """The batched core behind a single env (wrapped or not), a vector env,
    the SB3 adapter (or an SB3 VecEnvWrapper on it), or a core itself."""
    if isinstance(env, BatchedSim):
        return env
    for candidate in (env, getattr(env, "unwrapped", None), getattr(env, "venv", None)):
        core = getattr(candidate, "core", None)
        if isinstance(core, BatchedSim):
            return core
    venv = getattr(env, "venv", None)
    if venv is not None:
        return core_of(venv)
    raise TypeError(f"cannot find the ragdoll core of {env!r}")


class Controller:
    """Base: ``act(obs)`` -> action in [-1, 1]; (D,) -> (A,), (W, D) -> (W, A)."""

    def __init__(self, env):
        self.core = core_of(env)
        self.task = self.core.task
        self.num_actuators = self.core.num_actuators

    def act(self, obs) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float64)
        single = obs.ndim == 1
        a = self._act(np.atleast_2d(obs))
        a = np.clip(a, -1.0, 1.0).astype(np.float32)
        return a[0] if single else a

    __call__ = act

    def _act(self, obs):
        raise NotImplementedError


class ZeroTorque(Controller):
    """No torque at all."""

    def _act(self, obs):
        return np.zeros((obs.shape[0], self.num_actuators))


class PendulumPD(Controller):
    """a = -(kp θ + kd θ̇) per hinge, gains in action units (1/rad, s/rad).

    The defaults hold both pendulums upright from the reset noise; for the
    double pendulum the hip also corrects the trunk's absolute tilt.
    """

    def __init__(self, env, kp=None, kd=None):
        super().__init__(env)
        if not isinstance(self.task, ChainTask):
            raise TypeError("PendulumPD drives the pendulum tasks")
        k = len(self.task.links)
        self.kp = np.broadcast_to(np.asarray(kp if kp is not None else (8.0 if k == 1 else (12.0, 8.0)),
                                             dtype=float), (k,))
        self.kd = np.broadcast_to(np.asarray(kd if kd is not None else (1.5 if k == 1 else (2.0, 1.0)),
                                             dtype=float), (k,))

    def _act(self, obs):
        k = len(self.task.links)
        q, qd = obs[:, :k], obs[:, k:2 * k]
        if k == 2:  # the hip acts on the trunk's absolute tilt
            q = np.stack((q[:, 0], q[:, 0] + q[:, 1]), axis=-1)
            qd = np.stack((qd[:, 0], qd[:, 0] + qd[:, 1]), axis=-1)
        return -(self.kp * q + self.kd * qd)


def linearize(core: BatchedSim, eps: float = 1e-4):
    """(A, B) of x' = A x + B u for one env step of a chain task around
    upright at rest, x = [angles, rates], u = action, by central
    differences of the engine itself (2(n + m) worlds in one batched step)."""
    task = core.task
    if not isinstance(task, ChainTask):
        raise TypeError("linearize() needs a pendulum (chain) task")
    params = {name: getattr(task, name) for name in task.params}
    settings = {k: v for k, v in asdict(core.settings).items() if k != "check_finite"}
    k = len(task.links)
    n, m = 2 * k, core.num_actuators
    worlds = 2 * (n + m)
    sim = BatchedSim(type(task)(**params), worlds, frame_skip=core.frame_skip, reset_noise_scale=0.0,
                     push_strength=0.0, **settings)
    x0 = np.zeros((worlds, n))
    u0 = np.zeros((worlds, m))
    for i in range(n):
        x0[2 * i, i], x0[2 * i + 1, i] = eps, -eps
    for j in range(m):
        u0[2 * (n + j), j], u0[2 * (n + j) + 1, j] = eps, -eps
    sim.task.set_coordinates(sim.model, sim.state, np.arange(worlds), x0[:, :k], x0[:, k:])
    sim.step(u0)
    q, qd = sim.task.coordinates(sim.model, sim.state)
    x1 = np.concatenate((q, qd), axis=-1)
    diff = (x1[0::2] - x1[1::2]) / (2 * eps)
    return diff[:n].T.copy(), diff[n:].T.copy()


def solve_dare(A, B, Q, R, iterations=100_000, tol=1e-12):
    """P of the discrete algebraic Riccati equation (scipy if importable)."""
    try:
        from scipy.linalg import solve_discrete_are
    except ImportError:
        solve_discrete_are = None
    if solve_discrete_are is not None:
        return solve_discrete_are(A, B, Q, R)
    P = Q.copy()
    for _ in range(iterations):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P_next = Q + A.T @ P @ (A - B @ K)
        if np.max(np.abs(P_next - P)) <= tol * max(1.0, np.max(np.abs(P))):
            return P_next
        P = P_next
    raise RuntimeError("the Riccati iteration did not converge (is the system stabilisable?)")


class LQR(Controller):
    """u = -K x, the discrete LQR gain of the engine's linearisation.

    q: state weights (angles then rates); r: action weight. The action is
    clipped to [-1, 1], so far from upright it saturates like any torque-limited
    controller.
    """

    def __init__(self, env, q=None, r=1.0):
        super().__init__(env)
        if not isinstance(self.task, ChainTask):
            task = self.task.env_id or type(self.task).__name__
            fits = ("'standing_pd' (which 'pd' picks there) and 'zero'" if isinstance(self.task, BalanceTask)
                    else "'zero'")
            raise TypeError(f"the LQR baseline is for the pendulum tasks (Ragdoll/InvertedPendulum-v0, "
                            f"Ragdoll/InvertedDoublePendulum-v0), not {task}; the baselines for {task}: {fits}")
        self.A, self.B = linearize(self.core)
        n = self.A.shape[0]
        k = n // 2
        q = np.asarray(q if q is not None else [10.0] * k + [1.0] * k, dtype=float)
        self.Q = np.diag(np.broadcast_to(q, (n,)))
        self.R = np.eye(self.B.shape[1]) * float(r)
        P = solve_dare(self.A, self.B, self.Q, self.R)
        self.K = np.linalg.solve(self.R + self.B.T @ P @ self.B, self.B.T @ P @ self.A)

    def _act(self, obs):
        return -obs[:, :self.K.shape[1]] @ self.K.T


#: StandingPD gains per joint (canonical name without side): (kp, kd) for a
#: hinge, or per axis ((kp, kd) twist, swing_y, swing_z) for a ball joint, in
#: N·m/rad and N·m·s/rad. They act on top of StandingPD's gravity compensation,
#: which cancels the gravity stiffness (knee 185, ankle 334, hip 69, lower
#: spine 79 N·m/rad at the standing pose), so they only have to hold the pose
#: against disturbances. The light bones bound them: an explicit PD held over a
#: control step Δt oscillates and diverges at larger kd·Δt/I or kp·Δt²/I, and a
#: foot rocking on its edge has little inertia, so the ankles' own gains are
#: small: balance comes from the centre-of-mass term. The knees are stiff (the
#: limit at 0 stops them on the other side). The table is for Balance's 60 Hz
#: control: it is twice the table tuned for 30 Hz (frame_skip 2), which at
#: 3.3x (before the engine passed motor torques on through damped joints) let
#: every world fall even without pushes. Measured on the default pushes
#: (40 episodes of 20 s, 60 Hz, with the balance gains below): 1.5x, 2x and
#: 3x the 30 Hz table fell in 7, 6 and 9 (kc, dc = 1200, 300); 2.5x in 6
#: (1200, 400).
STANDING_GAINS = {
    "spine_lower": ((25.2, 0.64), (63.0, 1.06), (63.0, 1.06)),
    "spine_upper": ((21.0, 0.64), (42.0, 0.84), (42.0, 0.84)),
    "neck": ((1.68, 0.06), (6.3, 0.168), (6.3, 0.168)),
    "shoulder": ((3.0, 0.06), (18.0, 0.3), (18.0, 0.3)),
    "elbow": (3.36, 0.084),
    "wrist": ((0.3, 0.006), (1.2, 0.03), (1.2, 0.03)),
    "hip": ((36.0, 0.6), (84.0, 1.26), (84.0, 1.26)),
    "knee": (600.0, 6.0),
    "ankle": ((2.4, 0.06), (36.0, 0.6), (24.0, 0.6)),
}

_LEG_PARTS = ("thigh", "shin", "foot")


def support_torques(core: BatchedSim, positions, orientations):
    """(S, leg) of the humanoid at body poses ``positions`` (N, 3),
    ``orientations`` (N, 4): joint torques τ = S f (N·m, per actuated axis)
    that hold every body still against a uniform field f (m/s², same frame as
    the poses), and ``leg[k]`` the index of the foot under actuator k (-1 for
    the trunk, head and arms).

    Each joint above the pelvis carries its child's subtree: τ = -e·Σ m_b (x_b
    - a) × f, about its axis e (the parent joint frame's, as the motor pushes)
    and anchor a. A leg joint (double stance, feet on the ground) carries the
    bodies on the pelvis side: the bones above it in its own leg and half of
    the pelvis, trunk, head and arms, whose wrench passes to each leg at that
    leg's hip (the half load moved sideways by the hip's offset from the hip
    midpoint), τ = +e·Σ w_b m_b (x_b - a) × f.
    """
    model, task = core.model, core.task
    h, J = task.humanoid, model.joints
    side, rank = {}, {}
    for part in task.body:
        kind = part.split("_")[0]
        if kind in _LEG_PARTS:
            b = model.body_index(h.name(part))
            side[b], rank[b] = part[-1], _LEG_PARTS.index(kind)
    mass = np.where(model.dynamic, model.mass, 0.0)
    bodies = [model.body_index(h.name(part)) for part in task.body]
    children = {}
    for j in range(len(J.names)):
        children.setdefault(int(J.parent[j]), []).append(int(J.child[j]))

    def anchor(j):
        p = int(J.parent[j])
        return positions[p] + math3d.quat_rotate(orientations[p], J.anchor_p[j])

    hips = {side[int(J.child[j])]: anchor(j) for j in range(len(J.names))
            if rank.get(int(J.child[j])) == 0}
    mid = 0.5 * (hips["l"] + hips["r"])
    S = np.zeros((model.num_actuators, 3))
    leg = np.full(model.num_actuators, -1, dtype=np.int64)
    for k, act in enumerate(model.actuators):
        j = act.joint
        c, a = int(J.child[j]), anchor(j)
        e = math3d.quat_rotate(math3d.quat_mul(orientations[int(J.parent[j])], J.frame_p[j]), np.eye(3)[act.axis])
        moment = np.zeros((3, 3))  # Σ w_b m_b [x_b - a]×: the moment about a is moment @ f
        if c in side:
            for b in bodies:
                if b in side:
                    w, shift = float(side[b] == side[c] and rank[b] < rank[c]), 0.0
                else:
                    w, shift = 0.5, hips[side[c]] - mid
                moment += w * mass[b] * math3d.skew(positions[b] + shift - a)
            S[k] = e @ moment
            leg[k] = model.body_index(h.name("foot_" + side[c]))
        else:
            stack = [c]
            while stack:
                b = stack.pop()
                moment += mass[b] * math3d.skew(positions[b] - a)
                stack.extend(children.get(b, ()))
            S[k] = -(e @ moment)
    return S, leg


class StandingPD(Controller):
    """Balance: holds the standing pose (every angle 0) with a PD per actuated
    axis on top of gravity compensation and a centre-of-mass balance term, as
    an action τ / max_torque clipped to [-1, 1]::

        τ = -kp (q - q_ref) - kd q̇ + S φ + G q
        φ = R_pelvisᵀ (g + f),   f = (kc (c - c_ref) + dc ċ) / m   (horizontal)

    * q, q̇: ``joint_angles``, ``joint_velocities``; q_ref is 0 but for the
      knees, held at ``knee_lock`` (rad, < 0): beyond their limit at 0, so a
      straight knee is pressed onto the limit (kp·|knee_lock| N·m) instead of
      buckling.
    * S: :func:`support_torques` at the standing pose, the static torques
      holding every body against a uniform field; S g (g the model's
      gravity, turned into the pelvis frame with ``pelvis_orientation``) is the
      gravity load, G q its first-order change with the joint angles (central
      differences of ``support_torques`` along each axis; the leg rows with
      the foot kept flat on the ground).
    * f: balance field. Holding the bodies against f pushes the centre of
      mass with -m f, a horizontal spring-damper on ``com_from_feet`` c
      towards ``com_target`` c_ref (m) with ``com_gains`` (kc N/m, dc N·s/m),
      applied through every joint as a change of gravity would be (virtual
      model control: Pratt et al. 2001, Int. J. Robot. Res. 20(2):129). The
      ankle strategy and the whole-body inverted pendulum (m g h ≈ 670 N·m/rad
      about the ankles) come out of it: kc h² ≈ 1050 N·m/rad about the ankles.
      c_ref is 2 cm behind the foot centres (5 cm in front of the ankles):
      the standing pose puts the centre of mass 7 cm behind them, only 6 cm
      in front of the heel edges, and backward pushes tipped it over them.
    * An ankle's support terms act only while its foot touches the ground
      (``foot_contacts``): on a lifted foot they flipped it within 0.2 s.
    * A lifted foot's ankle PD (``lifted_ankle``, its kp and kd scaled by
      0.25 while ``foot_contacts`` reads 0) acts on the 1 kg foot alone,
      whose roll inertia about the ankle (about 0.004 kg·m²) puts the full
      gains past the explicit damper's limit (kd Δt / I ≈ 2.6 > 2 at 60 Hz):
      the roll torque flipped sign at every control step and the foot came
      down rolled onto its edge, a wide stance the PD then lost a second or
      two later (most of its falls after sideways chest pushes). Default
      pushes, 20 s episodes, falls with 1.0 / 0.25 (2026-12-05): 21 / 12 of
      320 (eight seed sets of 40, ``BalanceVectorEnv(num_envs=40).reset(seed=S)``,
      S = 0, 100, ..., 700) and 28 / 9 of 400 in ten other seed sets. In six
      of those (240 episodes) 0.1, 0.2, 0.25 and 0.5 fell in 22, 9, 9 and
      23: the foot flopping, or still ringing.
    * Tuned at 30 Hz control on push trials (16 worlds, pushes of 10, 15,
      20 N·s in 8 directions at the chest and the pelvis, worlds standing 4 s
      later): kc, dc = 800, 240 kept 16, 8 and 2 of 16; 400, 160 kept 13, 5
      and 2; 1200, 300 let 6 of 16 fall even without a push; c_ref 5 cm
      behind (with 400, 160) kept 5 of 16 at 10 N·s. Retuned for Balance's
      60 Hz control on the default pushes (40 episodes of 20 s per seed set,
      with the 60 Hz joint table): kc, dc = 1200, 400 fell in 4 of 40, 1600,
      400 in 5 and 2000, 400 in 7 (the 30 Hz controller unchanged: 9 of 20);
      c_ref 2 cm behind, 1 cm behind and at the foot centres fell in 6, 5
      and 6 of 120 (three seed sets), 4 cm behind in 14 of 40, 2 cm in front
      in 6 of 40.
    * Frontal plane: a foot cannot take more roll moment than half the body
      weight times its half width (18 N·m), so the ankle ``swing_z`` rows of S
      and G are moved to the hips' ``swing_z`` (for the legs swaying sideways
      as a parallelogram, ankle swing_z = -hip swing_z, so the work is the
      same): the hips shift the load between the feet instead.
    * Load sharing (``load_sharing``): S and G hold half of the trunk on each
      leg, but a sideways correction moves the load onto one foot. The roll
      moment asked of the ground (the two ankle ``swing_z`` support torques
      before the move), M, puts the centre of pressure p = M / (m g) beside
      the feet's midpoint; foot i, at y_i = ±d (d = 8.7 cm) across from it,
      must then carry the share w_i = 1/2 + p y_i / (2 d²), clipped to
      [0, 1], of the weight, and every support row of leg i (hip, knee,
      ankle; S and G terms) is scaled by 2 w_i: the loaded leg holds the
      whole trunk, the unloaded one is left alone. Without it, a sideways
      push (15 N·s at the chest) shifted 90-100 % of the load onto the foot
      on the side it went to within 2 steps, and the other leg's hip, still
      carrying its half of the moved rows, swung that unloaded foot in
      under the body (it slid 4-5 cm inwards) while the trunk rolled over
      the stance hip; the body fell 1-2 s after the push. Measured at 30 Hz
      with the push trials above (seed 3), without -> with: 15 N·s kept 8 -> 15 of
      16 (every lateral and diagonal push at the pelvis, and all but one at
      the chest), 20 N·s 2 -> 5 of 16; 10 N·s and no push stay 16 of 16;
      under the default pushes (16 episodes of 20 s, seed 0) 13 -> 4
      episodes end in a fall (mean time standing 12.8 -> 17.4 s). Not
      helping in the same trials: a world-frame roll PD on the pelvis (or
      the trunk) through the hips
      (kp 100-600 N·m/rad: 5-7 instead of 8 of 16 at 15 N·s; roll-rate
      damping of 15 N·m·s/rad made the light pelvis oscillate and every
      world fell without a push, 3-4 was harmless and useless), a
      capture-point ankle roll term on the stance foot, capping the hips'
      share of the moved rows (4-9 of 16), scaling the lateral field
      (0.5-2x), stiffer spine roll, keying the shares on ``foot_contacts``
      (a world fell before any push).

    gains: overrides of :data:`STANDING_GAINS` by joint name ("knee", ...);
    scale: multiplies every kp and kd (not the gravity and balance terms).
    gravity, balance: switch the S g + G q and the f terms off.
    load_sharing: False keeps every leg row at half the load (the controller
    before load sharing).
    lifted_ankle: the factor on a lifted foot's ankle kp and kd (1.0: the
    controller before 2026-12-05).
    """

    def __init__(self, env, gains=None, scale=1.0, com_gains=(1200.0, 400.0), com_target=(-0.02, 0.0),
                 knee_lock=-0.1, gravity=True, balance=True, load_sharing=True, lifted_ankle=0.25):
        super().__init__(env)
        if not isinstance(self.task, BalanceTask):
            raise TypeError("StandingPD drives Balance-v0")
        table = {**STANDING_GAINS, **(gains or {})}
        task, model = self.task, self.core.model
        h = task.humanoid
        prefix = h.prefix
        kp, kd, q_ref = [], [], []
        joint_of = []
        for act in model.actuators:
            joint = act.name.split(":")[0][len(prefix):]
            key = joint[:-2] if joint[-2:] in ("_l", "_r") else joint
            g = table[key]
            pair = g if np.ndim(g) == 1 else g[act.axis]
            kp.append(pair[0] * scale)
            kd.append(pair[1] * scale)
            q_ref.append(knee_lock if key == "knee" else 0.0)
            joint_of.append(joint)
        self.kp, self.kd, self.q_ref = np.array(kp), np.array(kd), np.array(q_ref)
        self.gravity, self.balance, self.load_sharing = bool(gravity), bool(balance), bool(load_sharing)
        self.lifted_ankle = float(lifted_ankle)
        self.kc, self.dc = (float(v) for v in com_gains)
        self.com_target = np.array([*com_target, 0.0], dtype=float)[:3]
        self.mass = float(np.where(model.dynamic, model.mass, 0.0)[task.humanoid_bodies].sum())
        self.g = np.zeros(3) if model.gravity is None else np.array(model.gravity, dtype=float)

        standing = standing_pose(h)
        pos, quat = pose(h, model, standing)
        self.S, leg = support_torques(self.core, pos, quat)
        self.leg_rows = leg >= 0
        # Ankle rows act through a foot on the ground: ankle_foot[k] is the foot_contacts slot of row k (-1: none).
        slot = {int(f): i for i, f in enumerate(task.feet)}
        self.ankle_foot = np.array([slot[int(leg[k])] if joint.startswith("ankle") else -1
                                    for k, joint in enumerate(joint_of)])
        self.pelvis_build = quat[task.pelvis]
        A, eps = model.num_actuators, 1e-5
        self.G = np.zeros((A, A))
        for k, act in enumerate(model.actuators):
            loads = []
            for d in (eps, -eps):
                angles = dict(standing)
                if h.joint_kinds[joint_of[k]] == "hinge":
                    angles[joint_of[k]] = d
                else:
                    angles[joint_of[k]] = tuple(d if i == act.axis else 0.0 for i in range(3))
                p, q = pose(h, model, angles)  # the pelvis at its build pose: the field is g
                S, _ = support_torques(self.core, p, q)
                tau = S @ self.g
                for r in np.flatnonzero(self.leg_rows):  # the foot kept flat: g turns with it
                    tau[r] = S[r] @ math3d.quat_rotate(q[leg[r]], math3d.quat_rotate_inv(quat[leg[r]], self.g))
                loads.append(tau)
            self.G[:, k] = (loads[0] - loads[1]) / (2 * eps)
        # Frontal-plane load sharing (see the class docstring). row_foot[k]: foot_contacts slot of the leg
        # of row k (-1: trunk, head, arms); ankle_roll[i]: the ankle swing_z row of foot slot i, whose
        # support rows S_roll, G_roll (kept before they move to the hips) give the roll moment the
        # feet are asked for; foot_side[i]: foot i's offset (m) from the feet's midpoint towards the
        # left of the pelvis at the standing pose.
        self.row_foot = np.array([slot[int(f)] if f >= 0 else -1 for f in leg])
        self.ankle_roll = np.array([k for i in range(len(task.feet)) for k, act in enumerate(model.actuators)
                                    if self.ankle_foot[k] == i and act.axis == 2])
        self.S_roll, self.G_roll = self.S[self.ankle_roll].copy(), self.G[self.ankle_roll].copy()
        left = math3d.quat_rotate(self.pelvis_build, np.array([0.0, 1.0, 0.0]))
        feet_pos = pos[task.feet]
        self.foot_side = (feet_pos - feet_pos.mean(axis=0)) @ left
        # A field towards the left asks the ankles for a moment that moves the centre of pressure left:
        # roll_sign turns the moment into "towards the left" whatever the joint frames' conventions.
        self.roll_sign = float(np.sign(self.S_roll.sum(axis=0) @ left))
        self.weight = self.mass * float(np.linalg.norm(self.g))
        names = list(self.core.actuator_names)
        for s in "lr":
            ankle, hip = names.index(f"{prefix}ankle_{s}:swing_z"), names.index(f"{prefix}hip_{s}:swing_z")
            for M in (self.S, self.G):
                M[hip] -= M[ankle]
                M[ankle] = 0.0
        layout = task.obs_layout
        self._q, self._qd = layout["joint_angles"], layout["joint_velocities"]
        self._rot, self._com, self._comv = layout["pelvis_orientation"], layout["com_from_feet"], layout["com_velocity"]
        self._feet = layout["foot_contacts"]

    def _act(self, obs):
        q, qd = obs[:, self._q], obs[:, self._qd]
        touching = np.concatenate([obs[:, self._feet], np.ones((obs.shape[0], 1))], axis=1)[:, self.ankle_foot]
        # A lifted foot's ankle PD acts on the foot alone (see the class docstring).
        tau = np.where(touching > 0, 1.0, self.lifted_ankle) * (-self.kp * (q - self.q_ref) - self.kd * qd)
        field = np.zeros((obs.shape[0], 3))
        if self.balance:
            e = obs[:, self._com] - self.com_target
            field[:, :2] = (self.kc * e[:, :2] + self.dc * obs[:, self._comv][:, :2]) / self.mass
        rot = obs[:, self._rot]
        build = np.broadcast_to(self.pelvis_build, rot.shape)
        if self.gravity:
            # trunk rows: gravity as the pelvis sees it; leg rows: the feet are flat
            trunk = math3d.quat_rotate(build, math3d.quat_rotate_inv(rot, field + self.g))
            legs = math3d.quat_rotate(build, math3d.quat_rotate_inv(rot, field)) + self.g
            support = np.where(self.leg_rows, legs @ self.S.T, trunk @ self.S.T) + q @ self.G.T
        else:
            legs = math3d.quat_rotate(build, math3d.quat_rotate_inv(rot, field))
            support = legs @ self.S.T
        if self.load_sharing:
            support = support * self._leg_loads(legs, q)
        # A foot off the ground carries nothing: its ankle's support torques would only flip it.
        return (tau + support * touching) / self.core.max_torque

    def _leg_loads(self, legs, q):
        """(W, A) factors on the support rows: 2 w_i on the rows of leg i, 1 elsewhere.

        The roll moment the field and gravity ask of the ground, M (N·m, the
        two ankle ``swing_z`` support torques, before they moved to the
        hips), puts the centre of pressure p = M / (m g) (m) towards the left
        of the feet's midpoint; foot i (at ±d from it) must carry the share
        w_i = 1/2 + p y_i / (2 d²), clipped to [0, 1], of the body weight.
        """
        moment = legs @ self.S_roll.T
        if self.gravity:
            moment = moment + q @ self.G_roll.T
        cop = self.roll_sign * moment.sum(axis=1) / self.weight
        d2 = self.foot_side ** 2
        share = np.clip(0.5 + cop[:, None] * self.foot_side / (2.0 * d2), 0.0, 1.0)  # (W, feet)
        factor = np.ones((legs.shape[0], self.num_actuators))
        legs_rows = self.row_foot >= 0
        factor[:, legs_rows] = 2.0 * share[:, self.row_foot[legs_rows]]
        return factor


BASELINES = {"zero": ZeroTorque, "pd": None, "lqr": LQR, "standing_pd": StandingPD, "pendulum_pd": PendulumPD}


def make_baseline(name: str, env, **kwargs) -> Controller:
    """``"zero"``, ``"lqr"``, ``"pd"`` (StandingPD for Balance, PendulumPD for
    the pendulums), ``"standing_pd"`` or ``"pendulum_pd"`` for ``env``."""
    if name not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; baselines: {sorted(BASELINES)}")
    if name == "pd":
        cls = StandingPD if isinstance(core_of(env).task, BalanceTask) else PendulumPD
    else:
        cls = BASELINES[name]
    return cls(env, **kwargs)
