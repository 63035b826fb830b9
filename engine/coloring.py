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


def color_rows(key_a, key_b, dyn_a, dyn_b, num_keys, priority, first_fit=False) -> list[np.ndarray]:
    """Vectorised colouring of rows (contact manifolds) by their keys.

    key_a, key_b: (K,) keys of each row's two bodies (world × bodies + body);
    dyn_a, dyn_b: (K,) whether that body moves (static keys are shared freely);
    num_keys: keys range over [0, num_keys);
    priority: (K,) integers, distinct among the rows that share a dynamic key.
    Returns index arrays, one per colour, in colour order, rows ascending.

    In rounds (Jones and Plassmann 1993): each round takes the rows whose
    priority is the lowest left at each of their dynamic keys; no two of
    them share a body.

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
    K = key_a.size
    if K == 0:
        return []
    color = np.full(K, -1, dtype=np.int64)
    if first_fit:
        used = np.zeros((num_keys, 8), dtype=bool)  # used[key, c]: colour c has a row at key
    rounds = 0
    rem = np.arange(K)
    unclaimed = np.iinfo(np.int64).max
    while rem.size:
        ka, kb, da, db, pr = key_a[rem], key_b[rem], dyn_a[rem], dyn_b[rem], priority[rem]
        claim = np.full(num_keys, unclaimed, dtype=np.int64)
        np.minimum.at(claim, ka[da], pr[da])
        np.minimum.at(claim, kb[db], pr[db])
        ok = (~da | (claim[ka] == pr)) & (~db | (claim[kb] == pr))
        if first_fit:
            ka, kb, da, db = ka[ok], kb[ok], da[ok], db[ok]
            taken = (used[ka] & da[:, None]) | (used[kb] & db[:, None])
            if taken.all(axis=1).any():
                used = np.concatenate((used, np.zeros_like(used)), axis=1)
                taken = np.concatenate((taken, np.zeros_like(taken)), axis=1)
            c = np.argmin(taken, axis=1)  # the first colour free at both keys
            used[ka[da], c[da]] = True
            used[kb[db], c[db]] = True
            color[rem[ok]] = c
        else:
            color[rem[ok]] = rounds
        rounds += 1
        rem = rem[~ok]
    count = int(color.max()) + 1
    order = np.argsort(color, kind="stable")
    bounds = np.searchsorted(color[order], np.arange(count + 1))
    return [order[bounds[i]:bounds[i + 1]] for i in range(count)]
