"""Fixtures shared by the engine tests."""

from __future__ import annotations

import pytest

from engine.core.jit import get_threads, set_threads


@pytest.fixture
def restore_threads():
    """The thread count as it was before the test."""
    before = get_threads()
    yield
    set_threads(before)
