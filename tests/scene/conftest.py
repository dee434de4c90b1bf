from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest


@dataclass(frozen=True)
class Cells:
    """Stand-in for the simulator's FrameCells (duck-typed)."""

    ids: np.ndarray
    x_um: np.ndarray
    y_um: np.ndarray
    angle_rad: np.ndarray
    length_um: np.ndarray
    width_um: np.ndarray


def make_cells(y_um, x_um=0.7, angle_rad=0.0, length_um=3.0, width_um=1.0, ids=None) -> Cells:
    y = np.atleast_1d(np.asarray(y_um, float))
    n = y.size

    def col(v):
        return np.broadcast_to(np.asarray(v, float), (n,)).copy()

    return Cells(
        ids=np.arange(1, n + 1, dtype=np.int64) if ids is None else np.asarray(ids, np.int64),
        x_um=col(x_um),
        y_um=y,
        angle_rad=col(angle_rad),
        length_um=col(length_um),
        width_um=col(width_um),
    )


@pytest.fixture
def cells_factory():
    return make_cells
