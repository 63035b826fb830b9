"""The collision detection of a step, for one world and for a batch of worlds.

For each world: the AABB of every body grown by its speculative reach
|v| dt + |ω| dt r_bound (how far its surface can move in the step, so fast
bodies do not tunnel), the overlap test over the model's fixed candidate
pair list, and the narrow phase of each overlapping pair with its own
margin (the speculative distance plus both bodies' reach). Every pair's
manifold lands in its (world, pair) row of the outputs; the batch runs one
world per ``prange`` iteration, so W worlds together give bit for bit what
each gives alone. The outputs are flat over (world, pair): row w P + p.
Units: metres, seconds.
"""

from __future__ import annotations

from ..jit import SERIAL_BELOW, kernel, parallel_kernel, prange
from ..vec import norm
from .broadphase import body_bounds, boxes_overlap
from .manifold import MAX_POINTS
from .narrowphase import narrow_world


@kernel
def detect_world(w, shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position, orientation,
                 velocity, angular_velocity, dt, speculative, bounds, margin, normal, point, separation, valid,
                 keep, contact_separation, poly):
    """Collision detection of world ``w``.

    shape_type (N,), shape_params (N, 3), bounding_radius (N,) m: the bodies'
    shapes; pair_a, pair_b, pair_kind (P,): the candidate pairs (canonical
    order) and their kind codes; position, orientation, velocity,
    angular_velocity (W, N, ·): the state (m, m/s, rad/s); dt: the step (s);
    speculative: the speculative distance (m). Scratch: bounds (W, N, 7)
    (lo, hi, reach per body), margin (W, P) (each pair's margin), poly
    (W, 2, 8, 3). Writes row w P + p of normal (W P, 3), point (W P, 4, 3),
    separation (W P, 4), valid (W P, 4) for pair p; keep (W, P): the pair
    overlaps and has a valid point; contact_separation (W, P): its least
    valid separation (+inf without one). Rows of pairs that do not overlap
    hold the normal 0 and empty slots (:func:`.narrowphase.narrow_world`).
    """
    for i in range(shape_type.shape[0]):
        lo, hi = body_bounds(shape_type[i], (shape_params[i, 0], shape_params[i, 1], shape_params[i, 2]),
                             (position[w, i, 0], position[w, i, 1], position[w, i, 2]),
                             (orientation[w, i, 0], orientation[w, i, 1], orientation[w, i, 2],
                              orientation[w, i, 3]))
        # Speculative reach: how far the body's surface may move in one step.
        v = (velocity[w, i, 0], velocity[w, i, 1], velocity[w, i, 2])
        omega = (angular_velocity[w, i, 0], angular_velocity[w, i, 1], angular_velocity[w, i, 2])
        reach = norm(v) * dt + norm(omega) * dt * bounding_radius[i]
        for c in range(3):
            bounds[w, i, c] = lo[c] - reach
            bounds[w, i, 3 + c] = hi[c] + reach
        bounds[w, i, 6] = reach
    grow = 2.0 * (0.5 * speculative)
    for p in range(pair_a.shape[0]):
        a, b = pair_a[p], pair_b[p]
        keep[w, p] = boxes_overlap((bounds[w, a, 0], bounds[w, a, 1], bounds[w, a, 2]),
                                   (bounds[w, a, 3], bounds[w, a, 4], bounds[w, a, 5]),
                                   (bounds[w, b, 0], bounds[w, b, 1], bounds[w, b, 2]),
                                   (bounds[w, b, 3], bounds[w, b, 4], bounds[w, b, 5]), grow)
        # The pair's own margin (the narrow phase keeps the points within it).
        margin[w, p] = speculative + (bounds[w, a, 6] + bounds[w, b, 6])
    narrow_world(w, pair_kind, pair_a, pair_b, position, orientation, shape_params, margin, keep, normal, point,
                 separation, valid, contact_separation, poly)


@parallel_kernel
def detect_batch(shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position, orientation,
                 velocity, angular_velocity, dt, speculative, bounds, margin, normal, point, separation, valid,
                 keep, contact_separation, poly):
    """``detect_world`` for every world, one world per ``prange`` iteration."""
    for w in prange(position.shape[0]):
        detect_world(w, shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position,
                     orientation, velocity, angular_velocity, dt, speculative, bounds, margin, normal, point,
                     separation, valid, keep, contact_separation, poly)


@kernel
def detect_serial(shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position, orientation,
                  velocity, angular_velocity, dt, speculative, bounds, margin, normal, point, separation, valid,
                  keep, contact_separation, poly):
    """``detect_world`` for every world on the calling thread (small batches)."""
    for w in range(position.shape[0]):
        detect_world(w, shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position,
                     orientation, velocity, angular_velocity, dt, speculative, bounds, margin, normal, point,
                     separation, valid, keep, contact_separation, poly)


def detect(shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position, orientation, velocity,
           angular_velocity, dt, speculative, bounds, margin, normal, point, separation, valid, keep,
           contact_separation, poly):
    """``detect_world`` for every world of the batch (arguments as there):
    ``detect_batch`` or, below ``SERIAL_BELOW`` worlds, ``detect_serial``."""
    run = detect_serial if position.shape[0] < SERIAL_BELOW else detect_batch
    run(shape_type, shape_params, bounding_radius, pair_a, pair_b, pair_kind, position, orientation, velocity,
        angular_velocity, dt, speculative, bounds, margin, normal, point, separation, valid, keep, contact_separation,
        poly)


@kernel
def gather_rows(keep, normal, point, separation, valid, normal_impulse, friction_impulse, w_out, p_out, normal_out,
                point_out, separation_out, valid_out, lam_n_out, lam_t_out):
    """The (world, pair) rows with ``keep`` (W, P) set, flat and sorted by
    pair then world (the order of ``np.nonzero(keep.T)``): their world and
    pair indices, manifolds (from the (W P, ...) rows of ``detect``) and
    warm-start impulses (the state's (W, P, 4) normal and (W, P, 4, 3)
    friction impulses, zero in slots that are not valid)."""
    P = keep.shape[1]
    r = 0
    for p in range(P):
        for w in range(keep.shape[0]):
            if not keep[w, p]:
                continue
            src = w * P + p
            w_out[r] = w
            p_out[r] = p
            for c in range(3):
                normal_out[r, c] = normal[src, c]
            for k in range(MAX_POINTS):
                on = 1.0 if valid[src, k] else 0.0
                valid_out[r, k] = valid[src, k]
                separation_out[r, k] = separation[src, k]
                lam_n_out[r, k] = normal_impulse[w, p, k] * on
                for c in range(3):
                    point_out[r, k, c] = point[src, k, c]
                    lam_t_out[r, k, c] = friction_impulse[w, p, k, c] * on
            r += 1
