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
