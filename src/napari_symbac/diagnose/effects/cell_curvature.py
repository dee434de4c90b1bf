"""Cells bent along their length (eq. 1) that the model draws straight."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry, weighted_sum

__all__ = ["CellCurvature"]


def _bend_fields(geometry: Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell: bow profile ``1 - (2 s / L)^2`` and unit normal ``(n_x, n_y)`` fields."""
    ids = geometry.cell_ids
    n_t, rows, cols = geometry.shape
    bow = np.zeros((len(ids), n_t, rows, cols))
    nx = np.zeros((len(ids), n_t, 1, 1))
    ny = np.zeros((len(ids), n_t, 1, 1))
    yy, xx = np.mgrid[0:rows, 0:cols].astype(float)
    for i, cid in enumerate(ids):
        for k in range(n_t):
            inside = geometry.labels[k] == cid
            if inside.sum() < 3:
                continue
            py, px = yy[inside], xx[inside]
            cy, cx = py.mean(), px.mean()
            cov = np.cov(np.stack([px - cx, py - cy]))
            _, evecs = np.linalg.eigh(cov)
            ax, ay = evecs[:, 1]
            s = (xx - cx) * ax + (yy - cy) * ay
            half = max(np.abs((px - cx) * ax + (py - cy) * ay).max(), 1.0)
            region = geometry.nearest[k] == cid
            bow[i, k] = np.where(region, np.clip(1 - (s / half) ** 2, -1, 1), 0.0)
            nx[i, k], ny[i, k] = -ay, ax
    return bow, nx, ny


class CellCurvature(Effect):
    """Each cell's centre-line bows sideways by ``a_i`` px at its middle (eq. 1).

    First order: ``mu - (1 - I_m / I_c) sum_i a_i (1 - (2 s / L)^2) n_i . grad(C)``
    near cell ``i``, with ``C`` the cells' part of the image (eq. 3), ``s`` the
    position along the cell's axis, ``L`` its length and ``n_i`` its normal. Only the
    cell moves, and the media fills where it was (hence ``1 - I_m / I_c``); the
    gradient of the whole image ``mu`` would also move the trench walls a few pixels
    from the cells' sides, which in phase contrast carried 85-90 % of the bend's
    signal away (score-test non-centrality 11 instead of 73, the exact bend 74, on the
    0.3-s.d. benchmark trench).
    """

    name = "cell_curvature"
    explanation = (
        "Cells are bent (banana-shaped) while the model draws them straight: one side of "
        "each cell is displaced outwards in the middle, the other inwards."
    )
    signature = "opposite-signed residuals along the two long sides of cells (dipoles)"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._bow, self._nx, self._ny = _bend_fields(geometry)

    def n_params(self) -> int:
        return len(self._bow)

    def steps(self, theta):
        return np.full(len(theta), 0.05)

    def mean(self, theta, mu, parts, geo):
        if not len(theta):
            return mu
        gy, gx = np.gradient(parts[0] * (1.0 - self.geometry.media_per_cell), axis=(1, 2))
        shift_x = weighted_sum(theta, self._bow * self._nx)
        shift_y = weighted_sum(theta, self._bow * self._ny)
        return mu - shift_x * gx - shift_y * gy

    def summary(self, theta, mu):
        px = self.geometry.pixel_size_um
        return {
            "rms_bow_um": float(np.sqrt(np.mean(np.square(theta))) * px) if len(theta) else 0.0,
            "bow_um": {int(i): float(a * px) for i, a in zip(self.geometry.cell_ids, theta)},
        }

    def magnitude(self, summary):
        return summary["rms_bow_um"]
