"""Test ordering shared by every test directory.

The slow selection is dominated by a few long runs; they are collected first so
that with two workers (``python -m pytest -q -m slow -n 2 --dist loadgroup``)
the 100,000-step run and the 1,000-world soak start at once on different
workers, and the shorter ones fill in around them instead of the longest
starting last. The soak's two tests form one xdist group (``test_soak.py``):
they share one soak, computed once on their worker.
"""

from __future__ import annotations

#: Test functions started first, longest first (wall times measured here with two
#: workers on a shared machine: the 100,000-step maximum-torque ragdoll 39 min, the
#: 1,000-world soak tests 10 min each, the full 10-row pyramids 5.5 min each).
LONGEST_FIRST = (
    "test_max_torque_100k_steps",
    "test_soak_replay_bit_identical",
    "test_soak_1000_worlds_1000_steps",
    "test_hard_case_full[pyramid_10]",
    "test_hard_case_full[pyramid_10_far]",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    # A stable sort: every other test keeps its collection order.
    items.sort(key=lambda item: rank.get(item.name, len(rank)))
