"""Fixtures of the fit tests: a trench rendered by the project's own model."""

from __future__ import annotations

import pytest
from _fit_synthetic import Truth, make_truth


@pytest.fixture(scope="session")
def truth() -> Truth:
    """Three cells in a 128 x 46 crop with known parameters (see ``_fit_synthetic``)."""
    return make_truth()
