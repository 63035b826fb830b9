"""The contact manifold returned by every narrow-phase pair function.

Shapes: W worlds, P pairs of one shape combination, up to ``MAX_POINTS``
contact points per pair. Units: metres.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Contact points per pair (a box face resting on a face needs four).
MAX_POINTS = 4

#: Separation stored in slots that hold no contact point.
INVALID_SEPARATION = np.inf


class Manifold(NamedTuple):
    """Contacts between shape a and shape b of P pairs in W worlds.

    normal:     (W, P, 3) unit vector pointing from shape a to shape b (one per pair).
    point:      (W, P, 4, 3) world contact points, midway between the two surfaces (m).
    separation: (W, P, 4) signed distance between the surfaces along ``normal`` (m);
                negative = penetration depth, ``INVALID_SEPARATION`` (+inf) in
                slots where ``valid`` is False.
    valid:      (W, P, 4) bool; a point is valid when its separation < margin.

    Points of invalid slots are finite but meaningless. Slots are assigned by
    feature (box corner, capsule end, incident-face vertex order) so that a
    resting contact keeps its points in the same slots from step to step.
    """

    normal: np.ndarray
    point: np.ndarray
    separation: np.ndarray
    valid: np.ndarray

    def flipped(self) -> "Manifold":
        """The same contacts seen from the other shape (normal from b to a)."""
        return self._replace(normal=-self.normal)

    @property
    def count(self) -> np.ndarray:
        """(W, P) number of valid points."""
        return self.valid.sum(axis=-1)


def assemble(normal, points, separation, exists, margin) -> Manifold:
    """Pad K <= 4 candidate points to a :class:`Manifold`.

    normal (..., 3); points (..., K, 3); separation (..., K); exists (..., K)
    bool or None (all exist). A point is valid when it exists, its separation
    is finite and below ``margin`` (m: a number, or one per pair, shaped as
    the leading axes).
    """
    k = separation.shape[-1]
    lead = np.broadcast_shapes(normal.shape[:-1], points.shape[:-2], separation.shape[:-1])
    normal = np.broadcast_to(normal, lead + (3,))
    points = np.broadcast_to(points, lead + (k, 3))
    separation = np.broadcast_to(separation, lead + (k,))
    valid = (separation < np.asarray(margin)[..., None]) & np.isfinite(separation)
    if exists is not None:
        valid &= np.broadcast_to(exists, lead + (k,))
    point = np.zeros(lead + (MAX_POINTS, 3))
    point[..., :k, :] = np.where(np.isfinite(points), points, 0.0)
    sep = np.full(lead + (MAX_POINTS,), INVALID_SEPARATION)
    sep[..., :k] = np.where(valid, separation, INVALID_SEPARATION)
    val = np.zeros(lead + (MAX_POINTS,), dtype=bool)
    val[..., :k] = valid
    return Manifold(np.ascontiguousarray(normal, dtype=float), point, sep, val)


def select(cond: np.ndarray, if_true: Manifold, if_false: Manifold) -> Manifold:
    """Per pair, the manifold ``if_true`` where ``cond`` (..., ) holds, else ``if_false``."""
    c3 = cond[..., None]
    return Manifold(
        np.where(c3, if_true.normal, if_false.normal),
        np.where(c3[..., None], if_true.point, if_false.point),
        np.where(c3, if_true.separation, if_false.separation),
        np.where(c3, if_true.valid, if_false.valid),
    )
