"""One pair's contact manifold as a tuple, and its storage in output arrays.

Inside the kernels a manifold is the tuple ``(normal, points, separations,
valid)``: the unit normal from shape a to shape b, the 4 slots' points
(world, midway between the two surfaces, m), their signed separations along
the normal (m; negative = penetration, ``INVALID_SEPARATION`` where not
valid) and validity flags. Tuples stay in registers, so no kernel allocates
per pair; :func:`store` writes one into row ``r`` of the arrays ``normal``
(R, 3), ``point`` (R, MAX_POINTS, 3), ``separation`` (R, MAX_POINTS) and
``valid`` (R, MAX_POINTS).

A candidate point is valid when it exists, its separation is finite and
below the pair's margin (m). Coordinates that are not finite are stored as
0, so every stored point is finite; slots that hold no candidate get the
point 0.
"""

from __future__ import annotations

import math

from ..jit import kernel

#: Contact points per pair (a box face resting on a face needs four).
MAX_POINTS = 4

#: Separation stored in slots that hold no valid contact point (m).
INVALID_SEPARATION = math.inf


@kernel
def finite_or_zero(x):
    return x if math.isfinite(x) else 0.0


@kernel
def candidate(p, s, exists, margin):
    """A slot holding the candidate point ``p`` (m) with separation ``s`` (m):
    (point, separation, valid), valid when ``exists`` and ``s`` is finite and
    below ``margin``."""
    ok = exists and s < margin and math.isfinite(s)
    return ((finite_or_zero(p[0]), finite_or_zero(p[1]), finite_or_zero(p[2])),
            s if ok else INVALID_SEPARATION, ok)


@kernel
def empty():
    """A slot holding no candidate."""
    return (0.0, 0.0, 0.0), INVALID_SEPARATION, False


@kernel
def manifold(n, s0, s1, s2, s3):
    """The manifold of normal ``n`` and the slots s0..s3 (``candidate``, ``empty``)."""
    return n, (s0[0], s1[0], s2[0], s3[0]), (s0[1], s1[1], s2[1], s3[1]), (s0[2], s1[2], s2[2], s3[2])


@kernel
def single(n, p, s, margin):
    """A manifold of one candidate point (slot 0), the other slots empty."""
    return manifold(n, candidate(p, s, True, margin), empty(), empty(), empty())


@kernel
def invalidated(m):
    """The manifold ``m`` with no valid slot (its points kept)."""
    inf = INVALID_SEPARATION
    return m[0], m[1], (inf, inf, inf, inf), (False, False, False, False)


@kernel
def store(normal, point, separation, valid, r, m):
    """Write the manifold ``m`` into row ``r`` of the output arrays."""
    n, pts, seps, ok = m
    for c in range(3):
        normal[r, c] = n[c]
    for k in range(MAX_POINTS):
        p = pts[k]
        for c in range(3):
            point[r, k, c] = p[c]
        separation[r, k] = seps[k]
        valid[r, k] = ok[k]


@kernel
def least_separation(m):
    """The least separation of the valid slots of ``m`` (+inf without one)."""
    least = INVALID_SEPARATION
    for k in range(MAX_POINTS):
        if m[3][k] and m[2][k] < least:
            least = m[2][k]
    return least
