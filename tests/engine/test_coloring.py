"""Graph colouring of constraints: every colour touches each moving body at
most once, every constraint is coloured once, and greedy first fit keeps the
colour count at most Δ + 1."""

import numpy as np
import pytest

from engine.coloring import color_pairs, color_rows


def _check_colouring(colors, key_a, key_b, dyn_a, dyn_b):
    rows = np.concatenate(colors)
    assert np.array_equal(np.sort(rows), np.arange(key_a.size)), "every row coloured exactly once"
    for c in colors:
        keys = np.concatenate((key_a[c][dyn_a[c]], key_b[c][dyn_b[c]]))
        assert np.unique(keys).size == keys.size, "a moving body twice in one colour"
        assert np.all(np.diff(c) > 0), "rows ascending within a colour"


def _max_degree(key_a, key_b, dyn_a, dyn_b):
    """Δ: the most other rows a row shares a moving body with."""
    count = np.bincount(np.concatenate((key_a[dyn_a], key_b[dyn_b])))
    return int(max(count[key_a] * dyn_a + count[key_b] * dyn_b - dyn_a - dyn_b))


def test_stack_first_fit_takes_two_colours_ordered_one_per_row():
    # Ground (key 0, static) under boxes 1..n; row i joins key i and key i + 1.
    n = 20
    key_a = np.arange(n)
    key_b = np.arange(1, n + 1)
    dyn_a = key_a > 0
    dyn_b = np.ones(n, dtype=bool)
    greedy = color_rows(key_a, key_b, dyn_a, dyn_b, n + 1, np.arange(n), first_fit=True)
    _check_colouring(greedy, key_a, key_b, dyn_a, dyn_b)
    assert len(greedy) == 2
    # Ordered, top down (priority: highest row first): a colour per row, swept
    # in priority order, as a sequential Gauss-Seidel sweep would take them.
    ordered = color_rows(key_a, key_b, dyn_a, dyn_b, n + 1, np.arange(n)[::-1].copy())
    _check_colouring(ordered, key_a, key_b, dyn_a, dyn_b)
    assert [c.tolist() for c in ordered] == [[i] for i in range(n - 1, -1, -1)]


@pytest.mark.parametrize("seed", range(5))
def test_random_rows_first_fit_bound(seed):
    rng = np.random.default_rng(seed)
    worlds, bodies, per_world = 3, 30, 80
    a = rng.integers(0, bodies, (worlds, per_world))
    b = (a + rng.integers(1, bodies, (worlds, per_world))) % bodies
    key_a = (np.arange(worlds)[:, None] * bodies + a).ravel()
    key_b = (np.arange(worlds)[:, None] * bodies + b).ravel()
    static = np.zeros(worlds * bodies, dtype=bool)
    static[::bodies] = True  # body 0 of each world is static: shared freely
    dyn_a, dyn_b = ~static[key_a], ~static[key_b]
    priority = rng.permutation(key_a.size)
    colors = color_rows(key_a, key_b, dyn_a, dyn_b, worlds * bodies, priority, first_fit=True)
    _check_colouring(colors, key_a, key_b, dyn_a, dyn_b)
    assert len(colors) <= _max_degree(key_a, key_b, dyn_a, dyn_b) + 1
    _check_colouring(color_rows(key_a, key_b, dyn_a, dyn_b, worlds * bodies, priority), key_a, key_b, dyn_a, dyn_b)


def test_rows_on_static_bodies_share_a_colour():
    key_a = np.zeros(6, dtype=np.int64)  # all on the static ground
    key_b = np.arange(1, 7)
    for first_fit in (False, True):
        colors = color_rows(key_a, key_b, np.zeros(6, bool), np.ones(6, bool), 7, np.arange(6), first_fit)
        assert len(colors) == 1 and colors[0].size == 6


def test_no_rows():
    empty = np.zeros(0, dtype=np.int64)
    assert color_rows(empty, empty, empty.astype(bool), empty.astype(bool), 4, empty) == []


def test_color_pairs_keeps_bodies_apart():
    a = np.array([0, 1, 2, 0, 3])
    b = np.array([1, 2, 3, 2, 4])
    dynamic = np.array([False, True, True, True, True])
    colors = color_pairs(a, b, dynamic)
    _check_colouring(colors, a, b, dynamic[a], dynamic[b])


def _rounds_reference(key_a, key_b, dyn_a, dyn_b, priority, first_fit):
    """Jones and Plassmann's rounds taken literally: each round claims every
    key for the lowest priority left at it and colours the rows that won all
    their moving keys (a round per colour, or first fit within the round)."""
    K = key_a.size
    color = np.full(K, -1)
    used = {}
    rounds = 0
    while (color < 0).any():
        rem = np.flatnonzero(color < 0)
        claim = {}
        for r in rem:
            for k, d in ((key_a[r], dyn_a[r]), (key_b[r], dyn_b[r])):
                if d:
                    claim[k] = min(claim.get(k, priority[r]), priority[r])
        won = [r for r in rem if all(not d or claim[k] == priority[r]
                                     for k, d in ((key_a[r], dyn_a[r]), (key_b[r], dyn_b[r])))]
        for r in won:
            if first_fit:
                keys = [k for k, d in ((key_a[r], dyn_a[r]), (key_b[r], dyn_b[r])) if d]
                c = 0
                while any(c in used.get(k, ()) for k in keys):
                    c += 1
                for k in keys:
                    used.setdefault(k, set()).add(c)
                color[r] = c
            else:
                color[r] = rounds
        rounds += 1
    return [np.flatnonzero(color == c) for c in range(color.max() + 1)]


@pytest.mark.parametrize("first_fit", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_the_colouring_in_priority_order_is_jones_plassmanns_rounds(seed, first_fit):
    # The kernel takes the rows once in priority order (a row's round: one
    # more than the latest at its keys); the rounds taken one by one give the
    # same colours.
    rng = np.random.default_rng(seed)
    n, keys = 60, 25
    key_a = rng.integers(0, keys, n)
    key_b = (key_a + rng.integers(1, keys, n)) % keys
    dyn = rng.random(keys) > 0.15
    priority = rng.permutation(n)
    got = color_rows(key_a, key_b, dyn[key_a], dyn[key_b], keys, priority, first_fit)
    want = _rounds_reference(key_a, key_b, dyn[key_a], dyn[key_b], priority, first_fit)
    assert [c.tolist() for c in got] == [c.tolist() for c in want]
