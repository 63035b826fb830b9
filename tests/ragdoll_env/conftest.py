"""Fixtures of the environment tests."""

import warnings

import pytest


@pytest.fixture(autouse=True)
def _no_contact_warning_noise():
    """Balance warns once that the engine has no contacts yet; keep test output clean."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no contact model yet.*")
        yield
