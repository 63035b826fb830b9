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
colour); the kernels (:mod:`engine.core.joint_rows`) sweep a world's joints
colour by colour, then joint by joint.

Loop-closing joints are solved with the tree, exactly, through the Schur
complement of their rows (``engine.joint_tree``; ``joint_loops``).

Softness: the tree solve (:mod:`engine.joint_tree`) is exact, but Gauss-Seidel rows
solved after it (body-by-body contacts, limits outside the tree) see one body's
mass and fight rigid joints, so the tree joints of an articulation that such
rows act on take ``joint_hertz`` (rigid by default since 2026-12-04, when the
articulation's contacts are solved with its response, ``articulated_contacts``,
and its limits in the tree; 60 Hz in ``SOFT_JOINTS``), as do those of an articulation with loops
(rigid, they held their joints less well; ``loop_joint_hertz`` when its loops
are solved with the tree); those of an articulation
nothing else acts on, a pendulum or a chain in the air, are rigid with
geometric stiffness (``free_joint_hertz``, ``free_joint_geometric_stiffness``),
chosen per world and step.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .coloring import color_pairs
from .math3d import quat_rotate_inv, dot, quat_conj, quat_mul
from .joint_projection import project_joints, undo_unfollowed_moves
from .core.joints import (BALL, FIXED, HINGE, TWIST_LIMIT_MAX_SWING, JointArrays, JointGeometry,  # noqa: F401
                          empty_geometry, joint_geometry)
from .core.joints import inertia as inertia_kernel
from .core.joints import passive as passive_kernel, warm_start as warm_start_kernel
from .core.joint_rows import FIXED_LOCK, HINGE_LOCK, POINT, add_load as add_load_kernel, snap as snap_kernel
from .core.joint_rows import project_positions as project_positions_kernel, solve_equality as solve_equality_kernel
from .core.joint_rows import solve_limits as solve_limits_kernel
from .core import world
from .soft import make_soft, select_softness
from .state import Event

KINDS = {"hinge": HINGE, "ball": BALL, "fixed": FIXED}
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


