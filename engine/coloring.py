"""Greedy graph colouring of constraints so that no body appears twice in a colour.

Within one colour the constraints touch disjoint bodies, so one colour is one
sweep over worlds × constraints with no write conflicts: a Gauss-Seidel solve
becomes a sequence of conflict-free sweeps, as in Box2D v3's graph colouring
(``src/constraint_graph.c``). Static bodies do not count: they never move, so
many constraints may share one.

``color_pairs`` colours the joints and springs once, when a model is built;
the contact rows of each step are coloured world by world by the kernel
:func:`engine.core.contacts.color_in_order`, which ``color_rows`` calls on
rows of any keys.
"""

from __future__ import annotations

import numpy as np

from .core.contacts import color_in_order


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


def color_rows(key_a, key_b, dyn_a, dyn_b, num_keys, priority, first_fit=False) -> list[np.ndarray]:
    """Colouring of rows (contact manifolds) by their keys.

    key_a, key_b: (K,) keys of each row's two bodies (world × bodies + body);
    dyn_a, dyn_b: (K,) whether that body moves (static keys are shared freely);
    num_keys: keys range over [0, num_keys);
    priority: (K,) integers, distinct among the rows that share a dynamic key.
    Returns index arrays, one per colour, in colour order, rows ascending.

    The rounds of Jones and Plassmann (1993): each round takes the rows whose
    priority is the lowest left at each of their dynamic keys; no two of
    them share a body (:func:`engine.core.contacts.color_in_order`).

    * ``first_fit=False``: each round is a colour. Sweeping the colours in
      order is then the same as sweeping the rows one after another in
      priority order (a Gauss-Seidel sweep in that order, parallel only where
      rows are independent): a chain of n rows, each sharing a body with
      the next, takes n colours.
    * ``first_fit=True``: each row of a round takes the lowest colour not yet
      used at its keys: at most Δ + 1 colours (Δ: the most rows a row shares
      a body with) whatever the order, as in Box2D v3's greedy graph
      colouring; a stack of n boxes takes 2.
    """
    K = np.size(key_a)
    if K == 0:
        return []
    color = np.empty(K, dtype=np.int64)
    seq = np.argsort(np.asarray(priority), kind="stable").astype(np.int64)
    color_in_order(seq, np.asarray(key_a, dtype=np.int64), np.asarray(key_b, dtype=np.int64),
                   np.asarray(dyn_a, dtype=bool), np.asarray(dyn_b, dtype=bool), int(num_keys), bool(first_fit), color)
    order = np.argsort(color, kind="stable")
    bounds = np.searchsorted(color[order], np.arange(int(color.max()) + 2))
    return [order[bounds[i]:bounds[i + 1]] for i in range(bounds.size - 1)]
