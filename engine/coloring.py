"""Greedy graph colouring of constraints so that no body appears twice in a colour.

Within one colour the constraints touch disjoint bodies, so one colour is one
vectorised sweep over worlds × constraints with no write conflicts: a
Gauss-Seidel solve becomes a sequence of Jacobi-free parallel sweeps, as in
Box2D v3's graph colouring (``src/constraint_graph.c``). Static bodies do not
count: they never move, so many constraints may share one.
"""

from __future__ import annotations

import numpy as np


def color_pairs(body_a, body_b, dynamic) -> list[np.ndarray]:
    """Split constraint indices into colours.

    body_a, body_b: (C,) body indices of each constraint's two bodies.
    dynamic: (N,) bool, False for static bodies (shared freely).
    Returns a list of index arrays, one per colour, in constraint order.
    """
    body_a = np.asarray(body_a, dtype=np.int64)
    body_b = np.asarray(body_b, dtype=np.int64)
    colors: list[list[int]] = []
    used: list[set[int]] = []
    for c, (a, b) in enumerate(zip(body_a, body_b)):
        need = {int(x) for x in (a, b) if dynamic[x]}
        for k, bodies in enumerate(used):
            if not (need & bodies):
                colors[k].append(c)
                bodies |= need
                break
        else:
            colors.append([c])
            used.append(set(need))
    return [np.array(c, dtype=np.int64) for c in colors]
