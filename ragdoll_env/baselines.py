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
* :class:`StandingPD` — Balance: a PD per actuated axis holding the standing
  pose (every joint angle 0), gains per joint in N·m/rad and N·m·s/rad.
  Known limit: it does not yet keep the humanoid up (it falls within ~2 s,
  zero torque within ~1 s): torque PD at the env rate cannot be stiff on the
  light trunk bones (see :data:`STANDING_GAINS`).

scipy is optional: with it the LQR's Riccati equation is solved by
``scipy.linalg.solve_discrete_are``, without it by fixed-point iteration.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

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
#: N·m/rad and N·m·s/rad. The ankles carry the body as an inverted pendulum
#: (Σ kp > m g h ≈ 700 N·m/rad); every other axis is limited by the light
#: bones it drives: the pelvis, abdomen and chest turn with only 0.04-0.1 kg·m²
#: relative to their neighbours (measured from the engine's response to unit
#: torques), so an explicit PD held over a 1/30 s step oscillates and diverges
#: at larger kd·Δt/I or kp·Δt²/I. These values stood longest of those tried;
#: see the module notes: the humanoid still falls within about 2 s.
STANDING_GAINS = {
    "spine_lower": ((42.0, 1.05), (105.0, 1.75), (105.0, 1.75)),
    "spine_upper": ((35.0, 1.05), (70.0, 1.4), (70.0, 1.4)),
    "neck": ((2.8, 0.1), (10.5, 0.28), (10.5, 0.28)),
    "shoulder": ((1.4, 0.035), (14.0, 0.35), (14.0, 0.35)),
    "elbow": (5.6, 0.14),
    "wrist": ((0.5, 0.01), (2.0, 0.05), (2.0, 0.05)),
    "hip": ((14.0, 0.35), (140.0, 2.1), (140.0, 2.1)),
    "knee": (105.0, 2.1),
    "ankle": ((7.0, 0.21), (420.0, 28.0), (280.0, 17.5)),
}


class StandingPD(Controller):
    """Balance: τ = kp (0 - q) - kd q̇ on every actuated axis, as an action
    τ / max_torque clipped to [-1, 1] (the standing pose is every angle 0).

    gains: overrides of :data:`STANDING_GAINS` by joint name ("knee", ...);
    scale: multiplies every kp and kd.
    """

    def __init__(self, env, gains=None, scale=1.0):
        super().__init__(env)
        if not isinstance(self.task, BalanceTask):
            raise TypeError("StandingPD drives Balance-v0")
        table = {**STANDING_GAINS, **(gains or {})}
        prefix = self.task.humanoid.prefix
        kp, kd = [], []
        for act in self.core.model.actuators:
            joint = act.name.split(":")[0][len(prefix):]
            key = joint[:-2] if joint[-2:] in ("_l", "_r") else joint
            g = table[key]
            pair = g if np.ndim(g) == 1 else g[act.axis]
            kp.append(pair[0] * scale)
            kd.append(pair[1] * scale)
        self.kp = np.array(kp)
        self.kd = np.array(kd)
        layout = self.task.obs_layout
        self._q, self._qd = layout["joint_angles"], layout["joint_velocities"]

    def _act(self, obs):
        tau = -self.kp * obs[:, self._q] - self.kd * obs[:, self._qd]
        return tau / self.core.max_torque


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
