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

Loop-closing joints are solved with the tree, exactly, through the Schur
complement of their rows (``_TreeSolver.solve_with_loops``; ``joint_loops``).

Softness: the tree solve (``_TreeSolver``) is exact, but Gauss-Seidel rows
solved after it (contacts, limits outside the tree) see one body's mass and
fight rigid joints, so the tree joints of an articulation that such rows act
on are soft (``joint_hertz``), as are those of an articulation with loops
(rigid, they held their joints less well); those of an articulation
nothing else acts on, a pendulum or a chain in the air, are rigid with
geometric stiffness (``free_joint_hertz``, ``free_joint_geometric_stiffness``),
chosen per world and step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .coloring import color_pairs
from .math3d import (sym3_inverse, clamp_norm, cross, quat_rotate_inv, dot, mat_vec, quat_conj, quat_mul, quat_rotate, sym3_solve,
                     quat_to_matrix, world_inv_inertia)
from .joint_projection import project_joints
from .soft import Softness, implicit_spring_impulse, make_soft
from .state import Event

HINGE, BALL, FIXED = 0, 1, 2
KINDS = {"hinge": HINGE, "ball": BALL, "fixed": FIXED}
_EX = np.array([1.0, 0.0, 0.0])
_EY = np.array([0.0, 1.0, 0.0])
_EZ = np.array([0.0, 0.0, 1.0])
JOINT_HERTZ_CAP = 0.5  # joint stiffness at most this x the substep rate
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

        self.has_limit = has_limit = np.isfinite(self.lower) | np.isfinite(self.upper)
        self.has_swing = has_swing = (self.kind == BALL) & (self.cone < math.pi).any(axis=1)
        self.tree = None
        in_tree = np.zeros(J, dtype=bool)
        lim_in_tree = np.zeros(J, dtype=bool)
        if settings.joint_solver == "tree" and settings.solver == "soft_step" and J:
            self.tree = _TreeSolver(self, model, settings)
            in_tree[self.tree.joints] = True
            if not in_tree.any():
                self.tree = None
            elif settings.joint_limits_in_tree and math.isinf(settings.limit_hertz):
                lim_in_tree = in_tree
                self.tree.limits = bool((has_limit | has_swing)[self.tree.joints].any())
        # Loop-closing joints solved with the tree (``_TreeSolver.solve_with_loops``),
        # unless their rows stay Gauss-Seidel; not with limits in the tree, nor
        # with rigid tree joints: they gained energy (the 10x10 sphere grid at
        # ACCURATE: 103 J in 10 s with rigid loop rows, 11 J with their
        # regularisation at 1e-3; chain_loop with soft ones: 62 J).
        self.loop_rows = None
        in_loop_solve = np.zeros(J, dtype=bool)
        if (self.tree is not None and settings.joint_loops == "exact" and not self.tree.limits
                and math.isfinite(settings.joint_hertz)):
            moving = model.dynamic[self.parent] | model.dynamic[self.child]
            loops = np.flatnonzero(~in_tree & moving)
            if loops.size:
                self.loop_rows = _Rows(loops, self.kind[loops], self.parent[loops], self.child[loops])
                in_loop_solve[loops] = True
        colors = color_pairs(self.parent, self.child, model.dynamic)
        self.colors = []
        for idx in colors:
            k = self.kind[idx]
            gs = ~in_tree[idx] & ~in_loop_solve[idx]
            self.colors.append({
                "all": idx,
                "point": idx[gs],
                "hinge": idx[(k == HINGE) & gs],
                "fixed": idx[(k == FIXED) & gs],
                "twist_limit": idx[has_limit[idx] & ~lim_in_tree[idx]],
                "swing_limit": idx[has_swing[idx] & ~lim_in_tree[idx]],
                "passive": idx[(self.damping[idx] > 0) | (self.stiffness[idx] > 0)],
            })
        # Gauss-Seidel limit rows: their geometry is computed once per solve
        # for all of them (positions do not move within a solve), listed
        # colour by colour and within a colour twist-only, twist-and-swing,
        # swing-only joints, so that a colour's twist rows and its swing rows
        # are each one slice of that list (views, no gathers in the sweep).
        # A colour's joints share no body, so their order within it is free.
        gs_limit = []
        for color in self.colors:
            t, w = color["twist_limit"], color["swing_limit"]
            both = np.intersect1d(t, w)
            order = (np.setdiff1d(t, both), both, np.setdiff1d(w, both))
            color["gs_slice"] = slice(sum(map(len, gs_limit)), sum(map(len, gs_limit)) + sum(map(len, order)))
            color["twist_slice"] = slice(color["gs_slice"].start, color["gs_slice"].start + len(order[0]) + len(both))
            color["swing_slice"] = slice(color["gs_slice"].start + len(order[0]), color["gs_slice"].stop)
            color["twist_limit"], color["swing_limit"] = np.concatenate(order[:2]), np.concatenate(order[1:])
            gs_limit.append(np.concatenate(order))
        self.gs_limit = np.concatenate(gs_limit).astype(np.int64) if gs_limit else np.zeros(0, dtype=np.int64)
        if self.tree is not None:
            # Articulations that Gauss-Seidel joint rows act on (loop-closing
            # joints, limits outside the tree): their tree joints stay soft.
            t = self.tree
            # Loop-closing joints count whether solved exactly or not: rigid
            # loops solved with the tree held their joints less well (a 20 kg
            # ball on a slack chain pinned at both ends, benchmarks.stability
            # chain_loop: 3.0 mm against 1.1 mm soft over 10 s).
            gs_rows = ~in_tree | ((has_limit | has_swing) & ~lim_in_tree)
            t.gs_touched = np.zeros(t.num_components + 1, dtype=bool)
            t.gs_touched[t.body_component[self.parent[gs_rows]]] = True
            t.gs_touched[t.body_component[self.child[gs_rows]]] = True
            t.gs_touched[-1] = False
            # Articulations with Gauss-Seidel loop-closing joints: not
            # position-projected (engine.joint_projection).
            gs_loop = ~in_tree & ~in_loop_solve
            t.loop_touched = np.zeros(t.num_components + 1, dtype=bool)
            t.loop_touched[t.body_component[self.parent[gs_loop]]] = True
            t.loop_touched[t.body_component[self.child[gs_loop]]] = True
            t.loop_touched[-1] = False
        self.passive_joints = np.flatnonzero((self.damping > 0) | (self.stiffness > 0))
        where_passive = {int(j): i for i, j in enumerate(self.passive_joints)}
        for color in self.colors:
            color["passive_pos"] = np.array([where_passive[int(j)] for j in color["passive"]], dtype=np.int64)
            # Axes a passive joint's spring acts on (hinge: x; ball: x, y, z; fixed: none), 1.0/0.0.
            kp = self.kind[color["passive"]]
            n_axes = 1 if (kp == HINGE).all() else 3
            color["passive_use"] = [(((kp == BALL) | (k == 0)) & (kp != FIXED)).astype(float) for k in range(n_axes)]
        self.effect_names = {"joints"}
        if has_limit.any() or has_swing.any():
            self.effect_names.add("joint_limits")
        if actuators:
            self.effect_names.add("motors")
        if self.breakable:
            self.effect_names.add("joint_breaking")
        self.settings = settings
        self._load_before = None  # within a step: |λ| (W, J) before the substep's biased solve (geometric stiffness)
        self._iinv = None
        self._all = np.arange(J)
        # warm_start: the joints colour by colour, and the order of their parent
        # (first J) and child (last J) terms in its scatter: per colour, parents then children.
        self._warm_joints = np.concatenate([c["all"] for c in self.colors]).astype(np.int64) if J else self._all
        self._warm_hinge = self.kind[self._warm_joints] == HINGE
        sizes = np.cumsum([0] + [len(c["all"]) for c in self.colors])
        n = len(self._warm_joints)
        self._warm_order = np.concatenate([np.r_[lo:hi, n + lo:n + hi] for lo, hi in zip(sizes[:-1], sizes[1:])]
                                          ).astype(np.int64) if n else np.zeros(0, dtype=np.int64)
        self._warm_bodies = np.concatenate((self.parent[self._warm_joints], self.child[self._warm_joints]))[self._warm_order]
        self._frames_on = False  # frames of _frames_state cached between begin_step and end_step
        self._frames = self._frames_state = None
        self._limits = self._swing_twist = None  # of every joint, cached with the frames
        self._gs_rows = None  # _gs_limit_rows, cached with the frames

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
        """World joint frames of parent and child, anchors and lever arms.

        Within a step the frames of every joint are computed once per set of
        positions (``positions_moved`` drops them) and sliced here."""
        if self._frames_on and state is self._frames_state:
            if self._frames is None:
                self._frames = self._compute_frames(state, self._all)[2:]
            fpw, fcw, ra, rb = self._frames
            return self.parent[idx], self.child[idx], fpw[:, idx], fcw[:, idx], ra[:, idx], rb[:, idx]
        return self._compute_frames(state, idx)

    def positions_moved(self, model=None, state=None):
        """The bodies moved: frames cached within the step are stale. Given
        the model and state (within a step, after the substep's positions),
        the world inverse inertias and the tree's metric follow the new
        orientations too: the relax solve applying impulses through the
        inertias of the substep's start pumped the spin of thin links (a
        1 kg, 20 cm capsule, 7x lighter about its axis: a ball joint's
        impulse at its end, through the inertia of a link tilted 0.01 rad
        before, has a component along the new axis, 7x amplified; 250 rad/s
        in 4 s and +40 J in 5 s for a ball on a chain pinned at both ends,
        benchmarks.stability chain_loop with rigid joints).

        The geometric stiffness of this metric (used by the relax and by the
        next substep's biased solve) takes each joint's load as the smaller
        of |λ| before and after the biased solve: the load the joint carries
        through the substep, not the biased solve's position correction
        (an impulse of m C/h when a joint has opened by C, which is no load).
        With |λ| after the biased solve, the 100:1 ball and chain
        (benchmarks.stability, 10 s) opened its joints by 9.9-40 mm
        depending on where in space it hung (ten offsets: the spikes of the
        correction, stiffening the relax's metric, amplified rounding), with
        the smaller one by 3.0 mm at every offset; with |λ| before it alone
        a chain of thin links gained 20 J in 30 s (the relax projects the
        velocities in the stiffened metric, which can raise the kinetic
        energy; tests/engine/test_joints.py thin_chain_axial_spin: 0.35 J at
        most over 30 s with the smaller, 0.50 J with the after value)."""
        self._frames = None
        self._drop_position_caches()
        if state is not None:
            self._set_inertia(model, state)
            if self.tree is not None and self.settings.solver != "thesis":
                self.tree.begin_step(self, model, state, self._h)

    def _drop_position_caches(self):
        """Forget what was computed from the last set of positions and
        inertias (limit geometry, swing-twist, limit rows, the tree's
        factors): at the start and end of a step and when the bodies move."""
        self._limits = self._swing_twist = self._gs_rows = None
        if self.tree is not None:
            self.tree._factored = None

    def limit_geometry(self, state, idx):
        """``_limit_rows`` of joints ``idx``; within a step computed once for
        every joint per set of positions (with the frames) and sliced here."""
        if self._frames_on and state is self._frames_state:
            if self._limits is None:
                _, _, fpw, fcw, _, _ = self.frames(state, self._all)
                self._limits = self._limit_rows(self._all, fpw, fcw, self.relative_swing_twist(state, self._all))
            return tuple(x[:, idx] for x in self._limits)
        _, _, fpw, fcw, _, _ = self.frames(state, idx)
        return self._limit_rows(idx, fpw, fcw)

    def relative_swing_twist(self, state, idx):
        """``swing_twist`` of each joint's relative rotation, cached like the frames."""
        if self._frames_on and state is self._frames_state:
            if self._swing_twist is None:
                _, _, fpw, fcw, _, _ = self.frames(state, self._all)
                self._swing_twist = swing_twist(quat_mul(quat_conj(fpw), fcw))
            return tuple(x[:, idx] for x in self._swing_twist)
        _, _, fpw, fcw, _, _ = self.frames(state, idx)
        return swing_twist(quat_mul(quat_conj(fpw), fcw))

    def _compute_frames(self, state, idx):
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
        twist, phi, dy, dz = self.relative_swing_twist(state, idx)
        ball = (self.kind[idx] == BALL)
        return np.stack((np.where(self.kind[idx] == FIXED, 0.0, twist),
                         np.where(ball, phi * dy, 0.0), np.where(ball, phi * dz, 0.0)), axis=-1)

    def relative_angular_velocity(self, state, idx=None):
        """Child minus parent angular velocity in the parent joint frame (W, J, 3), rad/s."""
        idx = np.arange(len(self.names)) if idx is None else idx
        a, b, fpw, _, _, _ = self.frames(state, idx)
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

    def passive(self, model, state, h):
        """Muscle tone: an implicit spring-damper on each joint axis towards the
        rest angles, k (N·m/rad) and c (N·m·s/rad), stable for any stiffness.
        The geometry (axes, angles, inverse masses) is computed once for every
        passive joint; the colours then sweep the velocities."""
        idx_all = self.passive_joints
        if not idx_all.size:
            return
        a_all, b_all, fpw, _, _, _ = self.frames(state, idx_all)
        ang = self.angles(state, idx_all)
        ia_all, ib_all = self._iinv[:, a_all], self._iinv[:, b_all]
        axes, inv_ms = [], []
        for e in (_EX, _EY, _EZ):
            axis = quat_rotate(fpw, np.broadcast_to(e, fpw.shape[:-1] + (3,)))
            axes.append(axis)
            inv_ms.append(dot(axis, mat_vec(ia_all, axis)) + dot(axis, mat_vec(ib_all, axis)))
        err = ang - self.rest[idx_all]
        for color in self.colors:
            idx, pos = color["passive"], color["passive_pos"]
            if idx.size == 0:
                continue
            a, b = self.parent[idx], self.child[idx]
            ia, ib = ia_all[:, pos], ib_all[:, pos]
            wa, wb = state.angular_velocity[:, a], state.angular_velocity[:, b]
            active = self._active(state, idx)
            k_, c_ = self.stiffness[idx], self.damping[idx]
            for k, axis_use in enumerate(color["passive_use"]):
                axis = axes[k][:, pos]
                p = implicit_spring_impulse(k_, c_, h, err[:, pos, k], dot(wb - wa, axis), inv_ms[k][:, pos])
                p = (p * (active * axis_use))[..., None] * axis
                wa = wa - mat_vec(ia, p)
                wb = wb + mat_vec(ib, p)
            state.angular_velocity[:, a] = wa
            state.angular_velocity[:, b] = wb

    # ----------------------------------------------------------------- solver
    def begin_step(self, model, state, h, touching=None):
        """World inverse inertias for the step (Box2D prepares once per step)
        and each tree joint's softness; ``touching`` (W, num_bodies) bool marks
        the bodies with contact rows this step (None: no contacts)."""
        self._frames_on, self._frames, self._frames_state = True, None, state
        self._drop_position_caches()
        self._set_inertia(model, state)
        s = self.settings
        # Tree joints are stiffer than Gauss-Seidel rows: the tree solve is
        # exact, while loop-closing rows fight it and gained energy when stiff
        # (benchmarks.stability sphere_grid at 240 Hz: +127 J). Both are capped
        # at half the substep rate (hω <= π), like contact_hertz.
        cap = JOINT_HERTZ_CAP / h
        tree_hz = s.joint_hertz if math.isinf(s.joint_hertz) else min(s.joint_hertz, cap)
        gs_hz = s.gs_joint_hertz if math.isinf(s.gs_joint_hertz) else min(s.gs_joint_hertz, cap)
        free_hz = s.free_joint_hertz if math.isinf(s.free_joint_hertz) else min(s.free_joint_hertz, cap)
        self._soft = make_soft(gs_hz, s.gs_joint_damping_ratio, h)
        self._limit_soft = make_soft(s.limit_hertz, s.gs_joint_damping_ratio, h)
        self._substeps_done = 0
        self._load_before = None
        if s.solver == "thesis":
            self._soft = make_soft(0.0, 0.0, h)  # rigid rows, position error by projection
            self._limit_soft = self._tree_soft = self._soft
        elif self.tree is not None:
            self._choose_tree_softness(make_soft(tree_hz, s.joint_damping_ratio, h),
                                       make_soft(free_hz, s.joint_damping_ratio, h), touching)
            self.tree.begin_step(self, model, state, h)
        self._h = h
        if self.breakable:
            # Impulses summed over the step's substeps: the load a joint carries.
            self._lin_sum = np.zeros(state.joint_linear_impulse.shape)
            self._ang_sum = np.zeros(state.joint_linear_impulse.shape[:2])

    def _choose_tree_softness(self, soft, rigid, touching):
        """Each tree joint's softness for the step: an articulation that a
        Gauss-Seidel row acts on (a contact this step, a loop-closing joint,
        a limit outside the tree) takes ``joint_hertz`` (``soft``), the others
        ``free_joint_hertz`` (``rigid``) and, with
        ``free_joint_geometric_stiffness``, geometric stiffness.

        The tree solve is exact, but Gauss-Seidel rows after it see one body's
        mass: against rigid joints a resting ragdoll chatters (a contact stops
        a 1 kg foot, the tree hands the impulse to 70 kg, the joint error comes
        back at C/h: 5-9 cm/s 3-6 s after landing) and a 10x10 grid of ball
        joints opened 7.5 cm instead of 3.8 cm; the softness lets the two
        agree. Where nothing else acts, softness only costs accuracy: a soft
        pendulum's period is 0.34% long and it loses 9% of its energy in 60 s
        (rigid, with geometric stiffness: 0.03% and under 1%)."""
        t = self.tree
        s = self.settings
        hit = np.tile(t.gs_touched, (1 if touching is None else touching.shape[0], 1))  # (W or 1, articulations + 1)
        if touching is not None:
            w, body = np.nonzero(touching)
            hit[w, t.body_component[body]] = True
        on = hit[:, t.component]  # (W or 1, tree joints): soft
        if self.loop_rows is not None:
            # Exact loop rows take the softness of their articulation's tree
            # joints (joint_hertz), so the coupled solve is one system, scaled
            # alike (with rigid tree joints, soft loop rows gained 38 J in 10 s
            # in chain_loop where rigid ones gained none).
            self._loop_soft = soft
            t.loop_geometric_weight = 1.0 if s.joint_geometric_stiffness else None
        geo_free = s.free_joint_geometric_stiffness
        if soft == rigid and s.joint_geometric_stiffness == geo_free:
            on = np.ones_like(on)
        if on.all():
            self._tree_soft = soft
            t.geometric_weight = 1.0 if s.joint_geometric_stiffness else None
        elif not on.any():
            self._tree_soft = rigid
            t.geometric_weight = 1.0 if geo_free else None
        else:
            o = on[..., None]
            self._tree_soft = Softness(np.where(o, soft.bias_rate, rigid.bias_rate),
                                       np.where(o, soft.mass_scale, rigid.mass_scale),
                                       np.where(o, soft.impulse_scale, rigid.impulse_scale))
            weight = np.where(on, float(s.joint_geometric_stiffness), float(geo_free))
            t.geometric_weight = weight if weight.any() else None

    def _set_inertia(self, model, state):
        """World inverse inertias (and the rotation matrices, which the tree
        solver's inertias reuse) at the state's orientations."""
        self._rot = quat_to_matrix(state.orientation)
        self._iinv = world_inv_inertia(None, model.inv_inertia, self._rot)

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
        if self.tree is not None and self.tree.geometric_weight is not None:
            lam = state.joint_linear_impulse
            self._load_before = np.sqrt(dot(lam, lam))  # the load before this substep's solve
        # The stored impulses move velocities only (no row reads them), so every
        # joint's are applied in one scatter, each body's terms in colour order,
        # parent's before child's within a colour: the sums of a sweep colour by
        # colour, in one call.
        idx = self._warm_joints
        a, b, fpw, fcw, ra, rb = self.frames(state, idx)
        P = state.joint_linear_impulse[:, idx]
        L = state.joint_angular_impulse[:, idx]
        hinge = self._warm_hinge
        # Hinge lock impulses are stored in the parent frame's (y, z) axes.
        if hinge.any():
            by = quat_rotate(fpw, np.broadcast_to(_EY, ra.shape))
            bz = quat_rotate(fpw, np.broadcast_to(_EZ, ra.shape))
            lh = L[..., 1:2] * by + L[..., 2:3] * bz
            L = np.where(hinge[:, None], lh, L)
        L = L + self._limit_vector(state, idx)
        inv_m = model.inv_mass
        ang_a = mat_vec(self._iinv[:, a], cross(ra, P) + L)
        ang_b = mat_vec(self._iinv[:, b], cross(rb, P) + L)
        order, bodies = self._warm_order, self._warm_bodies
        np.add.at(state.velocity, (slice(None), bodies),
                  np.concatenate((-(P * inv_m[a][:, None]), P * inv_m[b][:, None]), axis=1)[:, order])
        np.add.at(state.angular_velocity, (slice(None), bodies), np.concatenate((-ang_a, ang_b), axis=1)[:, order])

    def _limit_vector(self, state, idx):
        lam = state.joint_limit_impulse[:, idx]
        if not lam.any():
            return 0.0
        Jt, _, Js, _ = self.limit_geometry(state, idx)
        return (lam[..., 0:1] - lam[..., 1:2]) * Jt + lam[..., 2:3] * Js

    def _limit_rows(self, idx, fpw, fcw, st=None):
        """Angular Jacobians (world vectors, Ċ = J·(ω_c - ω_p)) and errors of the
        twist and swing limits.

        Twist: with a, c the parent's and child's x axes and φ the swing angle,
        θ̇ = ω·(a + c)/(1 + cos φ) = ω·mid / cos(φ/2) exactly (the swing part of
        ω has no component along a + c). Swing: C = φ_max(1 - f(s)) with
        f(s) = ‖(s_y/c_y, s_z/c_z)‖ for the swing vector s = φ d, so the cone's
        boundary is f = 1 and C ≈ φ_max - φ near it; with n = (0, d), m = a × n
        (parent frame), ṡ = (ω·n) d + (φ/sin φ)(ω·m) d⊥ + φ θ̇ d⊥.
        ``st``: the joints' ``swing_twist`` if already known.
        Returns (J_twist, twist, J_swing, C_swing).
        """
        shape = fpw.shape[:-1] + (3,)
        ax_p = quat_rotate(fpw, np.broadcast_to(_EX, shape))
        ax_c = quat_rotate(fcw, np.broadcast_to(_EX, shape))
        twist, phi, dy, dz = swing_twist(quat_mul(quat_conj(fpw), fcw)) if st is None else st
        ball = (self.kind[idx] == BALL)[:, None]
        mid = ax_p + ax_c
        mid = mid / np.maximum(dot(mid, mid), 1e-24)[..., None] * 2.0  # (a + c)/(1 + cos φ)
        Jt = np.where(ball, mid, ax_p)
        cone = self.cone[idx]
        cy, cz = cone[:, 0], cone[:, 1]
        gy, gz = dy / (cy * cy), dz / (cz * cz)
        f_dir = np.sqrt(gy * dy + gz * dz)  # f(d) = 1/φ_max
        phi_max = 1.0 / f_dir
        gy, gz = gy * phi_max, gz * phi_max  # ∇f at s (degree-0 homogeneous)
        g_n = gy * dy + gz * dz
        g_m = -gy * dz + gz * dy
        zero = np.zeros(dy.shape)
        n = quat_rotate(fpw, np.stack((zero, dy, dz), axis=-1))
        m = quat_rotate(fpw, np.stack((zero, -dz, dy), axis=-1))
        sin_phi = np.sin(phi)
        ratio = np.where(sin_phi > 1e-6, phi / np.where(sin_phi > 1e-6, sin_phi, 1.0), 1.0)
        Js = -phi_max[..., None] * (g_n[..., None] * n + (g_m * ratio)[..., None] * m
                                    + (g_m * phi)[..., None] * mid)
        C_swing = phi_max * (1.0 - phi * f_dir)
        return Jt, twist, Js, C_swing

    def _apply(self, model, state, a, b, ra, rb, P, L):
        """Apply linear impulse P at the anchors and angular impulse L (to the
        child; the parent gets the opposite)."""
        inv_m = model.inv_mass
        state.velocity[:, a] -= P * inv_m[a][:, None]
        state.velocity[:, b] += P * inv_m[b][:, None]
        state.angular_velocity[:, a] -= mat_vec(self._iinv[:, a], cross(ra, P) + L)
        state.angular_velocity[:, b] += mat_vec(self._iinv[:, b], cross(rb, P) + L)

    def solve(self, model, state, h, use_bias):
        # The equality rows (tree and Gauss-Seidel) run in the biased solve, and
        # in the relax only with joint_relax; the limit rows run after them in
        # every solve, so a limb driven into its limit ends each solve on it.
        if use_bias or self.settings.joint_relax:
            self._solve_equality(model, state, h, use_bias)
        if not self.gs_limit.size:
            return
        rows = self._gs_limit_rows(state)
        soft = self._limit_soft
        lo = self._one_sided_terms(rows["C_lo"], rows["m_twist"], h, use_bias, soft)
        hi = self._one_sided_terms(rows["C_hi"], rows["m_twist"], h, use_bias, soft)
        sw = self._one_sided_terms(rows["C_swing"], rows["m_swing"], h, use_bias, soft)
        act = self._active(state, self.gs_limit)
        for color in self.colors:
            whole = color["gs_slice"]
            if whole.start == whole.stop:
                continue
            # A colour's joints share no body: their bodies' angular velocities,
            # impulses and inverse inertias are gathered once for its twist and
            # swing rows (each a slice of this range) and written back once.
            idx = self.gs_limit[whole]
            a, b = self.parent[idx], self.child[idx]
            wa, wb = state.angular_velocity[:, a], state.angular_velocity[:, b]
            ia, ib = self._iinv[:, a], self._iinv[:, b]
            lam = state.joint_limit_impulse[:, idx]
            for slot, pos, axis, terms, sign in ((0, color["twist_slice"], rows["Jt"], lo, 1.0),
                                                 (1, color["twist_slice"], rows["Jt"], hi, -1.0),
                                                 (2, color["swing_slice"], rows["Js"], sw, 1.0)):
                if pos.start == pos.stop:
                    continue
                k = slice(pos.start - whole.start, pos.stop - whole.start)
                ax = axis[:, pos] if sign > 0 else -axis[:, pos]
                self._one_sided(wa[:, k], wb[:, k], ia[:, k], ib[:, k], ax, [x[:, pos] for x in terms],
                                act[:, pos], lam[:, k, slot])
            state.angular_velocity[:, a] = wa
            state.angular_velocity[:, b] = wb
            state.joint_limit_impulse[:, idx] = lam

    def _gs_limit_rows(self, state):
        """Axes, errors (C >= 0 allowed) and effective masses of every
        Gauss-Seidel limit row, at the solve's positions (within a step
        computed once per set of positions)."""
        if self._frames_on and state is self._frames_state:
            if self._gs_rows is None:
                self._gs_rows = self._compute_gs_limit_rows(state)
            return self._gs_rows
        return self._compute_gs_limit_rows(state)

    def _compute_gs_limit_rows(self, state):
        idx = self.gs_limit
        a, b = self.parent[idx], self.child[idx]
        Jt, twist, Js, C_swing = self.limit_geometry(state, idx)
        lo, hi = self.lower[idx], self.upper[idx]
        has_lo, has_hi = np.isfinite(lo), np.isfinite(hi)
        ia, ib = self._iinv[:, a], self._iinv[:, b]

        def effective_mass(axis):
            k = dot(axis, mat_vec(ia, axis)) + dot(axis, mat_vec(ib, axis))
            return 1.0 / np.maximum(k, 1e-30)

        return {"Jt": Jt, "Js": Js, "C_swing": C_swing,
                "C_lo": np.where(has_lo, twist - np.where(has_lo, lo, 0.0), 1e9),
                "C_hi": np.where(has_hi, np.where(has_hi, hi, 0.0) - twist, 1e9),
                "m_twist": effective_mass(Jt), "m_swing": effective_mass(Js)}

    def _solve_equality(self, model, state, h, use_bias):
        soft = self._soft
        bias = use_bias and self.settings.solver != "thesis"
        for color in self.colors:
            if color["hinge"].size:
                self._solve_hinge_lock(model, state, color["hinge"], h, bias, soft)
            if color["fixed"].size:
                self._solve_fixed_lock(model, state, color["fixed"], h, bias, soft)
            if color["point"].size:
                self._solve_point(model, state, color["point"], h, bias, soft)
        if self.tree is not None and self.loop_rows is not None:
            self.tree.solve_with_loops(self, model, state, self._soft_terms(use_bias, self._tree_soft),
                                       self._soft_terms(use_bias, self._loop_soft), use_bias)
        elif self.tree is not None:
            bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, self._tree_soft)
            self.tree.solve(self, model, state, bias_rate, mass_scale, impulse_scale, use_bias, h)

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
            rhs = cdot + clamp_norm(bias_rate * sep, self.settings.joint_max_push_out)
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
            err = clamp_norm(bias_rate * cross(ax_p, ax_c), self.settings.joint_max_angular_push_out)
            c1 = c1 + dot(err, by)
            c2 = c2 + dot(err, bz)
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
            rhs = rhs + clamp_norm(bias_rate * err, self.settings.joint_max_angular_push_out)
        lam = state.joint_angular_impulse[:, idx]
        L = -mass_scale * sym3_solve(ia + ib, rhs) - impulse_scale * lam
        L = L * self._active(state, idx)[..., None]
        state.joint_angular_impulse[:, idx] = lam + L
        state.angular_velocity[:, a] -= mat_vec(ia, L)
        state.angular_velocity[:, b] += mat_vec(ib, L)

    def _one_sided_terms(self, C, m, h, use_bias, soft):
        """Gain, bias and impulse scale of one-sided rows with error C (C >= 0
        allowed) and effective mass m (Box2D v3 limits): speculative bias C/h,
        rigid, while open; soft bias when violated."""
        bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, soft)
        open_ = C > 0.0
        bias = np.where(open_, C / h, np.maximum(bias_rate * C, -self.settings.joint_max_angular_push_out))
        gain = -m * np.where(open_, 1.0, mass_scale)
        return gain, bias, np.where(open_, 0.0, impulse_scale)

    def _one_sided(self, wa, wb, ia, ib, axis, terms, act, lam):
        """One-sided angular rows about ``axis`` on the angular velocities
        ``wa``, ``wb`` of their bodies (updated in place, like the accumulated
        impulses ``lam``): Δλ = gain (Ċ + bias) - isc λ with λ >= 0 (``terms``
        = gain, bias, isc of ``_one_sided_terms``; ``ia``, ``ib``: the bodies'
        world inverse inertias)."""
        gain, bias, isc = terms
        cdot = dot(wb - wa, axis)
        d = gain * (cdot + bias) - isc * lam
        new = np.maximum(lam + d, 0.0) * act
        d = new - lam
        lam[...] = new
        L = d[..., None] * axis
        wa -= mat_vec(ia, L)
        wb += mat_vec(ib, L)

    def end_step(self, model, state, h, events):
        self._frames_on, self._frames, self._frames_state = False, None, None
        self._drop_position_caches()
        if self.settings.solver == "thesis":
            self._project_positions(model, state)
        elif self.tree is not None and self.settings.joint_projection_passes:
            project_joints(self, model, state)
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


