"""Joints: ball (swing-twist limit), hinge (angle range) and fixed, solved as soft
constraints in the substepped solver, with motors, passive muscle tone and breaking.

Every joint holds two body-local anchor points together (a 3-row point
constraint solved as one 3x3 block, as Box2D v3's ``b2SolveRevoluteJoint``
solves its 2x2 block). Hinges also lock the two axes perpendicular to the hinge
(a 2x2 angular block), fixed joints lock all three rotations (3x3); limits are
one-sided rows with speculative bias while open (Box2D v3 joint limits).

Joint frames: each joint has a frame in the parent and in the child whose x
axis is the hinge or twist axis. The relative rotation q_rel =
conj(q_p ⊗ f_p) ⊗ (q_c ⊗ f_c) is split as q_rel = q_swing ⊗ q_twist with the
twist about x (swing-twist decomposition, as in Jolt's SwingTwistConstraint):
the hinge angle is the twist angle; a ball joint's swing is an elliptic cone
with half-angles (cone_y, cone_z) over the swing vector φ·(d_y, d_z).

Constraints are split into colours at build time (no dynamic body twice in a
colour); each colour is one vectorised sweep over worlds × joints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .coloring import color_pairs
from .math3d import (cross, dot, mat_vec, quat_conj, quat_mul, quat_rotate, sym3_solve,
                     world_inv_inertia)
from .soft import implicit_spring_impulse, make_soft
from .state import Event

HINGE, BALL, FIXED = 0, 1, 2
KINDS = {"hinge": HINGE, "ball": BALL, "fixed": FIXED}
_EX = np.array([1.0, 0.0, 0.0])
_EY = np.array([0.0, 1.0, 0.0])
_EZ = np.array([0.0, 0.0, 1.0])
AXIS_NAMES = {HINGE: ("",), BALL: (":twist", ":swing_y", ":swing_z")}


@dataclass(frozen=True)
class Actuator:
    """One actuated joint axis: torque ``u`` in [-max_torque, max_torque] N·m
    about the parent frame's axis (0: hinge/twist x, 1: swing y, 2: swing z)."""

    name: str
    joint: int
    axis: int
    max_torque: float


def swing_twist(q_rel):
    """Twist angle about x and swing vector (φ d_y, φ d_z) of relative rotations.

    q_rel = q_swing ⊗ q_twist, q_twist = (w, x, 0, 0)/‖·‖; the swing
    quaternion then has no x part: (s_w, 0, s_y, s_z). Returns twist (…,),
    swing angle φ (…,), swing direction (d_y, d_z) (…, 2) and the swing
    quaternion components.
    """
    w, x = q_rel[..., 0], q_rel[..., 1]
    tn = np.sqrt(w * w + x * x)
    degenerate = tn < 1e-9
    tn = np.where(degenerate, 1.0, tn)
    tw, tx = np.where(degenerate, 1.0, w / tn), np.where(degenerate, 0.0, x / tn)
    # q_swing = q_rel ⊗ conj(q_twist), conj(q_twist) = (tw, -tx, 0, 0)
    y, z = q_rel[..., 2], q_rel[..., 3]
    sw = w * tw + x * tx
    sy = y * tw - z * tx
    sz = z * tw + y * tx
    twist = 2.0 * np.arctan2(tx, tw)
    twist = np.where(twist > math.pi, twist - 2 * math.pi, np.where(twist < -math.pi, twist + 2 * math.pi, twist))
    # Keep the swing quaternion in the w >= 0 hemisphere (angle in [0, π]).
    sign = np.where(sw < 0, -1.0, 1.0)
    sw, sy, sz = sw * sign, sy * sign, sz * sign
    s = np.sqrt(sy * sy + sz * sz)
    phi = 2.0 * np.arctan2(s, sw)
    safe = np.where(s > 1e-12, s, 1.0)
    dy = np.where(s > 1e-12, sy / safe, 1.0)
    dz = np.where(s > 1e-12, sz / safe, 0.0)
    return twist, phi, dy, dz


