"""Shared fixtures.

The real micrographs live outside the package, in ``../shared/data/real`` beside the
checkout (GPL-2 data that must not ship). Tests that need them skip with a clear
reason in a user's clone that lacks them, and fail in CI, where they must exist.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def _real_data_dir() -> Path:
    override = os.environ.get("NAPARI_SYMBAC_REAL_DATA")
    return Path(override) if override else REPO_ROOT.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """Folder of the real micrographs (``../shared/data/real``)."""
    path = _real_data_dir()
    if not path.is_dir():
        message = (
            f"real micrographs not found at {path}: they live in ../shared/data/real beside "
            "the checkout (set NAPARI_SYMBAC_REAL_DATA to point elsewhere)"
        )
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return path


@pytest.fixture(autouse=True, scope="session")
def _quiet_tqdm():
    # tqdm's monitor thread has given intermittent segfaults with Qt threads on CI.
    import tqdm

    tqdm.tqdm.monitor_interval = 0