# --------------------------------------------------------------------------------------
# Direct tree solve of the joint equality rows (Baraff 1996, "Linear-time dynamics
# using Lagrange multipliers").
#
# The bodies and joints of an articulation form a tree of nodes (body - joint -
# body ...). The system  [M  Jᵀ; J  0] [y; z] = [0; r]  has that tree's sparsity,
# so its block LDLᵀ factorisation in leaves-first order has no fill-in and gives
# x = -z = (J M⁻¹ Jᵀ)⁻¹ r exactly in time linear in the number of bodies. Each
# joint node has 6 rows: 3 point rows and 3 angular lock rows (hinge: y, z of the
# parent frame; fixed: world x, y, z; ball: none); unused rows get -1 on the
# diagonal and no coupling, so they solve to 0. Nodes of one (depth, kind) are one
# vectorised group. The 6x6 products and inverses are np.matmul (BLAS) and
# np.linalg.inv (LAPACK) per matrix: one call per group instead of one per inner
# index (measured 1.2-1.3x the whole ragdoll step at W = 1..1024), and still one
# library call per 6x6 matrix, so the result of a world never depends on the
# number of worlds.


# Entries of -[r]× = [[0, r_z, -r_y], [-r_z, 0, r_x], [r_y, -r_x, 0]] in the
# top-right block of a 6x6 joint Jacobian: (row, column, component of r, sign).
_SKEW_ROW = np.array([0, 0, 1, 1, 2, 2])
_SKEW_COL = np.array([4, 5, 3, 5, 3, 4])
_SKEW_COMP = np.array([2, 1, 2, 0, 1, 0])
_SKEW_SIGN = np.array([1.0, -1.0, -1.0, 1.0, 1.0, -1.0])
_DIAG3 = np.arange(3)
LOOP_SOLVE_BYTES = 256 * 2 ** 20  # most temporaries of one chunk of worlds in the loop solve
LOOP_REGULARISATION = 1e-6  # of the largest diagonal entry, added to the loop rows' Schur complement
ACTIVE_SET_TOLERANCE = 1e-6  # rad/s: a limit row closing faster than this after a solve joins the active set