class JointSet:
    """The compiled joints of a model and their solver."""

    def __init__(self, model, specs, settings):
        from .joint_tree import _Rows, _TreeSolver  # not at the top: joint_tree imports the joint kinds from here

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
        # The motors' torques are summed with the other forces by the integration
        # kernels (engine.core.effects.accumulate), from these arrays.
        self.act_joint = np.array([a.joint for a in actuators], dtype=np.int64)
        self.act_axis = np.array([a.axis for a in actuators], dtype=np.int64)
        self.act_max = np.array([a.max_torque for a in actuators], dtype=float)

        self.has_limit = has_limit = np.isfinite(self.lower) | np.isfinite(self.upper)
        self.has_swing = has_swing = (self.kind == BALL) & (self.cone < math.pi).any(axis=1)
        self.tree = None
        self.components_held_tight = None  # (W, articulations + 1) bool, set each step (begin_step)
        self._loop_tree_joints = None
        in_tree = np.zeros(J, dtype=bool)
        lim_in_tree = np.zeros(J, dtype=bool)
        if settings.tree_solve and J:
            self.tree = _TreeSolver(self, model, settings)
            in_tree[self.tree.joints] = True
            if not in_tree.any():
                self.tree = None
            elif settings.limits_in_tree:
                lim_in_tree = in_tree
                self.tree.limits = bool((has_limit | has_swing)[self.tree.joints].any())
        # Loop-closing joints solved with the tree (``_TreeSolver.solve_with_loops``),
        # unless their rows stay Gauss-Seidel; not with limits in the tree (the
        # loop solve has no active set). With rigid tree joints too: the
        # articulation takes loop_joint_hertz (``_choose_tree_softness``), as
        # rigid loop rows gained energy (the 10x10 sphere grid at ACCURATE: 103 J
        # in 10 s, 11 J with their regularisation at 1e-3). Left to Gauss-Seidel
        # at CLOSED_JOINTS, chain_loop opened by 1.85 cm and the grid by 7.5 cm
        # in their quick runs; solved here, 0.20 and 1.2 mm.
        self.loop_rows = None
        in_loop_solve = np.zeros(J, dtype=bool)
        if self.tree is not None and settings.joint_loops == "exact" and not self.tree.limits:
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
        # Each Gauss-Seidel limit row's articulation (tree component), -1 outside a tree.
        self._gs_limit_component = np.full(self.gs_limit.size, -1, dtype=np.int64)
        if self.tree is not None:
            # Articulations that Gauss-Seidel joint rows act on (loop-closing
            # joints, limits outside the tree): their tree joints stay soft.
            t = self.tree
            # Loop-closing joints count whether solved exactly or not: rigid
            # loops solved with the tree held their joints less well (a 20 kg
            # ball on a slack chain pinned at both ends, benchmarks.stability
            # chain_loop: 3.0 mm against 1.1 mm soft over 10 s).
            gs_rows = ~in_tree | ((has_limit | has_swing) & ~lim_in_tree)
            # Tree joints of articulations with loop-closing joints solved with
            # the tree: their own softness (loop_joint_hertz); None without any.
            exact_loop = np.zeros(t.num_components + 1, dtype=bool)
            exact_loop[t.body_component[self.parent[in_loop_solve]]] = True
            exact_loop[t.body_component[self.child[in_loop_solve]]] = True
            exact_loop[-1] = False
            # Per articulation (last entry: no articulation, False): closed by loops solved with the tree.
            t.exact_loop = exact_loop if exact_loop.any() else None
            t.loop_bodies = exact_loop[t.body_component]
            self._loop_tree_joints = None if t.exact_loop is None else exact_loop[t.component]
            tree_pos = np.full(J, -1, dtype=np.int64)
            tree_pos[t.joints] = np.arange(t.joints.size)
            pos = tree_pos[self.gs_limit]
            self._gs_limit_component = np.where(pos >= 0, t.component[np.maximum(pos, 0)], -1)
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
        # The passive joints colour by colour.
        self._passive_order = np.concatenate([c["passive"] for c in self.colors] + [np.zeros(0, dtype=np.int64)]
                                             ).astype(np.int64)
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
        # warm_start: the joints colour by colour.
        self._warm_joints = np.concatenate([c["all"] for c in self.colors]).astype(np.int64) if J else self._all
        self.arrays = JointArrays(self.kind, self.parent, self.child, self.frame_p, self.frame_c,
                                  self.anchor_p, self.anchor_c, np.ascontiguousarray(self.cone))
        self._frames_on = False  # geometry of _frames_state cached between begin_step and end_step
        self._frames = self._frames_state = None  # _frames: the JointGeometry of every joint

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
    def geometry(self, state) -> JointGeometry:
        """Frames, lever arms, swing-twist angles and limit rows of every joint
        (``engine.core.joints.JointGeometry``, arrays (W, J, ...)). Within a
        step computed once per set of positions (``positions_moved`` drops it)."""
        if self._frames_on and state is self._frames_state:
            if self._frames is None:
                self._frames = self._compute_geometry(state)
            return self._frames
        return self._compute_geometry(state)

    @contextlib.contextmanager
    def positions_fixed(self, state):
        """Within it the joint geometry of ``state`` (``geometry``) is
        computed once and shared by every query (angles, rates, frames,
        limits), as within a step: for queries read together, such as an
        env's observation and reward. The state's positions and orientations
        must not change inside. Outside a step only."""
        if self._frames_on:
            raise RuntimeError("positions_fixed inside a step")
        self._frames_on, self._frames, self._frames_state = True, None, state
        try:
            yield
        finally:
            self._frames_on, self._frames, self._frames_state = False, None, None

    def _compute_geometry(self, state):
        g = empty_geometry(state.num_worlds, len(self.names))
        joint_geometry(self.arrays, state.position, state.orientation, g)
        return g

    def frames(self, state, idx):
        """(parent, child, parent frame, child frame, parent lever arm, child
        lever arm) of joints ``idx``, the last four (W, len(idx), ...) in the world."""
        g = self.geometry(state)
        # take: the same copies as fancy indexing, cheaper on small arrays.
        return (self.parent.take(idx), self.child.take(idx), g.fpw.take(idx, 1), g.fcw.take(idx, 1),
                g.ra.take(idx, 1), g.rb.take(idx, 1))

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
        if self.tree is not None:
            self.tree._factored = None

    def limit_geometry(self, state, idx):
        """(J_twist, twist, J_swing, C_swing, twist_defined) of joints ``idx``
        (``engine.core.joints``: the limit rows)."""
        g = self.geometry(state)
        return tuple(x.take(idx, 1) for x in (g.jt, g.twist, g.js, g.c_swing, g.twist_defined))

    def relative_swing_twist(self, state, idx):
        """(twist, φ, d_y, d_z) of each joint's relative rotation (``engine.core.joints.swing_twist``)."""
        g = self.geometry(state)
        return tuple(x.take(idx, 1) for x in (g.twist, g.phi, g.dy, g.dz))

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
        twist, phi, dy, dz = self.relative_swing_twist(state, idx)
        v = np.maximum(np.maximum(self.lower - twist, twist - self.upper), 0.0)
        phi_max = 1.0 / np.sqrt((dy / self.cone[:, 0]) ** 2 + (dz / self.cone[:, 1]) ** 2)
        v = np.maximum(v, np.where(self.kind == BALL, np.maximum(phi - phi_max, 0.0), 0.0))
        if (self.kind == FIXED).any():
            q = quat_mul(fcw, quat_conj(fpw))
            ang = 2.0 * np.arctan2(np.sqrt(dot(q[..., 1:], q[..., 1:])), np.abs(q[..., 0]))
            v = np.where(self.kind == FIXED, ang, v)
        return np.where(state.joint_broken, 0.0, v)

    # ----------------------------------------------------------------- forces
    def passive(self, model, state, h):
        """Muscle tone: an implicit spring-damper on each joint axis towards the
        rest angles, k (N·m/rad) and c (N·m·s/rad), stable for any stiffness.
        The joints are swept colour by colour (``engine.core.joints.passive``)."""
        order = self._passive_order
        if not order.size:
            return
        passive_kernel(self.arrays, order, self._iinv, self.geometry(state), self.stiffness, self.damping,
                       np.ascontiguousarray(self.rest), state.joint_broken, state.angular_velocity, h)

    # ----------------------------------------------------------------- solver
    def begin_step(self, model, state, h, touching=None, motor=None):
        """World inverse inertias for the step (Box2D prepares once per step)
        and each tree joint's softness; ``touching`` (W, num_bodies) bool marks
        the bodies with contact rows this step (None: no contacts), ``motor``
        (W, actuators) the step's motor torques in N·m (None: none)."""
        self._frames_on, self._frames, self._frames_state = True, None, state
        self._drop_position_caches()
        self._set_inertia(model, state)
        s = self.settings
        # (W, articulations + 1): the articulations with a contact this step, for the three uses below.
        in_contact = None if touching is None or self.tree is None else self._components_in_contact(touching)
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
        self._limit_zone = None
        if (s.limit_soft_margin > 0 and s.relax_iterations > 0 and s.solver != "thesis" and in_contact is not None
                and self.gs_limit.size):
            self._limit_zone = self._soft_limit_zone(make_soft(tree_hz, s.joint_damping_ratio, h), in_contact)
        self._substeps_done = 0
        self._load_before = None
        if s.solver == "thesis":
            self._soft = make_soft(0.0, 0.0, h)  # rigid rows, position error by projection
            self._limit_soft = self._tree_soft = self._soft
        elif self.tree is not None:
            loop_hz = s.loop_joint_hertz if math.isinf(s.loop_joint_hertz) else min(s.loop_joint_hertz, cap)
            self.components_held_tight = self._components_held_tight(state.num_worlds, in_contact, motor)
            self._choose_tree_softness(make_soft(tree_hz, s.joint_damping_ratio, h),
                                       make_soft(free_hz, s.joint_damping_ratio, h), in_contact,
                                       make_soft(loop_hz, s.loop_joint_damping_ratio, h))
            self.tree.begin_step(self, model, state, h)
        self._h = h
        if self.breakable:
            # Impulses summed over the step's substeps: the load a joint carries.
            self._lin_sum = np.zeros(state.joint_linear_impulse.shape)
            self._ang_sum = np.zeros(state.joint_linear_impulse.shape[:2])

    def _components_held_tight(self, num_worlds, in_contact, motor):
        """(W, articulations + 1) bool: the articulations touching something
        (``in_contact``, ``_components_in_contact``) or driven by a nonzero motor torque
        (``motor``, (W, actuators)) this step; the last column False. Their
        joints are projected at ``joint_projection_slop``, the others' (passive,
        in the air) at ``free_joint_projection_slop`` (``joint_projection``)."""
        t = self.tree
        if in_contact is None:
            held = np.zeros((num_worlds, t.num_components + 1), dtype=bool)
        else:
            held = in_contact.copy()
        if motor is not None and len(self.act_joint):
            w, a = np.nonzero(np.asarray(motor, dtype=float) != 0.0)
            held[w, t.body_component[self.child[self.act_joint[a]]]] = True
            held[:, -1] = False
        return held

    def _soft_limit_zone(self, soft, in_contact):
        """(softness, rows) of the step's Gauss-Seidel limit rows that are soft
        while violated by less than ``limit_soft_margin``: the rows of
        articulations with a contact this step (``in_contact``, ``_components_in_contact``),
        whose tree joints are soft (``joint_hertz``), take that softness; None
        if no row does. See ``Settings.limit_soft_margin``."""
        comp = self._gs_limit_component
        if not (comp >= 0).any():  # no limit row in a tree (all -1 without one)
            return None
        rows = in_contact[:, comp]  # comp -1 reads the last column, False
        return (soft, rows) if rows.any() else None

    def _components_in_contact(self, touching):
        """(W, articulations + 1) bool: the articulations with a body in
        ``touching`` (W, bodies); the last column (no articulation) False."""
        t = self.tree
        hit = np.zeros((touching.shape[0], t.num_components + 1), dtype=bool)
        w, body = np.nonzero(touching)
        hit[w, t.body_component[body]] = True
        hit[:, -1] = False
        return hit

    def _choose_tree_softness(self, soft, rigid, in_contact, loop):
        """Each tree joint's softness for the step: an articulation that a
        Gauss-Seidel row acts on (a contact this step, a loop-closing joint,
        a limit outside the tree) takes ``joint_hertz`` (``soft``), the others
        ``free_joint_hertz`` (``rigid``) and, with
        ``free_joint_geometric_stiffness``, geometric stiffness; an
        articulation with loop-closing rows solved with the tree takes
        ``loop_joint_hertz`` (``loop``), in its tree and loop rows alike.

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
        hit = t.gs_touched[None]  # (W or 1, articulations + 1)
        if in_contact is not None:
            hit = hit | in_contact
        on = hit[:, t.component]  # (W or 1, tree joints): soft
        if self.loop_rows is not None:
            # Exact loop rows take the softness of their articulation's tree
            # joints (loop_joint_hertz), so the coupled solve is one system, scaled
            # alike (with rigid tree joints, soft loop rows gained 38 J in 10 s
            # in chain_loop where rigid ones gained none).
            self._loop_soft = loop
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
            self._tree_soft = select_softness(on[..., None], soft, rigid)
            weight = np.where(on, float(s.joint_geometric_stiffness), float(geo_free))
            t.geometric_weight = weight if weight.any() else None
        in_loop = self._loop_tree_joints
        if in_loop is not None:
            self._tree_soft = select_softness(in_loop[None, :, None], loop, self._tree_soft)
            w = t.geometric_weight
            w = np.zeros(on.shape) if w is None else np.broadcast_to(np.asarray(w, dtype=float), on.shape)
            w = np.where(in_loop, float(s.joint_geometric_stiffness), w)
            t.geometric_weight = w if w.any() else None

    def _set_inertia(self, model, state):
        """World inverse inertias (and the rotation matrices, which the tree
        solver's inertias reuse) at the state's orientations."""
        W, N = state.orientation.shape[:2]
        self._rot, self._iinv = np.empty((W, N, 3, 3)), np.empty((W, N, 3, 3))
        inertia_kernel(state.orientation, model.inv_inertia, self._rot, self._iinv)

    def _active(self, state, idx):
        return (~state.joint_broken.take(idx, 1)).astype(float)

    def _add_load(self, state):
        add_load_kernel(state.joint_linear_impulse, state.joint_angular_impulse, state.joint_limit_impulse,
                        self._lin_sum, self._ang_sum)

    def warm_start(self, model, state):
        if self.breakable and self._substeps_done:
            self._add_load(state)  # λ at the end of the previous substep
        self._substeps_done += 1
        if self.tree is not None and self.tree.geometric_weight is not None:
            lam = state.joint_linear_impulse
            self._load_before = np.sqrt(dot(lam, lam))  # the load before this substep's solve
        # Joint by joint in colour order: each body's terms in the order of a
        # sweep colour by colour.
        warm_start_kernel(self.arrays, self._warm_joints, self._iinv, model.inv_mass, self.geometry(state),
                          state.joint_linear_impulse, state.joint_angular_impulse, state.joint_limit_impulse,
                          state.velocity, state.angular_velocity)

    def solve(self, model, state, h, use_bias):
        # The equality rows (tree and Gauss-Seidel) run in the biased solve, and
        # in the relax only with joint_relax; the limit rows run after them in
        # every solve, so a limb driven into its limit ends each solve on it.
        if use_bias or self.settings.joint_relax:
            self._solve_equality(model, state, h, use_bias)
        if not self.gs_limit.size:
            return
        # Gauss-Seidel limit rows, joint by joint colour by colour
        # (engine.core.joint_rows.solve_limits): their axes, errors and
        # effective masses from the geometry at the solve's positions.
        s = self.settings
        _, _, twist_row, swing_row = self._row_orders
        bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, self._limit_soft)
        if use_bias and self._limit_zone is not None:
            zs, zone = self._limit_zone
        else:
            zs, zone = self._limit_soft, np.zeros((state.num_worlds, 0), dtype=bool)
        solve_limits_kernel(self.arrays, self.gs_limit, twist_row, swing_row, self.lower, self.upper, self._iinv,
                            self.geometry(state), state.angular_velocity, state.joint_limit_impulse,
                            state.joint_broken, h, bool(use_bias), float(bias_rate), float(mass_scale),
                            float(impulse_scale), np.ascontiguousarray(zone), float(zs.bias_rate),
                            float(zs.mass_scale), float(zs.impulse_scale), float(s.limit_soft_margin),
                            float(s.joint_max_angular_push_out))

    @cached_property
    def _row_orders(self):
        """The Gauss-Seidel rows in solve order: (joints, kinds) of the
        equality rows, colour by colour its hinge locks, fixed locks, then
        point rows; and for each joint of ``gs_limit`` whether it has twist
        rows and a swing row (its colour's twist and swing slices)."""
        joints, kinds = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
        twist_row = np.zeros(self.gs_limit.size, dtype=bool)
        swing_row = np.zeros(self.gs_limit.size, dtype=bool)
        for color in self.colors:
            for key, kind in (("hinge", HINGE_LOCK), ("fixed", FIXED_LOCK), ("point", POINT)):
                joints.append(color[key])
                kinds.append(np.full(color[key].size, kind, dtype=np.int64))
            twist_row[color["twist_slice"]] = True
            swing_row[color["swing_slice"]] = True
        return (np.concatenate(joints).astype(np.int64), np.concatenate(kinds), twist_row, swing_row)

    def _solve_equality(self, model, state, h, use_bias):
        joints, kinds, _, _ = self._row_orders
        if joints.size:
            # The Gauss-Seidel point and lock rows (engine.core.joint_rows.solve_equality).
            s = self.settings
            bias = use_bias and s.solver != "thesis"
            bias_rate, mass_scale, impulse_scale = self._soft_terms(bias, self._soft)
            solve_equality_kernel(self.arrays, joints, kinds, self._iinv, model.inv_mass, self.geometry(state),
                                  state.position, state.velocity, state.angular_velocity,
                                  state.joint_linear_impulse, state.joint_angular_impulse, state.joint_broken,
                                  float(bias_rate), float(mass_scale), float(impulse_scale),
                                  float(s.joint_max_push_out), float(s.joint_max_angular_push_out))
        if self.tree is not None and self.loop_rows is not None:
            self.tree.solve_with_loops(self, model, state, self._soft_terms(use_bias, self._tree_soft),
                                       self._soft_terms(use_bias, self._loop_soft), use_bias)
        elif self.tree is not None:
            bias_rate, mass_scale, impulse_scale = self._soft_terms(use_bias, self._tree_soft)
            self.tree.solve(self, model, state, bias_rate, mass_scale, impulse_scale, use_bias, h)

    def substep_arrays(self, model, state):
        """The joints' arguments of the compiled substeps after ``begin_step``:
        (JointStep, JointArrays, TreeRows, TreeLayout, JointGeometry)
        (``engine.core.world``); ``finish_substeps`` takes the
        JointStep's buffers back."""
        from .joint_tree import _per_joint

        s = self.settings
        W, N = state.num_worlds, model.num_bodies
        joints, kinds, twist_row, swing_row = self._row_orders
        t = self.tree
        g = self.geometry(state)
        self._frames = g  # the substeps keep it at the current positions
        if t is None:
            T, layout = world.no_tree(N)
            tree_soft, limits, schur, passes = np.zeros((3, W, 0)), False, False, 0
            geometric, idx, weight = False, np.zeros(0, dtype=np.int64), np.zeros((W, 0))
            M = M_inv = np.zeros((W, 0, 6, 6))
        else:
            nj = t.joints.size
            T, layout = t.arrays, t.layout
            tree_soft = np.stack([_per_joint(x, W, nj) for x in self._soft_terms(True, self._tree_soft)])
            limits, schur = bool(t.limits), t.uses_schur()
            passes = int(t.active_set_passes)
            geometric = t.geometric_weight is not None
            idx, weight = t.loaded if geometric else (np.zeros(0, dtype=np.int64), np.zeros((W, 0)))
            M, M_inv = t.M.copy(), t.M_inv.copy()  # the step's start metric stays with the articulated contacts
        zone_on = self._limit_zone is not None
        zs, zone = self._limit_zone if zone_on else (self._limit_soft, np.zeros((W, 0), dtype=bool))
        J = len(self.names)
        Jt = world.JointStep(
            inv_mass=np.ascontiguousarray(model.inv_mass, dtype=float),
            inv_inertia=np.ascontiguousarray(model.inv_inertia, dtype=float),
            passive=bool(self._passive_order.size), passive_order=self._passive_order, stiffness=self.stiffness,
            damping=self.damping, rest=np.ascontiguousarray(self.rest), warm_order=self._warm_joints,
            breakable=self.breakable, lin_sum=self._lin_sum if self.breakable else np.zeros((W, 0, 3)),
            ang_sum=self._ang_sum if self.breakable else np.zeros((W, 0)), relax=bool(s.joint_relax),
            thesis=s.solver == "thesis", max_push=float(s.joint_max_push_out),
            max_angular_push=float(s.joint_max_angular_push_out), eq_joints=joints, eq_kinds=kinds,
            eq_soft=_floats(self._soft), gs_limit=self.gs_limit, twist_row=twist_row, swing_row=swing_row,
            lower=self.lower, upper=self.upper, limit_soft=_floats(self._limit_soft), zone_on=zone_on,
            zone=np.ascontiguousarray(zone, dtype=bool), no_zone=np.zeros((W, 0), dtype=bool),
            zone_soft=_floats(zs), margin=float(s.limit_soft_margin), tree=t is not None, tree_soft=tree_soft,
            limits=limits, schur=bool(schur), active_set_passes=passes,
            tree_metric=t is not None and s.solver != "thesis", geometric=geometric, geo_joint=idx,
            geo_parent=self.parent[idx], geo_child=self.child[idx], n_tree_loaded=0 if t is None else int(t.joints.size),
            weight=weight, cap=float(s.joint_geometric_stiffness_cap),
            load_before=np.zeros((W, J)) if geometric else np.zeros((W, 0)), rot=np.empty((W, N, 3, 3)),
            iinv_raw=np.empty((W, N, 3, 3)), iinv=np.ascontiguousarray(self._iinv, dtype=float), M=M, M_inv=M_inv)
        return Jt, self.arrays, T, layout, g

    def finish_substeps(self, state, arrays, substeps):
        """After the compiled substeps: the buffers they wrote (``arrays``, a
        ``JointStep``) become the joints' and the tree's current ones."""
        self._substeps_done = substeps
        self._load_before = arrays.load_before if arrays.geometric else None
        self._rot, self._iinv = arrays.rot, arrays.iinv
        if self.tree is not None:
            self.tree.iinv, self.tree.M, self.tree.M_inv = arrays.iinv, arrays.M, arrays.M_inv
            self.tree._factored = None

    def _soft_terms(self, use_bias, soft):
        if use_bias:
            return soft.bias_rate, soft.mass_scale, soft.impulse_scale
        return 0.0, 1.0, 0.0

    def end_step(self, model, state, h, events):
        self._frames_on, self._frames, self._frames_state = False, None, None
        self._drop_position_caches()
        self.project_positions(model, state)
        if not self.breakable:
            return
        self._add_load(state)
        # Joints whose load over the step exceeds their break force or torque
        # snap (engine.core.joint_rows.snap); their impulses are zeroed.
        snapped = np.zeros(state.joint_broken.shape, dtype=bool)
        snap_kernel(self._lin_sum, self._ang_sum, float(model.settings.dt), self.break_force, self.break_torque,
                    state.joint_broken, state.joint_linear_impulse, state.joint_angular_impulse,
                    state.joint_limit_impulse, snapped)
        if snapped.any():
            for w, j in zip(*np.nonzero(snapped)):
                step = int(state.step[w]) + 1
                events.append(Event("joint_broken", self.names[j], int(w), step, step * model.settings.dt))

    @property
    def projects_tree(self) -> bool:
        """Whether the step's end projects the tree joints' positions
        (:mod:`engine.joint_projection`)."""
        return self.settings.solver != "thesis" and self.tree is not None and self.settings.joint_projection_passes > 0

    def project_positions(self, model, state, worlds=None):
        """Move the positions back onto the joints: the thesis's correction
        with ``solver="thesis"``, else the tree's post-stabilisation if it
        has passes (``worlds``: only these, ascending; None: all)."""
        if self.settings.solver == "thesis":
            self._project_positions(model, state)
        elif self.projects_tree:
            project_joints(self, model, state, worlds)

    def undo_unfollowed_moves(self, model, state, moved, broken):
        """Worlds whose joints could not follow the static contact
        projection's moves go back to the step without them
        (:func:`engine.joint_projection.undo_unfollowed_moves`)."""
        if self.projects_tree:
            undo_unfollowed_moves(self, model, state, moved, broken)

    def _project_positions(self, model, state):
        """The thesis's position correction: move the two anchors together,
        split by inverse mass (the lighter body moves more), joint by joint
        colour by colour (engine.core.joint_rows.project_positions)."""
        project_positions_kernel(self.arrays, self._warm_joints, model.inv_mass, state.position,
                                 state.orientation, state.joint_broken)


def _floats(soft):
    """(bias_rate, mass_scale, impulse_scale) (3,) of a scalar softness."""
    return np.array([soft.bias_rate, soft.mass_scale, soft.impulse_scale], dtype=float)


def compile_joints(model, builder):
    """A JointSet for the builder's joints, or None when there are none."""
    if not builder.joints:
        return None
    return JointSet(model, builder.joints, builder.settings)
