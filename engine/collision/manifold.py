"""The contact manifold returned by every narrow-phase pair function.

Shapes: W worlds, P pairs of one shape combination, up to ``MAX_POINTS``
contact points per pair. Units: metres. The kernels build a manifold as a
tuple (:mod:`engine.core.collide.manifold`); this is its numpy form.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core.collide.manifold import INVALID_SEPARATION, MAX_POINTS

__all__ = ["INVALID_SEPARATION", "MAX_POINTS", "Manifold"]


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