def _mm(A, B):
    """A B for (..., n, k), (..., k, m)."""
    return np.matmul(A, B)


def _mtm(A, B):
    """Aᵀ B for (..., k, n), (..., k, m)."""
    return np.matmul(np.swapaxes(A, -1, -2), B)


def _inv_definite(A):
    """Inverse of definite (..., n, n) matrices."""
    return np.linalg.inv(A)


def _unique_splits(targets):
    """Split positions 0..len-1 into lists whose targets are unique, so that
    ``out[:, t[sel]] += v[:, sel]`` needs no np.add.at (fixed, sequential order)."""
    splits, seen = [], []
    for i, t in enumerate(np.asarray(targets).tolist()):
        for k, used in enumerate(seen):
            if t not in used:
                used.add(t)
                splits[k].append(i)
                break
        else:
            seen.append({t})
            splits.append([i])
    return [(np.array(sel), np.asarray(targets)[sel]) for sel in splits]


def _scatter_add(out, splits, v):
    for sel, tgt in splits:
        out[:, tgt] += v[:, sel]


class _JointTree:
    """Static layout of the joint tree: nodes, their parents and depth groups."""

    def __init__(self, parent, child, dynamic):
        J = len(parent)
        adj = {}
        self.joints = []  # joints solved by the tree
        # Union-find over dynamic bodies; a joint closing a loop is left out of the tree.
        root_of = {}

        def find(x):
            while root_of.get(x, x) != x:
                x = root_of[x]
            return x

        anchored = set()  # components attached to a static body
        for j in range(J):
            a, b = int(parent[j]), int(child[j])
            da, db = bool(dynamic[a]), bool(dynamic[b])
            if not (da or db):
                continue
            if da and db:
                ra, rb = find(a), find(b)
                if ra == rb:
                    continue
                if ra in anchored and rb in anchored:
                    continue  # would join two anchored trees: a loop through the world
                root_of[rb] = ra
                if rb in anchored:
                    anchored.discard(rb)
                    anchored.add(ra)
            else:
                r = find(a if da else b)
                if r in anchored:
                    continue
                anchored.add(r)
            self.joints.append(j)
            for x in (a, b):
                if dynamic[x]:
                    adj.setdefault(x, []).append(j)
        self.joints = np.array(self.joints, dtype=np.int64)
        # Articulation of each tree joint and body (-1 for bodies outside the tree).
        labels = {}
        self.component = np.array([labels.setdefault(find(int(child[j]) if dynamic[child[j]] else int(parent[j])), len(labels))
                                   for j in self.joints], dtype=np.int64)
        self.num_components = len(labels)
        self.body_component = np.full(len(dynamic), -1, dtype=np.int64)
        for x in adj:
            self.body_component[x] = labels[find(x)]
        bodies = sorted(adj)
        self.bodies = np.array(bodies, dtype=np.int64)
        nb = len(bodies)
        body_node = {b: i for i, b in enumerate(bodies)}
        joint_node = {int(j): nb + k for k, j in enumerate(self.joints)}
        n = nb + len(self.joints)
        node_parent = np.full(n, -1, dtype=np.int64)
        depth = np.full(n, -1, dtype=np.int64)
        # For joint nodes: whether the joint's parent body (side a) is the tree parent.
        self.a_is_parent = np.zeros(len(self.joints), dtype=bool)
        jset = set(int(j) for j in self.joints)
        # Roots: the static-anchored joint of a component, else its lowest body.
        visited = set()
        order = []
        roots = [joint_node[int(j)] for j in self.joints
                 if not (dynamic[parent[j]] and dynamic[child[j]])]
        for b in bodies:
            roots.append(body_node[b])
        for r in roots:
            if depth[r] >= 0:
                continue
            if r < nb and find(bodies[r]) in anchored:
                continue  # anchored component: rooted at its static joint
            depth[r] = 0
            stack = [r]
            while stack:
                u = stack.pop()
                order.append(u)
                if u < nb:
                    nbrs = [joint_node[j] for j in adj[bodies[u]]]
                else:
                    j = int(self.joints[u - nb])
                    nbrs = [body_node[int(x)] for x in (parent[j], child[j]) if dynamic[x]]
                for v in nbrs:
                    if depth[v] < 0:
                        depth[v] = depth[u] + 1
                        node_parent[v] = u
                        stack.append(v)
        assert (depth >= 0).all()
        for k, j in enumerate(self.joints):
            p = node_parent[nb + k]
            self.a_is_parent[k] = p >= 0 and bodies[p] == parent[j]
        self.n_nodes, self.n_bodies = n, nb
        self.node_parent = node_parent
        groups = []
        for d in range(int(depth.max()) + 1 if n else 0):
            for is_body in (True, False):
                ids = np.flatnonzero((depth == d) & ((np.arange(n) < nb) == is_body))
                if ids.size:
                    groups.append((ids, node_parent[ids], _unique_splits(node_parent[ids])))
        self.groups = groups[::-1]  # deepest first
        self.body_pos = body_node


