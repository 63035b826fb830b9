"""Contacts: candidate pairs, per-step manifolds, and their rows in the soft-step solver.

Build time: every pair of bodies that may touch (shape, group/mask filters,
bones joined by a joint skip each other unless asked, bones of one
articulation skip each other unless the scene declares "self_collision"),
sorted by shape-pair kind, with its combined friction and restitution.

Each step (``begin_step``): world AABBs grown by the distance each body can
travel in the step (speculative margin, so fast bodies do not tunnel), the
overlap test over the candidate pairs, then the narrow phase only on the
overlapping pairs, in one compiled kernel call over all worlds
(:mod:`engine.core.collide.world`); the (world, pair) rows with a valid point
are gathered flat across worlds, sorted by pair then world, and coloured
world by world so that no (world, body) appears twice in a colour; a world's
colours in turn are its sweep (:mod:`engine.contact_solver`).

Warm-start impulses persist per (world, pair, manifold slot) in the state.
"""

from __future__ import annotations

import numpy as np

from .collision import MAX_POINTS, candidate_pairs, is_canonical, kind_code
from .contact_projection import merged, project_static_contacts
from .contact_solver import ContactRows
from .core.collide import detect
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
        # Pairs sorted by shape-pair kind: the order of the state's per-pair
        # arrays and of the rows (sorted by pair, then world).
        kind = model.shape_type[pa] * 8 + model.shape_type[pb]
        order = np.argsort(kind, kind="stable")
        self.pair_a, self.pair_b = pa[order], pb[order]
        kind = kind[order]
        self.num_pairs = self.pair_a.size
        # The kernels' kind code of each pair (candidate_pairs orients every
        # pair in canonical order, so no pair needs a swap).
        types = [(int(model.shape_type[a]), int(model.shape_type[b])) for a, b in zip(self.pair_a, self.pair_b)]
        assert all(is_canonical(ta, tb) for ta, tb in types)
        self.pair_kind = np.array([kind_code(ta, tb) for ta, tb in types], dtype=np.int64)
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
        # The static pairs' kind codes and bodies, and the unbounded margin of
        # their exact narrow phase, for the static contact projection.
        self.static_pair_kind = self.pair_kind[self.static_pairs]
        self.static_pair_a = self.pair_a[self.static_pairs]
        self.static_pair_b = self.pair_b[self.static_pairs]
        self.unbounded_margin = np.full((1, self.static_pairs.size), np.inf)
        self.has_constraints = self.num_pairs > 0
        self.bounding_radius = _bounding_radius(model)
        self._shape_type = np.ascontiguousarray(model.shape_type, dtype=np.int64)
        self._shape_params = np.ascontiguousarray(model.shape_params, dtype=float)
        # Uniform gravity (m/s²), for the rows' closing accelerations and load stiffening.
        self.gravity = (np.array(model.gravity, dtype=float) if "gravity" in model.effects
                        else np.zeros(3))
        self.g_mag = float(np.linalg.norm(self.gravity))
        # Bodies held by a joint that move.
        self.held = self.jointed & model.dynamic
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
        W, P = state.num_worlds, self.num_pairs
        normal = np.empty((W * P, 3))  # row w P + p: pair p in world w
        point = np.empty((W * P, MAX_POINTS, 3))
        sep = np.empty((W * P, MAX_POINTS))
        valid = np.empty((W * P, MAX_POINTS), dtype=bool)
        keep = np.empty((W, P), dtype=bool)
        # Broad phase (AABBs grown by the speculative reach, overlap over the
        # candidate pairs) and narrow phase of the overlapping pairs, each with
        # its own margin: the kernels of engine.core.collide.world.
        detect(self._shape_type, self._shape_params, self.bounding_radius, self.pair_a, self.pair_b,
               self.pair_kind, state.position, state.orientation, state.velocity, state.angular_velocity,
               float(s.dt), float(s.speculative_distance), np.empty((W, model.num_bodies, 7)), np.empty((W, P)),
               normal, point, sep, valid, keep, state.contact_separation, np.empty((W, 2, 8, 3)))
        R = int(np.count_nonzero(keep))
        if R == 0:
            # Impulses restart at 0 for pairs without a row.
            state.contact_normal_impulse[...] = 0.0
            state.contact_friction_impulse[...] = 0.0
            self.rows = None
            return
        self.rows = ContactRows(model, state, self, keep, normal, point, sep, valid, R, h)

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
