"""Scatter-add over the body axis: ``out[:, t[i]] += v[:, i]`` for a fixed
list of targets t, in position order (as ``np.add.at`` sums), but in a few
indexed adds on large batches, where ``np.add.at`` costs several times more.
Used wherever rows (joints, contacts) hand impulses to their bodies."""

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
        self.targets = np.asarray(targets)
        parts, seen = [], []
        for i, t in enumerate(self.targets.tolist()):
            for k, used in enumerate(seen):
                if t not in used:
                    used.add(t)
                    parts[k].append(i)
                    break
            else:
                seen.append({t})
                parts.append([i])
        self.parts = [(np.array(sel), self.targets[sel]) for sel in parts]


def scatter_add(out, scatter, v):
    """out[:, t[i]] += v[:, i] for every position i of ``scatter`` (a ``Scatter``)."""
    if v.size < SCATTER_ADD_AT_PER_PART * len(scatter.parts):
        np.add.at(out, (slice(None), scatter.targets), v)
        return
    for sel, tgt in scatter.parts:
        out[:, tgt] += v.take(sel, 1)