class _Group:
    """One (depth, kind) group of tree nodes: body nodes (ids < nb) with their
    parent joints pj, or joint nodes jids with their parent body nodes par.

    Pivots with a closed form are picked out once: ``simple`` (positions in
    the group) are the leaf bodies (no child joint: the pivot is the body's
    own metric) of a body group, the ball joints (no lock rows: one 3x3 block)
    of a joint group; ``full`` are the others."""

    def __init__(self, ids, par, splits, nb, simple):
        self.ids, self.par, self.splits = ids, par, splits
        self.body = bool(ids[0] < nb)
        self.has_parent = bool(par[0] >= 0)
        self.pj = par - nb  # body groups: parent joint of each body
        self.jids = ids - nb  # joint groups: tree joint index
        self.simple = np.flatnonzero(simple)
        self.full = np.flatnonzero(~simple)
        # Node indices of each part: tree bodies (body groups) or tree joints.
        nodes = self.ids if self.body else self.jids
        self.simple_nodes, self.full_nodes = nodes[self.simple], nodes[self.full]

    def pivots(self, use_simple, simple, full):
        """D⁻¹ (W, n, 6, 6) of the group: ``simple(nodes)`` for its
        closed-form pivots when ``use_simple``, ``full(nodes)`` for the rest."""
        if not use_simple or not self.simple.size:
            return full(self.ids if self.body else self.jids)
        if not self.full.size:
            return simple(self.simple_nodes)
        part = simple(self.simple_nodes)
        Di = np.empty((part.shape[0], self.ids.size, 6, 6))
        Di[:, self.simple] = part
        Di[:, self.full] = full(self.full_nodes)
        return Di


