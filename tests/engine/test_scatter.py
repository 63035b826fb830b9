"""engine.scatter: the ordered scatter-add sums each target's terms in
position order, as np.add.at does, bit for bit, whichever way it takes."""

import numpy as np
import pytest

import engine.scatter as scatter_module
from engine.scatter import Scatter, occurrence_rank, scatter_add


def _terms(rng, W, n):
    v = rng.normal(size=(W, n, 3)) * 10.0 ** rng.integers(-8, 8, size=(W, n, 1))
    v[0, 0, 0] = -0.0
    v[0, 1, 1] = np.nan
    v[-1, -1, 2] = np.inf
    return v


def test_parts_hold_each_target_once_in_position_order():
    targets = [3, 1, 3, 3, 0, 1, 2, 3]
    parts = Scatter(targets).parts
    # The k-th occurrence of a target is in part k.
    assert [sel.tolist() for sel, _ in parts] == [[0, 1, 4, 6], [2, 5], [3], [7]]
    for sel, tgt in parts:
        assert len(set(tgt.tolist())) == tgt.size
        assert tgt.tolist() == [targets[i] for i in sel]


def test_occurrence_rank_counts_earlier_positions_with_the_same_key():
    assert occurrence_rank([3, 1, 3, 3, 0, 1, 2, 3]).tolist() == [0, 0, 1, 2, 0, 1, 0, 3]
    assert occurrence_rank(np.zeros(0, dtype=np.int64)).size == 0
    assert Scatter([]).parts == []


@pytest.mark.parametrize("per_part", [0, 10 ** 9], ids=["indexed adds", "np.add.at"])
@pytest.mark.parametrize("W", [1, 7])
def test_scatter_add_gives_np_add_at_bits(monkeypatch, per_part, W):
    monkeypatch.setattr(scatter_module, "SCATTER_ADD_AT_PER_PART", per_part)
    rng = np.random.default_rng(W)
    targets = rng.integers(0, 5, size=40)
    v = _terms(rng, W, targets.size)
    start = rng.normal(size=(W, 5, 3))
    start[..., 0] = 0.0  # +0.0 plus -0.0 terms: the sign of zero must come out as np.add.at's
    expected = start.copy()
    np.add.at(expected, (slice(None), targets), v)
    out = start.copy()
    scatter_add(out, Scatter(targets), v)
    assert out.tobytes() == expected.tobytes()
