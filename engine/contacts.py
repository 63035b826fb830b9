"""Contacts: candidate pairs, per-step manifolds, and their rows in the soft-step solver.

Build time: every pair of bodies that may touch (shape, group/mask filters,
bones joined by a joint skip each other unless asked, bones of one
articulation skip each other unless the scene declares "self_collision"),
sorted by shape-pair kind, with its combined friction and restitution.

Each step (``begin_step``): world AABBs grown by the distance each body can
travel in the step (speculative margin, so fast bodies do not tunnel), a
vectorised overlap test over worlds × pairs, then the narrow phase only on the
overlapping (world, pair) rows, gathered flat across worlds. The rows are
coloured in a few vectorised rounds so that no (world, body) appears twice in
a colour; each colour is one sweep of the solver (:mod:`engine.contact_solver`).

Warm-start impulses persist per (world, pair, manifold slot) in the state.
"""

from __future__ import annotations

import numpy as np

from .collision import MAX_POINTS, aabb, candidate_pairs, overlapping, pair_function
from .contact_projection import merged, project_static_contacts
from .contact_solver import ContactRows
from .math3d import norm
from .shapes import NONE, PLANE


class ContactSet:
    """The compiled contact pairs of a model and their per-step solver rows."""

    def __init__(self, model, builder):
        fx = builder.effects
        self.settings = builder.settings
        self.friction_on = "friction" in fx
        self.restitution_on = "restitution" in fx
        excluded = set()
        # Bodies held by a joint: their impacts need the joint solve (restitution).
        self.jointed = np.zeros(len(builder.bodies), dtype=bool)
        for j in builder.joints:
            if not j.collide_connected:
                excluded.add((j.parent, j.child))
            for body in (j.parent, j.child):
                if body is not None and body >= 0:
                    self.jointed[body] = True
        if "self_collision" not in fx:
            excluded |= _same_articulation_pairs(builder)
        group = np.array([b.collision_group for b in builder.bodies], dtype=np.int64)
        mask = np.array([b.collision_mask for b in builder.bodies], dtype=np.int64)
        pa, pb = candidate_pairs(model.shape_type, model.dynamic, group, mask, excluded)
        # Sort pairs by shape-pair kind so each kind is one contiguous slice.
        kind = model.shape_type[pa] * 8 + model.shape_type[pb]
        order = np.argsort(kind, kind="stable")
        self.pair_a, self.pair_b = pa[order], pb[order]
        kind = kind[order]
        self.num_pairs = self.pair_a.size
        self.kinds = []
        for k in np.unique(kind):
            idx = np.flatnonzero(kind == k)
            ta, tb = model.shape_type[self.pair_a[idx[0]]], model.shape_type[self.pair_b[idx[0]]]
            fn, swapped = pair_function(int(ta), int(tb))
            self.kinds.append((idx[0], idx[-1] + 1, fn, swapped))
        mats = model.materials
        names = model.body_material
        mu = [mats.friction(names[a], names[b]) for a, b in zip(self.pair_a, self.pair_b)]
        self.mu_static = np.array([m[0] for m in mu], dtype=float).reshape(-1)
        self.mu_kinetic = np.array([m[1] for m in mu], dtype=float).reshape(-1)
        self.restitution = np.array([mats.restitution(names[a], names[b]) for a, b in
                                     zip(self.pair_a, self.pair_b)], dtype=float).reshape(-1)
        if not self.friction_on:
            self.mu_static[:] = 0.0
            self.mu_kinetic[:] = 0.0
        if not self.restitution_on or not (self.restitution > 0).any():
            self.restitution[:] = 0.0
            self.restitution_on = False
        static_pair = ~model.dynamic[self.pair_a] | ~model.dynamic[self.pair_b]
        self.static_pairs = np.flatnonzero(static_pair)
        # The dynamic body of each pair with a static one.
        self.static_pair_body = np.where(model.dynamic[self.pair_a], self.pair_a, self.pair_b)[self.static_pairs]
        self.has_constraints = self.num_pairs > 0
        self.bounding_radius = _bounding_radius(model)
        self.effect_names = {"contacts"}
        if self.friction_on:
            self.effect_names.add("friction")
        if self.restitution_on:
            self.effect_names.add("restitution")
        if "self_collision" in fx:
            self.effect_names.add("self_collision")
        self.rows = None
        #: the points of the bodies the static projection moved in the last step (``project_static``)
        self.projected = None

    def initial_arrays(self, W):
        P = self.num_pairs
        return {
            "contact_normal_impulse": np.zeros((W, P, MAX_POINTS)),
            "contact_friction_impulse": np.zeros((W, P, MAX_POINTS, 3)),
            "contact_separation": np.full((W, P), np.inf),
        }

    # ------------------------------------------------------------- detection
    def begin_step(self, model, state, h):
        """Broad phase, narrow phase and row preparation, once per step."""
        s = self.settings
        dt = s.dt
        lo, hi = aabb(model.shape_type, model.shape_params, state.position, state.orientation)
        # Speculative margin: how far a body's surface may move in one step.
        reach = norm(state.velocity) * dt + norm(state.angular_velocity) * dt * self.bounding_radius
        lo = lo - reach[..., None]
        hi = hi + reach[..., None]
        over = overlapping(lo, hi, self.pair_a, self.pair_b, 0.5 * s.speculative_distance)
        p_idx, w_idx = np.nonzero(over.T)  # rows sorted by pair, so each kind is one slice
        state.contact_separation[...] = np.inf
        if w_idx.size == 0:
            self.rows = None
            state.contact_normal_impulse[...] = 0.0
            state.contact_friction_impulse[...] = 0.0
            return
        a, b = self.pair_a[p_idx], self.pair_b[p_idx]
        pos, quat = state.position, state.orientation
        # Each pair's own margin (the narrow phase keeps the points within it):
        # with one margin for all (the largest), a box pair's choice of its 4
        # points depended on the other worlds' speeds.
        margin_row = s.speculative_distance + (reach[w_idx, a] + reach[w_idx, b])
        normal = np.empty((w_idx.size, 3))
        point = np.empty((w_idx.size, MAX_POINTS, 3))
        sep = np.empty((w_idx.size, MAX_POINTS))
        valid = np.empty((w_idx.size, MAX_POINTS), dtype=bool)
        # Rows are sorted by pair index, so each kind's rows are one slice.
        bounds = np.searchsorted(p_idx, [(k[0], k[1]) for k in self.kinds])
        for (start, stop, fn, _), (r0, r1) in zip(self.kinds, bounds):
            if r1 <= r0:
                continue
            sl = slice(r0, r1)
            ra, rb = a[sl], b[sl]
            wa = w_idx[sl]
            m = fn(pos[wa, ra][None], quat[wa, ra][None], model.shape_params[ra],
                   pos[wa, rb][None], quat[wa, rb][None], model.shape_params[rb], margin_row[sl][None])
            normal[sl], point[sl], sep[sl], valid[sl] = m.normal[0], m.point[0], m.separation[0], m.valid[0]
        keep = valid.any(axis=1)
        w_idx, p_idx, a, b = w_idx[keep], p_idx[keep], a[keep], b[keep]
        normal, point, sep, valid = normal[keep], point[keep], sep[keep], valid[keep]
        state.contact_separation[w_idx, p_idx] = np.where(valid, sep, np.inf).min(axis=1)
        # Warm-start impulses of rows that persist; everything else restarts at 0.
        lam_n = state.contact_normal_impulse[w_idx, p_idx] * valid
        lam_t = state.contact_friction_impulse[w_idx, p_idx] * valid[..., None]
        state.contact_normal_impulse[...] = 0.0
        state.contact_friction_impulse[...] = 0.0
        if w_idx.size == 0:
            self.rows = None
            return
        self.rows = ContactRows(model, state, self, w_idx, p_idx, a, b, normal, point, sep, valid,
                                lam_n, lam_t, h)

    # ---------------------------------------------------------------- solver
    def warm_start(self, model, state):
        if self.rows is not None:
            self.rows.warm_start(model, state)

    def solve(self, model, state, h, use_bias):
        if self.rows is not None:
            self.rows.solve(model, state, h, use_bias)

    def relax_free_bodies(self, model, state, h):
        """One more relax pass over the rows whose bodies carry no joints
        (``Settings.free_contact_relax_passes``)."""
        if self.rows is not None:
            self.rows.solve(model, state, h, use_bias=False, only_free=True)

    def end_step(self, model, state, h, events):
        if self.rows is None:
            return
        if self.restitution_on:
            self.rows.restitution(model, state)
        if self.settings.solver == "thesis":
            self.rows.project_positions(model, state)
        self.rows.store(state)

    def project_static(self, model, state, worlds=None):
        """After the substeps: move bodies deeper than
        ``static_contact_projection_depth`` in a static shape back out to it
        (:mod:`engine.contact_projection`; not with ``solver="thesis"``, which
        resolves penetration its own way); the moved points are kept in
        ``projected`` for the joint projection's metric (world indices of the
        step's last slice of worlds, ``Settings.world_chunk``). ``worlds``: a
        further round after the joint projection, in these worlds only (those
        the round before moved something in), its points merged with the
        rounds' before. Returns the worlds it moved something in (ascending),
        or None."""
        if worlds is None:
            self.projected = None
        if self.settings.solver == "thesis":
            return None
        moved = project_static_contacts(self, model, state, self.settings.static_contact_projection_depth, worlds)
        if moved is None:
            return None
        self.projected = merged(self.projected, moved)
        return moved.worlds

    # --------------------------------------------------------------- queries
    def bodies_in_contact(self, state) -> np.ndarray:
        """(W, num_bodies) bool: bodies with a contact row this step (touching,
        or within the speculative margin of touching)."""
        out = np.zeros(state.position.shape[:2], dtype=bool)
        if self.rows is not None:
            out[self.rows.w, self.rows.a] = True
            out[self.rows.w, self.rows.b] = True
        return out

    def touching_static(self, state, tolerance: float = 1e-3) -> np.ndarray:
        """(W, N) bool: the body pressed on, or within ``tolerance`` m of, a
        static body (the ground) at the end of the last step."""
        out = np.zeros(state.position.shape[:2], dtype=bool)
        if self.static_pairs.size == 0:
            return out
        idx = self.static_pairs
        pressed = (state.contact_normal_impulse[:, idx] > 0).any(axis=-1)
        near = state.contact_separation[:, idx] < tolerance
        np.logical_or.at(out, (slice(None), self.static_pair_body), pressed | near)
        return out


def _bounding_radius(model):
    r = np.array([0.0 if s is None or model.shape_type[i] in (PLANE, NONE) else s.bounding_radius()
                  for i, s in enumerate(model.shapes)])
    return r


def _same_articulation_pairs(builder):
    """Pairs of dynamic bodies connected through any chain of joints."""
    parent = list(range(len(builder.bodies)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for j in builder.joints:
        if builder.bodies[j.parent].static or builder.bodies[j.child].static:
            continue
        ra, rb = find(j.parent), find(j.child)
        if ra != rb:
            parent[ra] = rb
    groups = {}
    for i, body in enumerate(builder.bodies):
        if not body.static:
            groups.setdefault(find(i), []).append(i)
    pairs = set()
    for members in groups.values():
        for x in range(len(members)):
            for y in range(x + 1, len(members)):
                pairs.add((members[x], members[y]))
    return pairs


def compile_contacts(model, builder):
    """A ContactSet when the scene declares contacts, else None."""
    if "contacts" not in builder.effects:
        return None
    return ContactSet(model, builder)