class _Rows:
    """The equality rows of a list of joints, 6 per joint: 3 point rows and 3
    angular lock rows (hinge: y, z of the parent frame; fixed: world x, y, z;
    ball: none), the unused ones masked."""

    def __init__(self, joints, kind, parent, child):
        self.joints, self.kind = joints, kind
        # Positions split so that each part's bodies are unique (scatter without np.add.at).
        self.split_a = _unique_splits(parent)
        self.split_b = _unique_splits(child)
        # Angular lock rows used per kind (rows 3..5).
        self.ang_mask = np.zeros((len(joints), 3))
        self.ang_mask[kind == HINGE, 1:] = 1.0
        self.ang_mask[kind == FIXED] = 1.0
        self.eq_mask = np.concatenate((np.ones((len(joints), 3)), self.ang_mask), axis=1)  # rows stored as joint impulses
        self.hinges = np.flatnonzero(kind == HINGE)
        self.fixed = np.flatnonzero(kind == FIXED)
        self.used_rows = np.flatnonzero(self.eq_mask.reshape(-1))  # of the joints' 6 rows each, flattened

    def _position_errors(self, state, a, b, fpw, fcw, ra, rb):
        """The joints' position errors: anchor separation x_b + r_b - x_a - r_a (m)
        and the angular error vector (rad) whose lock-row components the rows
        hold at zero: hinge a_p × a_c of the two x axes, fixed 2 vec(q_c q_p*)."""
        lin = state.position[:, b] + rb - state.position[:, a] - ra
        shape = ra.shape
        ax_p = quat_rotate(fpw, np.broadcast_to(_EX, shape))
        ax_c = quat_rotate(fcw, np.broadcast_to(_EX, shape))
        herr = cross(ax_p, ax_c)
        qd = quat_mul(fcw, quat_conj(fpw))
        ferr = 2.0 * qd[..., 1:] * np.where(qd[..., 0:1] < 0, -1.0, 1.0)
        return lin, np.where((self.kind == HINGE)[:, None], herr, ferr)


