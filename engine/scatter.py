"""Scatter-add over the body axis: ``out[:, t[i]] += v[:, i]`` for a fixed
list of targets t, in position order (as ``np.add.at`` sums), but in a few
indexed adds on large batches, where ``np.add.at`` costs several times more.
Used by the joint tree's solve and the joints' warm start;
``occurrence_rank`` also by the static contact projection's moves."""

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
        rank = occurrence_rank(self.targets)  # the k-th occurrence of a target goes to part k
        parts = [np.flatnonzero(rank == k) for k in range(int(rank.max()) + 1 if rank.size else 0)]
        self.parts = [(sel, self.targets[sel]) for sel in parts]


def occurrence_rank(keys):
    """(n,) int64: for each position i, how many earlier positions hold the
    same key (0 for a key's first occurrence). Positions of one rank have
    distinct keys, so an indexed update per rank, in rank order, touches each
    key once per pass and in position order."""
    keys = np.asarray(keys)
    order = np.argsort(keys, kind="stable")  # each key's positions together, in position order
    sorted_keys = keys[order]
    first = np.r_[True, sorted_keys[1:] != sorted_keys[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(keys.size), 0))
    rank = np.empty(keys.size, dtype=np.int64)
    rank[order] = np.arange(keys.size) - start
    return rank


def scatter_add(out, scatter, v):
    """out[:, t[i]] += v[:, i] for every position i of ``scatter`` (a ``Scatter``)."""
    if v.size < SCATTER_ADD_AT_PER_PART * len(scatter.parts):
        np.add.at(out, (slice(None), scatter.targets), v)
        return
    for sel, tgt in scatter.parts:
        out[:, tgt] += v.take(sel, 1)