class JointSet:
    """The compiled joints of a model and their solver."""

    def __init__(self, model, specs, settings):
        self.names = tuple(j.name for j in specs)
        J = len(specs)
        self.kind = np.array([KINDS[j.kind] for j in specs], dtype=np.int64)
        self.parent = np.array([j.parent for j in specs], dtype=np.int64)
        self.child = np.array([j.child for j in specs], dtype=np.int64)
        self.anchor_p = np.array([j.anchor_parent for j in specs], dtype=float).reshape(J, 3)
        self.anchor_c = np.array([j.anchor_child for j in specs], dtype=float).reshape(J, 3)
        self.frame_p = np.array([j.frame_parent for j in specs], dtype=float).reshape(J, 4)
        self.frame_c = np.array([j.frame_child for j in specs], dtype=float).reshape(J, 4)
        self.lower = np.full(J, -math.inf)
        self.upper = np.full(J, math.inf)
        self.cone = np.full((J, 2), math.pi)
        for i, j in enumerate(specs):
            lim = j.limits.get("angle", j.limits.get("twist"))
            if lim is not None:
                self.lower[i], self.upper[i] = lim
            if "swing" in j.limits:
                self.cone[i] = j.limits["swing"]
        self.max_torque = np.array([j.max_torque for j in specs], dtype=float).reshape(J, 3)
        self.damping = np.array([j.damping for j in specs], dtype=float)
        self.stiffness = np.array([j.stiffness for j in specs], dtype=float)
        self.rest = np.array([j.rest_angles for j in specs], dtype=float).reshape(J, 3)
        self.break_force = np.array([j.break_force for j in specs], dtype=float)
        self.break_torque = np.array([j.break_torque for j in specs], dtype=float)
        self.breakable = bool(np.isfinite(self.break_force).any() or np.isfinite(self.break_torque).any())
        self.has_passive = bool((self.damping > 0).any() or (self.stiffness > 0).any())
        self.has_constraints = J > 0
        has_limit = np.isfinite(self.lower) | np.isfinite(self.upper)
        has_swing = (self.kind == BALL) & (self.cone < math.pi).any(axis=1)

        actuators = []
        for i, j in enumerate(specs):
            n_axes = {HINGE: 1, BALL: 3, FIXED: 0}[self.kind[i]]
            for axis in range(n_axes):
                if self.max_torque[i, axis] > 0:
                    suffix = AXIS_NAMES[self.kind[i]][axis]
                    actuators.append(Actuator(j.name + suffix, i, axis, float(self.max_torque[i, axis])))
        self.actuators = tuple(actuators)
        self.act_joint = np.array([a.joint for a in actuators], dtype=np.int64)
        self.act_axis = np.array([a.axis for a in actuators], dtype=np.int64)
        self.act_max = np.array([a.max_torque for a in actuators], dtype=float)

        colors = color_pairs(self.parent, self.child, model.dynamic)
        self.colors = []
        for idx in colors:
            k = self.kind[idx]
            self.colors.append({
                "all": idx,
                "hinge": idx[k == HINGE],
                "fixed": idx[k == FIXED],
                "twist_limit": idx[has_limit[idx]],
                "swing_limit": idx[has_swing[idx]],
                "passive": idx[(self.damping[idx] > 0) | (self.stiffness[idx] > 0)],
            })
        self.effect_names = {"joints"}
        if has_limit.any() or has_swing.any():
            self.effect_names.add("joint_limits")
        if actuators:
            self.effect_names.add("motors")
        if self.breakable:
            self.effect_names.add("joint_breaking")
        self.settings = settings
        self._iinv = None

    # ------------------------------------------------------------------ state
    def initial_arrays(self, W):
        J = len(self.names)
        return {
            "joint_broken": np.zeros((W, J), dtype=bool),
            "joint_linear_impulse": np.zeros((W, J, 3)),
            "joint_angular_impulse": np.zeros((W, J, 3)),  # lock rows (hinge: 2, fixed: 3)
            "joint_limit_impulse": np.zeros((W, J, 3)),  # lower, upper, swing
        }

    # --------------------------------------------------------------- geometry
    def frames(self, state, idx):
        """World joint frames of parent and child, anchors and lever arms."""
        a, b = self.parent[idx], self.child[idx]
        qa, qb = state.orientation[:, a], state.orientation[:, b]
        fpw = quat_mul(qa, self.frame_p[idx])
        fcw = quat_mul(qb, self.frame_c[idx])
        ra = quat_rotate(qa, self.anchor_p[idx])
        rb = quat_rotate(qb, self.anchor_c[idx])
        return a, b, fpw, fcw, ra, rb

    def angles(self, state, idx=None):
        """Joint angles (W, J, 3) in radians: hinge (θ, 0, 0); ball (twist,
        swing_y, swing_z) with the swing vector φ·d; fixed zeros."""
        idx = np.arange(len(self.names)) if idx is None else idx
        _, _, fpw, fcw, _, _ = self.frames(state, idx)
        twist, phi, dy, dz = swing_twist(quat_mul(quat_conj(fpw), fcw))
        ball = (self.kind[idx] == BALL)
        return np.stack((np.where(self.kind[idx] == FIXED, 0.0, twist),
                         np.where(ball, phi * dy, 0.0), np.where(ball, phi * dz, 0.0)), axis=-1)

    def relative_angular_velocity(self, state, idx=None):
        """Child minus parent angular velocity in the parent joint frame (W, J, 3), rad/s."""
        idx = np.arange(len(self.names)) if idx is None else idx
        a, b, fpw, _, _, _ = self.frames(state, idx)
        from .math3d import quat_rotate_inv

        return quat_rotate_inv(fpw, state.angular_velocity[:, b] - state.angular_velocity[:, a])

    def anchor_error(self, state):
        """Distance between the two anchors of each joint (W, J), m (0 for broken)."""
        idx = np.arange(len(self.names))
        a, b, _, _, ra, rb = self.frames(state, idx)
        d = state.position[:, b] + rb - state.position[:, a] - ra
        return np.where(state.joint_broken, 0.0, np.sqrt(dot(d, d)))

    def limit_violation(self, state):
        """How far each joint is outside its limits (W, J), rad (0 inside)."""
        idx = np.arange(len(self.names))
        _, _, fpw, fcw, _, _ = self.frames(state, idx)
        twist, phi, dy, dz = swing_twist(quat_mul(quat_conj(fpw), fcw))
        v = np.maximum(np.maximum(self.lower - twist, twist - self.upper), 0.0)
        phi_max = 1.0 / np.sqrt((dy / self.cone[:, 0]) ** 2 + (dz / self.cone[:, 1]) ** 2)
        v = np.maximum(v, np.where(self.kind == BALL, np.maximum(phi - phi_max, 0.0), 0.0))
        if (self.kind == FIXED).any():
            q = quat_mul(fcw, quat_conj(fpw))
            ang = 2.0 * np.arctan2(np.sqrt(dot(q[..., 1:], q[..., 1:])), np.abs(q[..., 0]))
            v = np.where(self.kind == FIXED, ang, v)
        return np.where(state.joint_broken, 0.0, v)

    # ----------------------------------------------------------------- forces
    def motor_torques(self, model, view, u, acc):
        """Motor torques clamped to each axis's maximum, +τ on the child and -τ
        on the parent, about the parent joint frame's axis."""
        if not self.actuators:
            return
        j = self.act_joint
        tau = np.clip(u, -self.act_max, self.act_max)
        qa = view.orientation[:, self.parent[j]]
        fpw = quat_mul(qa, self.frame_p[j])
        basis = np.stack((_EX, _EY, _EZ))[self.act_axis]
        axis = quat_rotate(fpw, basis)
        t = axis * tau[..., None]
        if self.breakable:
            t = t * (~view.joint_broken[:, j])[..., None]
        np.add.at(acc.torque, (slice(None), self.child[j]), t)
        np.add.at(acc.torque, (slice(None), self.parent[j]), -t)

    def passive_torques(self, model, view, acc):
        """Passive stiffness and damping are implicit (see ``passive``)."""
        return None

    def passive(self, model, state, h):
        """Muscle tone: an implicit spring-damper on each joint axis towards the
        rest angles, k (N·m/rad) and c (N·m·s/rad), stable for any stiffness."""
        for color in self.colors:
            idx = color["passive"]
            if idx.size == 0:
                continue
            a, b, fpw, fcw, _, _ = self.frames(state, idx)
            ang = self.angles(state, idx)
            ia, ib = self._iinv[:, a], self._iinv[:, b]
            wa, wb = state.angular_velocity[:, a], state.angular_velocity[:, b]
            n_axes = 1 if (self.kind[idx] == HINGE).all() else 3
            active = self._active(state, idx)
            for k, e in enumerate((_EX, _EY, _EZ)[:n_axes]):
                axis = quat_rotate(fpw, np.broadcast_to(e, fpw.shape[:-1] + (3,)))
                use = active * ((self.kind[idx] == BALL) | (k == 0)) * (self.kind[idx] != FIXED)
                inv_m = dot(axis, mat_vec(ia, axis)) + dot(axis, mat_vec(ib, axis))
                p = implicit_spring_impulse(self.stiffness[idx], self.damping[idx], h,
                                            ang[..., k] - self.rest[idx, k], dot(wb - wa, axis), inv_m)
                p = (p * use)[..., None] * axis
                wa = wa - mat_vec(ia, p)
                wb = wb + mat_vec(ib, p)
            state.angular_velocity[:, a] = wa
            state.angular_velocity[:, b] = wb

    # ----------------------------------------------------------------- solver
    def begin_step(self, model, state, h):
        """World inverse inertias for the step (Box2D prepares once per step)."""
        self._iinv = world_inv_inertia(state.orientation, model.inv_inertia)
        s = self.settings
        self._soft = make_soft(s.joint_hertz, s.joint_damping_ratio, h)
        self._limit_soft = make_soft(s.limit_hertz, s.joint_damping_ratio, h)
        self._substeps_done = 0
        if self.breakable:
            # Impulses summed over the step's substeps: the load a joint carries.
            self._lin_sum = np.zeros(state.joint_linear_impulse.shape)
            self._ang_sum = np.zeros(state.joint_linear_impulse.shape[:2])
        if s.solver == "thesis":
            self._soft = make_soft(0.0, 0.0, h)  # rigid rows, position error by projection
            self._limit_soft = self._soft

    def _active(self, state, idx):
        return (~state.joint_broken[:, idx]).astype(float)

    def _add_load(self, state):
        self._lin_sum += state.joint_linear_impulse
        L = state.joint_angular_impulse
        self._ang_sum += np.sqrt(dot(L, L)) + np.abs(state.joint_limit_impulse).sum(axis=-1)

    def warm_start(self, model, state):
        if self.breakable and self._substeps_done:
            self._add_load(state)  # λ at the end of the previous substep
        self._substeps_done += 1
        for color in self.colors:
            idx = color["all"]
            a, b, fpw, fcw, ra, rb = self.frames(state, idx)
            P = state.joint_linear_impulse[:, idx]
            L = state.joint_angular_impulse[:, idx].copy()
            hinge = self.kind[idx] == HINGE
            # Hinge lock impulses are stored in the parent frame's (y, z) axes.
            if hinge.any():
                by = quat_rotate(fpw, np.broadcast_to(_EY, ra.shape))
                bz = quat_rotate(fpw, np.broadcast_to(_EZ, ra.shape))
                lh = L[..., 1:2] * by + L[..., 2:3] * bz
                L = np.where(hinge[:, None], lh, L)
            L = L + self._limit_vector(state, idx, fpw, fcw)
            self._apply(model, state, a, b, ra, rb, P, L)

    def _limit_vector(self, state, idx, fpw, fcw):
        lam = state.joint_limit_impulse[:, idx]
        if not lam.any():
            return 0.0
        ax_p = quat_rotate(fpw, np.broadcast_to(_EX, fpw.shape[:-1] + (3,)))
        ax_c = quat_rotate(fcw, np.broadcast_to(_EX, fpw.shape[:-1] + (3,)))
        twist_axis = self._twist_axis(ax_p, ax_c, self.kind[idx])
        _, _, dy, dz = swing_twist(quat_mul(quat_conj(fpw), fcw))
        swing_axis = quat_rotate(fpw, np.stack((np.zeros(dy.shape), dy, dz), axis=-1))
        return (lam[..., 0:1] - lam[..., 1:2]) * twist_axis - lam[..., 2:3] * swing_axis

    @staticmethod
    def _twist_axis(ax_p, ax_c, kind):
        mid = ax_p + ax_c
        mid = mid / np.maximum(np.sqrt(dot(mid, mid)), 1e-12)[..., None]
        return np.where((kind == BALL)[:, None], mid, ax_p)

    def _apply(self, model, state, a, b, ra, rb, P, L):
        """Apply linear impulse P at the anchors and angular impulse L (to the
        child; the parent gets the opposite)."""
        inv_m = model.inv_mass
        state.velocity[:, a] -= P * inv_m[a][:, None]
        state.velocity[:, b] += P * inv_m[b][:, None]
        state.angular_velocity[:, a] -= mat_vec(self._iinv[:, a], cross(ra, P) + L)
        state.angular_velocity[:, b] += mat_vec(self._iinv[:, b], cross(rb, P) + L)

    def solve(self, model, state, h, use_bias):
        soft = self._soft
        rigid_bias = self.settings.solver == "thesis"
        for color in self.colors:
            if color["twist_limit"].size:
                self._solve_twist_limits(model, state, color["twist_limit"], h, use_bias, self._limit_soft)
            if color["swing_limit"].size:
                self._solve_swing_limits(model, state, color["swing_limit"], h, use_bias, self._limit_soft)
            if color["hinge"].size:
                self._solve_hinge_lock(model, state, color["hinge"], h, use_bias and not rigid_bias, soft)
            if color["fixed"].size:
                self._solve_fixed_lock(model, state, color["fixed"], h, use_bias and not rigid_bias, soft)
            self._solve_point(model, state, color["all"], h, use_bias and not rigid_bias, soft)

    def _soft_terms(self, use_bias, soft):
        if use_bias:
            return soft.bias_rate, soft.mass_scale, soft.impulse_scale
        return 0.0, 1.0, 0.0

    def _solve_point(self, model, state, idx, h, use_bias, soft):
        a, b, _, _, ra, rb = self.frames(state, idx)
        xa, xb = state.position[:, a], state.position[:, b]
        va, vb = state.velocity[:, a], state.velocity[:, b]
        wa, wb = state.angular_velocity[:, a], state.angular_velocity[:, b]
        cdot = vb + cross(wb, rb) - va - cross(wa, ra)
        bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, soft)
        rhs = cdot
        if bias_rate:
            sep = xb + rb - xa - ra
            rhs = cdot + bias_rate * sep
        K = _point_mass_matrix(model.inv_mass[a] + model.inv_mass[b], ra, rb, self._iinv[:, a], self._iinv[:, b])
        lam = state.joint_linear_impulse[:, idx]
        P = -mass_scale * sym3_solve(K, rhs) - impulse_scale * lam
        P = P * self._active(state, idx)[..., None]
        state.joint_linear_impulse[:, idx] = lam + P
        self._apply(model, state, a, b, ra, rb, P, 0.0)

    def _solve_hinge_lock(self, model, state, idx, h, use_bias, soft):
        a, b, fpw, fcw, ra, rb = self.frames(state, idx)
        shape = ra.shape
        by = quat_rotate(fpw, np.broadcast_to(_EY, shape))
        bz = quat_rotate(fpw, np.broadcast_to(_EZ, shape))
        ia, ib = self._iinv[:, a], self._iinv[:, b]
        isum = ia + ib
        wrel = state.angular_velocity[:, b] - state.angular_velocity[:, a]
        c1, c2 = dot(wrel, by), dot(wrel, bz)
        bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, soft)
        if bias_rate:
            ax_p = quat_rotate(fpw, np.broadcast_to(_EX, shape))
            ax_c = quat_rotate(fcw, np.broadcast_to(_EX, shape))
            err = cross(ax_p, ax_c)
            c1 = c1 + bias_rate * dot(err, by)
            c2 = c2 + bias_rate * dot(err, bz)
        isy, isz = mat_vec(isum, by), mat_vec(isum, bz)
        k11, k12, k22 = dot(by, isy), dot(by, isz), dot(bz, isz)
        det = k11 * k22 - k12 * k12
        inv_det = 1.0 / np.where(det > 1e-30, det, 1e-30)
        x1 = (k22 * c1 - k12 * c2) * inv_det
        x2 = (k11 * c2 - k12 * c1) * inv_det
        lam = state.joint_angular_impulse[:, idx]
        act = self._active(state, idx)
        d1 = (-mass_scale * x1 - impulse_scale * lam[..., 1]) * act
        d2 = (-mass_scale * x2 - impulse_scale * lam[..., 2]) * act
        state.joint_angular_impulse[:, idx, 1] = lam[..., 1] + d1
        state.joint_angular_impulse[:, idx, 2] = lam[..., 2] + d2
        L = d1[..., None] * by + d2[..., None] * bz
        state.angular_velocity[:, a] -= mat_vec(ia, L)
        state.angular_velocity[:, b] += mat_vec(ib, L)

    def _solve_fixed_lock(self, model, state, idx, h, use_bias, soft):
        a, b, fpw, fcw, _, _ = self.frames(state, idx)
        ia, ib = self._iinv[:, a], self._iinv[:, b]
        rhs = state.angular_velocity[:, b] - state.angular_velocity[:, a]
        bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, soft)
        if bias_rate:
            # Rotation vector of q_c q_p⁻¹ (small-angle: 2·vec·sign(w)).
            qd = quat_mul(fcw, quat_conj(fpw))
            err = 2.0 * qd[..., 1:] * np.where(qd[..., 0:1] < 0, -1.0, 1.0)
            rhs = rhs + bias_rate * err
        lam = state.joint_angular_impulse[:, idx]
        L = -mass_scale * sym3_solve(ia + ib, rhs) - impulse_scale * lam
        L = L * self._active(state, idx)[..., None]
        state.joint_angular_impulse[:, idx] = lam + L
        state.angular_velocity[:, a] -= mat_vec(ia, L)
        state.angular_velocity[:, b] += mat_vec(ib, L)

    def _one_sided(self, state, a, b, axis, C, slot, idx, h, use_bias, soft):
        """One-sided angular row about ``axis`` keeping C >= 0 (Box2D v3 limits):
        speculative bias C/h while open, soft bias when violated."""
        ia, ib = self._iinv[:, a], self._iinv[:, b]
        k = dot(axis, mat_vec(ia, axis)) + dot(axis, mat_vec(ib, axis))
        m = 1.0 / np.maximum(k, 1e-30)
        cdot = dot(state.angular_velocity[:, b] - state.angular_velocity[:, a], axis)
        bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, soft)
        open_ = C > 0.0
        bias = np.where(open_, C / h, bias_rate * C)
        ms = np.where(open_, 1.0, mass_scale)
        isc = np.where(open_, 0.0, impulse_scale)
        lam = state.joint_limit_impulse[:, idx, slot]
        d = -m * ms * (cdot + bias) - isc * lam
        new = np.maximum(lam + d, 0.0) * self._active(state, idx)
        d = new - lam
        state.joint_limit_impulse[:, idx, slot] = new
        L = d[..., None] * axis
        state.angular_velocity[:, a] -= mat_vec(ia, L)
        state.angular_velocity[:, b] += mat_vec(ib, L)

    def _solve_twist_limits(self, model, state, idx, h, use_bias, soft):
        a, b, fpw, fcw, _, _ = self.frames(state, idx)
        shape = fpw.shape[:-1] + (3,)
        ax_p = quat_rotate(fpw, np.broadcast_to(_EX, shape))
        ax_c = quat_rotate(fcw, np.broadcast_to(_EX, shape))
        axis = self._twist_axis(ax_p, ax_c, self.kind[idx])
        twist, _, _, _ = swing_twist(quat_mul(quat_conj(fpw), fcw))
        lo, hi = self.lower[idx], self.upper[idx]
        has_lo, has_hi = np.isfinite(lo), np.isfinite(hi)
        C_lo = np.where(has_lo, twist - np.where(has_lo, lo, 0.0), np.inf)
        self._one_sided(state, a, b, axis, np.where(has_lo, C_lo, 1e9), 0, idx, h, use_bias, soft)
        C_hi = np.where(has_hi, np.where(has_hi, hi, 0.0) - twist, 1e9)
        self._one_sided(state, a, b, -axis, C_hi, 1, idx, h, use_bias, soft)

    def _solve_swing_limits(self, model, state, idx, h, use_bias, soft):
        a, b, fpw, fcw, _, _ = self.frames(state, idx)
        _, phi, dy, dz = swing_twist(quat_mul(quat_conj(fpw), fcw))
        cone = self.cone[idx]
        phi_max = 1.0 / np.sqrt((dy / cone[:, 0]) ** 2 + (dz / cone[:, 1]) ** 2)
        axis = quat_rotate(fpw, np.stack((np.zeros(dy.shape), dy, dz), axis=-1))
        self._one_sided(state, a, b, -axis, phi_max - phi, 2, idx, h, use_bias, soft)

    def end_step(self, model, state, h, events):
        if self.settings.solver == "thesis":
            self._project_positions(model, state)
        if not self.breakable:
            return
        self._add_load(state)
        dt = model.settings.dt
        force = np.sqrt(dot(self._lin_sum, self._lin_sum)) / dt
        torque = self._ang_sum / dt
        snapped = ((force > self.break_force) | (torque > self.break_torque)) & ~state.joint_broken
        if snapped.any():
            state.joint_broken |= snapped
            for arr in ("joint_linear_impulse", "joint_angular_impulse", "joint_limit_impulse"):
                state.arrays[arr][snapped] = 0.0
            for w, j in zip(*np.nonzero(snapped)):
                step = int(state.step[w]) + 1
                events.append(Event("joint_broken", self.names[j], int(w), step, step * model.settings.dt))

    def _project_positions(self, model, state):
        """The thesis's position correction: move the two anchors together,
        split by inverse mass (the lighter body moves more)."""
        for color in self.colors:
            idx = color["all"]
            a, b, _, _, ra, rb = self.frames(state, idx)
            sep = state.position[:, b] + rb - state.position[:, a] - ra
            ma, mb = model.inv_mass[a], model.inv_mass[b]
            total = np.maximum(ma + mb, 1e-30)
            act = self._active(state, idx)[..., None]
            state.position[:, a] += sep * (ma / total)[:, None] * act
            state.position[:, b] -= sep * (mb / total)[:, None] * act


def _point_mass_matrix(inv_m_sum, ra, rb, ia, ib):
    """K = (1/m_a + 1/m_b) I + [r_a]×ᵀ I_a⁻¹ [r_a]× + [r_b]×ᵀ I_b⁻¹ [r_b]× (3x3 per joint)."""
    K = np.zeros(ra.shape + (3,))
    for r, inv_i in ((ra, ia), (rb, ib)):
        # Column k of [r]×ᵀ I⁻¹ [r]× is -r × (I⁻¹ (r × e_k)) = (I⁻¹ (r × e_k)) × r.
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            K[..., :, k] += cross(mat_vec(inv_i, cross(r, np.broadcast_to(e, r.shape))), r)
    for k in range(3):
        K[..., k, k] += inv_m_sum
    return K


def compile_joints(model, builder):
    """A JointSet for the builder's joints, or None when there are none."""
    if not builder.joints:
        return None
    return JointSet(model, builder.joints, builder.settings)