class _TreeSolver(_Rows):
    """Per-substep factorisation and solve of the joint tree (see ``_JointTree``)."""

    def __init__(self, js, model, settings):
        t = _JointTree(js.parent, js.child, model.dynamic)
        self.t = t
        j = t.joints
        super().__init__(j, js.kind[j], js.parent[j], js.child[j])
        root = t.node_parent[t.n_bodies:] < 0
        dyn_b = model.dynamic[js.child[j]]
        self.child_is_b = np.where(root, dyn_b, t.a_is_parent)
        nb = t.n_bodies
        self.num_bodies = model.num_bodies
        has_child = np.zeros(t.n_nodes, dtype=bool)
        has_child[t.node_parent[t.node_parent >= 0]] = True
        ball = self.kind == BALL
        self.groups = [_Group(ids, par, splits, nb, ~has_child[ids] if ids[0] < nb else ball[ids - nb])
                       for ids, par, splits in t.groups]
        self.limits = False
        self.active_set_passes = settings.joint_active_set_passes
        self.component, self.num_components, self.body_component = t.component, t.num_components, t.body_component
        self.geometric_weight = None  # per step: 1, or (W, tree joints) weights, or None
        self.loop_geometric_weight = None  # the same for the loop-closing rows solved with the tree
        self._factored = None  # (state, blocks, factors) of the current positions and metric (see solve)

    def begin_step(self, js, model, state, h):
        """The bodies' metric M (W, tree bodies, 6, 6) at the state's
        orientations: mass, world inertia and, with geometric stiffness, its
        added inertia. Factors of earlier positions are dropped."""
        self._factored = None
        t = self.t
        b = t.bodies
        W = state.orientation.shape[0]
        M = np.zeros((W, t.n_bodies, 6, 6))
        m = model.mass[b]
        for k in range(3):
            M[..., k, k] = m
        I = world_inv_inertia(None, model.inertia[b], js._rot[:, b])
        self.iinv = js._iinv
        if self.geometric_weight is not None:
            # Geometric stiffness (Andrews, Teichmann & Kry 2017; Tournier et al.
            # 2015): a joint carrying force f at lever arm r resists turning the
            # body with stiffness ~ |f| (|r|² I - r rᵀ)/|r|; its implicit-Euler
            # share h² K is added to the body's inertia in the joint solve, which
            # keeps light links between heavy loads from the explicit
            # instability of the constraint-force direction.
            # Loop-closing joints solved with the tree carry load too: without
            # theirs, a 20 kg ball on a chain pinned at both ends gained 12 J in
            # 3 s (benchmarks.stability chain_loop).
            G = np.zeros((W, model.num_bodies, 3, 3))
            parts = [(self.joints, self.geometric_weight)]
            if js.loop_rows is not None and self.loop_geometric_weight is not None:
                parts.append((js.loop_rows.joints, self.loop_geometric_weight))
            for idx, weight in parts:
                _, _, _, _, ra, rb = js.frames(state, idx)
                lam = state.joint_linear_impulse[:, idx]
                f = np.sqrt(dot(lam, lam))
                if js._load_before is not None:
                    # Within a step: the smaller of the loads before and after this
                    # substep's biased solve (see JointSet.positions_moved).
                    f = np.minimum(f, js._load_before[:, idx])
                f = f * h * weight  # h² |F| = h |λ|
                for body, r in ((js.parent[idx], ra), (js.child[idx], rb)):
                    rn = np.sqrt(dot(r, r))
                    g = f / np.maximum(rn, 1e-12)
                    K = -r[..., :, None] * r[..., None, :]
                    for k in range(3):
                        K[..., k, k] += rn * rn
                    np.add.at(G, (slice(None), body), g[..., None, None] * K)
            # Capped at a few times the body's own inertia: the stiffness grows with
            # the load, and the load needed to turn a heavier body grows with it.
            G = G[:, b]
            trI = I[..., 0, 0] + I[..., 1, 1] + I[..., 2, 2]
            trG = G[..., 0, 0] + G[..., 1, 1] + G[..., 2, 2]
            cap = js.settings.joint_geometric_stiffness_cap * trI
            scale = np.where(trG > cap, cap / np.where(trG > cap, trG, 1.0), 1.0)
            I = I + G * scale[..., None, None]
            inv = js._iinv.copy()
            # Bodies without added stiffness keep their inverse as computed (bit
            # for bit, so a world reads the same stepped alone or in a batch).
            inv[:, b] = np.where((trG > 0)[..., None, None], sym3_inverse(I), inv[:, b])
            # Every joint row (warm start, limits, tree) uses the same metric.
            js._iinv = self.iinv = inv
        M[..., 3:, 3:] = I
        self.M = M
        # Its inverse, blockdiag(I/m, I_w⁻¹): the pivots of leaf bodies.
        M_inv = np.zeros(M.shape)
        M_inv[..., _DIAG3, _DIAG3] = model.inv_mass[b][:, None]
        M_inv[..., 3:, 3:] = self.iinv[:, b]
        self.M_inv = M_inv

    def jacobians(self, js, state, use_bias, bias_rate, velocity=True, max_push_out=None,
                  max_angular_push_out=None, rows=None):
        """Jacobian blocks (W, nj, 6, 6) of each tree joint (or of the joints
        of ``rows``, a ``_Rows``) wrt its sides a and b, the row mask and the
        right-hand side J·u + bias·C (without ``velocity``: bias·C alone); the
        bias is clamped to the joint push-out speeds unless other limits are
        given."""
        blocks = self.blocks(js, state, self if rows is None else rows)
        return self.right_hand_side(js, state, blocks, self if rows is None else rows, use_bias, bias_rate,
                                    velocity, max_push_out, max_angular_push_out)

    def blocks(self, js, state, rows):
        """The part of ``jacobians`` that depends on the positions alone:
        sides a, b, the joint frames and lever arms, the lock-row axes E
        (W, nj, 3, 3), the Jacobian blocks Ja, Jb (W, nj, 6, 6) and the row
        mask (W, nj, 6)."""
        idx = rows.joints
        a, b, fpw, fcw, ra, rb = js.frames(state, idx)
        shape = ra.shape
        W, nj = shape[0], shape[1]
        act = js._active(state, idx)
        mask = np.empty((W, nj, 6))
        mask[..., :3] = act[..., None]
        mask[..., 3:] = act[..., None] * rows.ang_mask
        # Angular lock rows: hinge (0, y, z) of the parent frame, fixed I, ball none.
        E = np.zeros((W, nj, 3, 3))
        if rows.hinges.size:
            fh = fpw[:, rows.hinges]
            E[:, rows.hinges, 1] = quat_rotate(fh, np.broadcast_to(_EY, fh.shape[:-1] + (3,)))
            E[:, rows.hinges, 2] = quat_rotate(fh, np.broadcast_to(_EZ, fh.shape[:-1] + (3,)))
        E[:, rows.fixed] = np.eye(3)
        # Side b: [[I, -[r_b]×], [0, E]]; side a: -[[I, -[r_a]×], [0, E]]; rows masked.
        J = np.zeros((2, W, nj, 6, 6))
        J[..., _DIAG3, _DIAG3] = 1.0
        J[..., _SKEW_ROW, _SKEW_COL] = np.stack((rb, ra))[..., _SKEW_COMP] * _SKEW_SIGN
        J[..., 3:, 3:] = E
        J *= mask[..., None]
        Jb, Ja = J[0], np.negative(J[1], out=J[1])
        return a, b, fpw, fcw, ra, rb, E, Ja, Jb, mask

    def right_hand_side(self, js, state, blocks, rows, use_bias, bias_rate, velocity=True, max_push_out=None,
                        max_angular_push_out=None):
        """``jacobians`` from the ``blocks`` of the current positions: (a, b,
        Ja, Jb, mask, r) with r = J·u + bias·C (W, nj, 6)."""
        if max_push_out is None:
            max_push_out = js.settings.joint_max_push_out
        if max_angular_push_out is None:
            max_angular_push_out = js.settings.joint_max_angular_push_out
        a, b, fpw, fcw, ra, rb, E, Ja, Jb, mask = blocks
        r = np.empty(mask.shape)
        if velocity:
            va, vb = state.velocity[:, a], state.velocity[:, b]
            wa, wb = state.angular_velocity[:, a], state.angular_velocity[:, b]
            r[..., :3] = vb + cross(wb, rb) - va - cross(wa, ra)
            r[..., 3:] = mat_vec(E, wb - wa)
        else:
            r[...] = 0.0
        if use_bias and np.any(bias_rate):
            lin, ang = rows._position_errors(state, a, b, fpw, fcw, ra, rb)
            r[..., :3] += clamp_norm(bias_rate * lin, max_push_out)
            r[..., 3:] += mat_vec(E, clamp_norm(bias_rate * ang, max_angular_push_out))
        r *= mask
        return a, b, Ja, Jb, mask, r

    def limit_rows(self, js, state, h, use_bias):
        """Limit rows in the free angular slots of each tree joint: hinge slot 3
        (twist), ball slots 3 (twist) and 4 (swing). The accumulated limit impulse
        is taken off the velocities first, so the active-set solve finds the
        whole (rigid, one-sided) limit impulse afresh.
        Returns J rows (W, nj, 3, 3), rhs (W, nj, 3), sign σ (W, nj, 3) with
        σ·λ >= 0 required, and which rows exist (W, nj, 3)."""
        idx = self.joints
        a, b = js.parent[idx], js.child[idx]
        lam = state.joint_limit_impulse[:, idx]
        Jt, twist, Js, Cs = js.limit_geometry(state, idx)
        # Remove the warm-started limit impulse.
        L = (lam[..., 0:1] - lam[..., 1:2]) * Jt + lam[..., 2:3] * Js
        np.add.at(state.angular_velocity, (slice(None), a), mat_vec(js._iinv[:, a], L))
        np.add.at(state.angular_velocity, (slice(None), b), -mat_vec(js._iinv[:, b], L))
        state.joint_limit_impulse[:, idx] = 0.0
        lo, hi = js.lower[idx], js.upper[idx]
        C_lo = np.where(np.isfinite(lo), twist - np.where(np.isfinite(lo), lo, 0.0), np.inf)
        C_hi = np.where(np.isfinite(hi), np.where(np.isfinite(hi), hi, 0.0) - twist, np.inf)
        # One twist row per joint: the bound the twist is heading for by the
        # substep's end (a light limb can cross the whole range in a substep).
        wrel = state.angular_velocity[:, b] - state.angular_velocity[:, a]
        ahead = h * dot(Jt, wrel)
        lower = C_lo + ahead <= C_hi - ahead
        sigma_t = np.where(lower, 1.0, -1.0)
        C_t = np.minimum(C_lo, C_hi)
        W, nj = twist.shape
        rows = np.zeros((W, nj, 3, 3))
        rows[..., 0, :] = Jt
        rows[..., 1, :] = np.where((self.kind == BALL)[:, None], Js, 0.0)
        exists = np.zeros((W, nj, 3), dtype=bool)
        exists[..., 0] = np.broadcast_to(js.has_limit[idx], (W, nj)) & (self.kind != FIXED)
        exists[..., 1] = np.broadcast_to(js.has_swing[idx], (W, nj))
        exists &= (js._active(state, idx) > 0)[..., None]
        sigma = np.ones((W, nj, 3))
        sigma[..., 0] = sigma_t
        C = np.stack((np.where(exists[..., 0], C_t, 0.0), np.where(exists[..., 1], Cs, 0.0), np.zeros((W, nj))), -1)
        wrel = state.angular_velocity[:, b] - state.angular_velocity[:, a]
        r = mat_vec(rows, wrel)
        # Speculative while open (C/h), rigid position bias when violated in
        # the biased solve, none in the relax solve.
        bias = np.where(C > 0, C / h, np.maximum(C / h, -js.settings.joint_max_angular_push_out) if use_bias else 0.0)
        r = r + sigma * bias
        r = np.where(exists, r, 0.0)
        return rows, r, sigma, exists, lower

    def solve(self, js, model, state, bias_rate, mass_scale, impulse_scale, use_bias, h):
        if not self.limits:
            # Factored once per set of positions and metric: the relax solve of
            # one substep and the biased solve of the next see the same
            # positions (only velocities change between them), so the second
            # reuses the first's factors, the same numbers (5 factorisations a
            # step instead of 8 at 4 substeps). Factors of a solve before the
            # positions moved are never reused: the relax solve on the biased
            # solve's factors let a 100 kg ball on a light chain gain energy
            # (benchmarks.stability ball_and_chain_far).
            if self._factored is None or self._factored[0] is not state:
                blocks = self.blocks(js, state, self)
                self._factored = (state, blocks, self._factor(blocks[7], blocks[8], blocks[9]))
            _, blocks, factors = self._factored
            a, b, Ja, Jb, mask, r = self.right_hand_side(js, state, blocks, self, use_bias, bias_rate)
            x = self._substitute(factors, r)
            d = (-mass_scale * x - impulse_scale * self._lam(state)) * mask
            self._apply(js, model, state, a, b, Ja, Jb, d)
            return
        lrows, lr, sigma, exists, lower = self.limit_rows(js, state, h, use_bias)
        a, b, Ja, Jb, mask, r = self.jacobians(js, state, use_bias, bias_rate)
        # Active set over the limit rows: start from the rows the current
        # velocities would violate, drop rows that pull, re-solve.
        active = exists & (sigma * lr < 0)
        for _ in range(self.active_set_passes):
            m2 = mask.copy()
            Ja2, Jb2, r2 = Ja.copy(), Jb.copy(), r.copy()
            for k in range(2):
                use = active[..., k]
                row = 3 + k
                u = use[..., None]
                Jb2[..., row, 3:] = np.where(u, lrows[..., k, :], Jb2[..., row, 3:])
                Ja2[..., row, 3:] = np.where(u, -lrows[..., k, :], Ja2[..., row, 3:])
                r2[..., row] = np.where(use, lr[..., k], r2[..., row])
                m2[..., row] = np.where(use, 1.0, m2[..., row])
            x = self._factor_solve(Ja2, Jb2, m2, r2, ball_rows=False)  # limit rows in the free slots
            lim = m2 - mask  # rows taken by limits (free slots of the joint): rigid, whole λ
            d = (-mass_scale * x - impulse_scale * self._lam(state)) * mask - x * lim
            lam_lim = -x[..., 3:5]
            bad = active[..., :2] & (sigma[..., :2] * lam_lim < 0)
            # Rows the solve's impulses would drive past their limit join.
            after = self._rows_after(js, state, a, b, Ja2, Jb2, d, lrows, lr)
            add = exists[..., :2] & ~active[..., :2] & (sigma[..., :2] * after[..., :2] < -ACTIVE_SET_TOLERANCE)
            if not (bad.any() or add.any()):
                break
            # Drop pulling rows first; add violated rows once none pulls.
            bad_joint = bad.any(axis=-1, keepdims=True)
            active[..., :2] = (active[..., :2] & ~bad) | (add & ~bad_joint)
        self._apply(js, model, state, a, b, Ja2, Jb2, d)
        # Store: twist row impulse is λ_lo - λ_hi, swing row λ_swing.
        idx = self.joints
        tw = d[..., 3] * lim[..., 3]
        state.joint_limit_impulse[:, idx, 0] = np.where(lower, tw, 0.0)
        state.joint_limit_impulse[:, idx, 1] = np.where(lower, 0.0, -tw)
        state.joint_limit_impulse[:, idx, 2] = d[..., 4] * lim[..., 4]

    def _rows_after(self, js, state, a, b, Ja, Jb, d, lrows, lr):
        """Limit row values (lr is at the current velocities) after the
        impulses Jᵀd: lr + J_lim (Δω_b - Δω_a)."""
        dw = mat_vec(self.iinv, self._body_impulses(Ja, Jb, d)[..., 3:])
        return lr + mat_vec(lrows, dw[:, b] - dw[:, a])

    def _body_impulses(self, Ja, Jb, d, rows=None):
        """Jᵀ d summed per body: (W, num_bodies, 6) linear and angular impulses."""
        return self.body_columns(Ja, Jb, d[..., None], rows)[..., 0]

    def solve_with_loops(self, js, model, state, soft_tree, soft_loop, use_bias):
        """The tree rows and the loop-closing rows (``js.loop_rows``) solved
        together, exactly (``solve_coupled``), then softened row by row as the
        tree's alone: Δλ = -mass_scale x - impulse_scale λ."""
        (bias_t, ms_t, isc_t), (bias_l, ms_l, isc_l) = soft_tree, soft_loop
        rows = js.loop_rows
        tree_rows = self.jacobians(js, state, use_bias, bias_t)
        loop_rows = self.jacobians(js, state, use_bias, bias_l, rows=rows)
        a, b, Ja, Jb, mask, _ = tree_rows
        la, lb, La, Lb, lmask, _ = loop_rows
        inv_m = model.inv_mass

        def inv_mass_times(v, worlds):
            """M⁻¹ v for per-body (W, N, 6, k) blocks of the worlds ``worlds``."""
            out = np.empty(v.shape)
            out[..., :3, :] = v[..., :3, :] * inv_m[:, None, None]
            out[..., 3:, :] = np.matmul(self.iinv[worlds], v[..., 3:, :])
            return out

        x_t, x_l = self.solve_coupled(tree_rows, loop_rows, rows, inv_mass_times)
        self._apply(js, model, state, a, b, Ja, Jb, (-ms_t * x_t - isc_t * self._lam(state)) * mask)
        self._apply(js, model, state, la, lb, La, Lb, (-ms_l * x_l - isc_l * self._lam(state, rows)) * lmask, rows)

    def body_columns(self, JA, JB, x, rows=None):
        """Σ Jᵀ x per body, (W, N, 6, k), from row blocks x (W, n, 6, k) of the
        tree's joints (or of ``rows``)."""
        rows = self if rows is None else rows
        out = np.zeros((x.shape[0], self.num_bodies, 6, x.shape[-1]))
        _scatter_add(out, rows.split_a, _mtm(JA, x))
        _scatter_add(out, rows.split_b, _mtm(JB, x))
        return out

    def solve_coupled(self, tree_rows, loop_rows, rows, inv_metric_times, M=None, M_inv=None):
        """x = K⁻¹ r over the tree rows T and the loop rows L together, K = J W⁻¹ Jᵀ
        (W: the bodies' metric, the mass matrices or ``M`` with
        ``inv_metric_times(v)`` = W⁻¹ v on (W, N, 6, k) blocks; ``M_inv``:
        the inverse of ``M`` on the tree bodies, if known, for the leaf
        pivots). The tree factorisation gives X = K_TT⁻¹ K_TL column by column
        and y = K_TT⁻¹ r_T; the loop rows solve the dense Schur complement

            (K_LL - K_LT X) x_L = r_L - K_LT y,     x_T = y - X x_L

        (Baraff 1996, section 7: loops by the tree plus a small dense system).
        ``tree_rows``, ``loop_rows``: ``jacobians`` of each. One column per used
        loop row: a 10x10 grid of ball joints pinned at two corners has 82
        loops, 246 columns, and stepped at 74-83 ms against 31 ms with
        Gauss-Seidel loop rows. Returns x_T (W, nj, 6), x_L (W, nl, 6).

        Its temporaries hold bodies x loop rows per world (about 5 MB for that
        grid), so the worlds go through in chunks of at most
        ``LOOP_SOLVE_BYTES``; each world's arithmetic is its own either way.
        ``inv_metric_times(v, worlds)`` takes the chunk's world slice."""
        W, nl = loop_rows[5].shape[:2]
        # (W, n, 6, m) float64 blocks alive at once: G, V and a product per
        # body, the substitution's six per tree joint, four per loop joint
        # (an over-estimate of the measured peak: 11 MB a world for the grid).
        per_world = 8 * 6 * rows.used_rows.size * (3 * self.num_bodies + 6 * tree_rows[5].shape[1] + 4 * nl)
        chunk = max(1, LOOP_SOLVE_BYTES // max(per_world, 1))
        if W <= chunk:
            return self._solve_coupled(tree_rows, loop_rows, rows, inv_metric_times, M, M_inv, slice(None))
        parts = [self._solve_coupled(tree_rows, loop_rows, rows, inv_metric_times, M, M_inv, slice(w, min(w + chunk, W)))
                 for w in range(0, W, chunk)]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def _solve_coupled(self, tree_rows, loop_rows, rows, inv_metric_times, M, M_inv, worlds):
        """``solve_coupled`` for the worlds of the slice ``worlds``."""
        a, b, Ja, Jb, mask, r = (x if i < 2 else x[worlds] for i, x in enumerate(tree_rows))
        la, lb, La, Lb, lmask, lr = (x if i < 2 else x[worlds] for i, x in enumerate(loop_rows))
        if M is None:
            M, M_inv = self.M, self.M_inv
        factors = self._factor(Ja, Jb, mask, M[worlds], M_inv=None if M_inv is None else M_inv[worlds])
        W, nl = lr.shape[:2]

        def rows_of(JA, JB, ia, ib, v):
            """J v for row blocks with sides ia, ib: (W, n, 6, k) from (W, N, 6, k)."""
            return _mm(JA, v[:, ia]) + _mm(JB, v[:, ib])

        # G = W⁻¹ J_Lᵀ, one column per used loop row (the kinds' rows; broken
        # joints' rows are masked per world below).
        used = rows.used_rows
        m = used.size
        eye = np.zeros((W, nl * 6, m))
        eye[:, used, np.arange(m)] = 1.0
        G = inv_metric_times(self.body_columns(La, Lb, eye.reshape(W, nl, 6, m), rows), worlds)
        X = self._substitute_columns(factors, rows_of(Ja, Jb, a, b, G))  # K_TT⁻¹ K_TL (W, nj, 6, m)
        V = inv_metric_times(self.body_columns(Ja, Jb, X), worlds)
        S = (rows_of(La, Lb, la, lb, G) - rows_of(La, Lb, la, lb, V)).reshape(W, nl * 6, m)[:, used]
        # Rows of a straight chain between two pins are redundant (a 10x10 grid
        # pinned at two corners of one edge): a relative 1e-6 on the diagonal
        # keeps S definite; an impulse in that null space moves nothing.
        diag = np.arange(m)
        lm = lmask.reshape(W, nl * 6)[:, used]
        S[:, diag, diag] += (1.0 - lm) + LOOP_REGULARISATION * S[:, diag, diag].max(axis=1, keepdims=True)
        y = self._substitute_columns(factors, r[..., None])  # K_TT⁻¹ r_T
        Ky = rows_of(La, Lb, la, lb, inv_metric_times(self.body_columns(Ja, Jb, y), worlds))
        rhs = (lr[..., None] - Ky).reshape(W, nl * 6, 1)[:, used] * lm[..., None]
        # A world already diverging (non-finite S) is solved as identity rows:
        # it is reported non-finite after the step instead of stopping the batch.
        bad = ~np.isfinite(S).all(axis=(1, 2))
        if bad.any():
            S[bad] = np.eye(m)
        x_used = np.linalg.solve(S, rhs)  # (W, m, 1)
        x_t = (y - np.matmul(X, x_used[:, None]))[..., 0]
        x_l = np.zeros((W, nl * 6))
        x_l[:, used] = x_used[..., 0]
        return x_t, x_l.reshape(W, nl, 6)

    def _lam(self, state, rows=None):
        """Accumulated equality-row impulses (W, n, 6) of the tree's joints (or of ``rows``)."""
        idx = (self if rows is None else rows).joints
        return np.concatenate((state.joint_linear_impulse[:, idx], state.joint_angular_impulse[:, idx]), axis=-1)

    def _apply(self, js, model, state, a, b, Ja, Jb, d, rows=None):
        """Accumulate the equality-row impulses d of the tree's joints (or of
        ``rows``; rows 3..5 of limit-taken slots are not stored here) and apply
        J_aᵀ d, J_bᵀ d."""
        rows = self if rows is None else rows
        new = self._lam(state, rows) + d * rows.eq_mask
        state.joint_linear_impulse[:, rows.joints] = new[..., :3]
        state.joint_angular_impulse[:, rows.joints] = new[..., 3:]
        imp = self._body_impulses(Ja, Jb, d, rows)
        state.velocity += imp[..., :3] * model.inv_mass[:, None]
        state.angular_velocity += mat_vec(self.iinv, imp[..., 3:])

    def _factor_solve(self, Ja, Jb, mask, r, M=None, ball_rows=True, M_inv=None):
        """(J M⁻¹ Jᵀ)⁻¹ r over the rows in mask (others 0); M, ``ball_rows``
        and ``M_inv`` as in ``_factor``."""
        return self._substitute(self._factor(Ja, Jb, mask, M, ball_rows, M_inv), r)

    def _factor(self, Ja, Jb, mask, M=None, ball_rows=True, M_inv=None):
        """Block LDLᵀ factors of [M Jᵀ; J 0] in leaves-first order (M: the
        bodies' (W, tree bodies, 6, 6) metric, default their mass matrices;
        ``M_inv``, if known, its inverse).

        A body node's pivot is D_b = M_b - Σ_children J_pᵀ D_j⁻¹ J_p; a joint
        node's is D_j = diag(mask - 1) - J_c D_c⁻¹ J_cᵀ (its one child body c).
        Closed forms: a leaf body's pivot is M_b, whose inverse is M_inv's
        (with the mass metric blockdiag(I/m, I_w⁻¹)); a ball joint's (``ball_rows``: its
        angular rows 3-5 are empty, as ``blocks`` builds them) is
        blockdiag(D_j[:3, :3], -I), one 3x3 inverse by the adjugate (10 times
        faster than LAPACK's from a thousand matrices, 4 times slower for one,
        about 12 µs more a call; it reads the upper triangle of a block
        symmetric to rounding, and the block is negative definite, never
        singular: -I for a broken joint). Returns D⁻¹ and
        L = D⁻¹ H_parent of each group."""
        nb = self.t.n_bodies
        cb = self.child_is_b[:, None, None]
        Jc = np.where(cb, Jb, Ja)  # block of the joint's tree child body
        Jp = np.where(cb, Ja, Jb)  # block of its tree parent body (unused for roots)
        W = mask.shape[0]
        metric, leaf_inv = (self.M, self.M_inv) if M is None else (M, M_inv)
        acc_b = np.zeros((W, nb, 6, 6))
        acc_j = np.empty(Jc.shape)  # J_c D_c⁻¹ J_cᵀ of each joint's child body
        Dinv, L = [], []
        for g in self.groups:
            if g.body:
                Di = g.pivots(leaf_inv is not None,
                              lambda ids: leaf_inv[:, ids],
                              lambda ids: _inv_definite(metric[:, ids] - acc_b[:, ids]))
                if g.has_parent:
                    Jg = Jc[:, g.pj]
                    Lg = _mm(Di, np.swapaxes(Jg, -1, -2))
                    acc_j[:, g.pj] = _mm(Jg, Lg)
            else:
                Di = g.pivots(ball_rows, lambda j: self._ball_pivot_inverse(acc_j[:, j], mask[:, j]),
                              lambda j: _inv_definite(self._joint_pivot(acc_j[:, j], mask[:, j])))
                if g.has_parent:
                    Jg = Jp[:, g.jids]
                    Lg = _mm(Di, Jg)
                    _scatter_add(acc_b, g.splits, _mtm(Jg, Lg))
            Dinv.append(Di)
            L.append(Lg if g.has_parent else None)
        return Dinv, L

    @classmethod
    def _ball_pivot_inverse(cls, acc, mask):
        """D_j⁻¹ = blockdiag(D_j[:3, :3]⁻¹, -I) of ball joints (angular rows empty)."""
        Di = np.zeros(acc.shape)
        Di[..., :3, :3] = sym3_inverse(cls._joint_pivot(acc[..., :3, :3], mask[..., :3]))
        Di[..., 3 + _DIAG3, 3 + _DIAG3] = -1.0
        return Di

    @staticmethod
    def _joint_pivot(acc, mask):
        """D_j = diag(mask - 1) - acc for (W, n, k, k) blocks acc and (W, n, k) masks."""
        D = np.negative(acc)
        k = acc.shape[-1]
        D.reshape(D.shape[:-2] + (k * k,))[..., ::k + 1] += mask - 1.0
        return D

    def _substitute(self, factors, r):
        """Forward and back substitution with the factors of ``_factor``:
        (J M⁻¹ Jᵀ)⁻¹ r for r (W, nj, 6)."""
        return self._substitute_columns(factors, r[..., None])[..., 0]

    def _substitute_columns(self, factors, R):
        """The same for k right-hand sides at once, R (W, nj, 6, k)."""
        Dinv, L = factors
        nb = self.t.n_bodies
        W, k = R.shape[0], R.shape[-1]
        acc_b = np.zeros((W, nb, 6, k))
        acc_j = np.empty(R.shape)
        bp = []
        for g, Lg in zip(self.groups, L):
            if g.body:
                b = -acc_b[:, g.ids]
                if g.has_parent:
                    acc_j[:, g.pj] = _mtm(Lg, b)
            else:
                b = R[:, g.jids] - acc_j[:, g.jids]
                if g.has_parent:
                    _scatter_add(acc_b, g.splits, _mtm(Lg, b))
            bp.append(b)
        x_b = np.empty((W, nb, 6, k))
        x_j = np.empty(R.shape)
        for g, Di, Lg, b in zip(self.groups[::-1], Dinv[::-1], L[::-1], bp[::-1]):
            xi = _mm(Di, b)
            if g.body:
                if g.has_parent:
                    xi = xi - _mm(Lg, x_j[:, g.pj])
                x_b[:, g.ids] = xi
            else:
                if g.has_parent:
                    xi = xi - _mm(Lg, x_b[:, g.par])
                x_j[:, g.jids] = xi
        return -x_j  # (J M⁻¹ Jᵀ)⁻¹ R per joint
