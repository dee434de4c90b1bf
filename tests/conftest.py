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


@pytest.fixture
def cell_hyperstack(real_data_dir, tmp_path):
    """ColiCoords' single-cell crop ``01`` as Fiji's composite hyperstack (axes CYX, 80
    nm pixels, float32): ``(path, channels)``, channel 0 brightfield, 1 fluorescence."""
    import numpy as np
    import tifffile

    folder = real_data_dir / "colicoords" / "01"
    channels = np.stack(
        [tifffile.imread(folder / f"{c}.tif") for c in ("brightfield", "fluorescence")]
    ).astype(np.float32)
    path = tmp_path / "two_channels.tif"
    tifffile.imwrite(
        path, channels, imagej=True, resolution=(1 / 0.08, 1 / 0.08),
        metadata={"axes": "CYX", "unit": "um", "mode": "composite"},
    )  # fmt: skip
    return path, channels


@pytest.fixture(autouse=True, scope="session")
def _quiet_tqdm():
    # tqdm's monitor thread has given intermittent segfaults with Qt threads on CI.
    import tqdm

    tqdm.tqdm.monitor_interval = 0


def make_cells(y_um, x_um=0.7, angle_rad=0.0, length_um=3.0, width_um=1.0, ids=None):
    """A :class:`~napari_symbac.sim.FrameCells` from scalars or per-cell sequences."""
    import numpy as np

    from napari_symbac.sim import FrameCells

    y = np.atleast_1d(np.asarray(y_um, float))
    n = y.size

    def column(value):
        return np.broadcast_to(np.asarray(value, float), (n,)).copy()

    return FrameCells(
        ids=np.arange(1, n + 1, dtype=np.int64) if ids is None else np.asarray(ids, np.int64),
        x_um=column(x_um),
        y_um=y,
        angle_rad=column(angle_rad),
        length_um=column(length_um),
        width_um=column(width_um),
    )


@pytest.fixture
def cells_factory():
    """Build frames of cells by hand: ``cells_factory([2.0, 5.0], width_um=0.9)``."""
    return make_cells
