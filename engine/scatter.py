"""Scatter-add over the body axis: ``out[:, t[i]] += v[:, i]`` for a fixed
list of targets t, in position order (as ``np.add.at`` sums), but in a few
indexed adds on large batches, where ``np.add.at`` costs several times more.
Used by the joint tree's solve and the joints' warm start and motor torques."""

from __future__ import annotations

import numpy as np


#: Below this many elements of v per part, ``scatter_add`` takes one
#: np.add.at (about 1.5 µs + 7 ns an element) instead of one indexed add per
#: part (about 3 µs a part): 3x faster on one world's 6x6 blocks, 2-3x slower
#: on 32 worlds' (numpy 2.4, this machine).
SCATTER_ADD_AT_PER_PART = 400


class Scatter:
    """Positions 0..len-1 of ``targets`` split into parts whose targets are
    unique, so that ``out[:, t[sel]] += v[:, sel]`` per part adds each
    target's terms in position order, as np.add.at does: the same sums, the
    same bits, whichever ``scatter_add`` takes."""

    def __init__(self, targets):
        self.targets = np.asarray(targets, dtype=np.int64)
        parts, count = [], {}
        for i, t in enumerate(self.targets.tolist()):
            k = count.get(t, 0)  # the k-th occurrence of t goes to part k
            count[t] = k + 1
            if k == len(parts):
                parts.append([])
            parts[k].append(i)
        self.parts = [(np.array(sel, dtype=np.int64), self.targets[sel]) for sel in parts]


def scatter_add(out, scatter, v):
    """out[:, t[i]] += v[:, i] for every position i of ``scatter`` (a ``Scatter``)."""
    if v.size < SCATTER_ADD_AT_PER_PART * len(scatter.parts):
        np.add.at(out, (slice(None), scatter.targets), v)
        return
    for sel, tgt in scatter.parts:
        out[:, tgt] += v.take(sel, 1)
