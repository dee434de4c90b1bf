"""Cell-to-cell brightness variability (expression noise, thickness, refractive index)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry, weighted_sum

__all__ = ["CellIntensityVariability"]


class CellIntensityVariability(Effect):
    """Each cell ``i`` has its own gain: ``mu + sum_i g_i I_c C_i``.

    ``C_i`` is cell ``i``'s own convolved component (eq. 3 for that cell alone,
    :attr:`Geometry.cell_components`) and ``I_c`` the fitted cell intensity, so the
    gain scales exactly the image the cell makes, halo and all, also where it
    overlaps its neighbours' images. Without per-cell components (a geometry from
    labels alone) ``C_i`` falls back to the cells' component on the pixels whose
    nearest cell is ``i`` (within 4 px). The reported coefficient of variation is the
    s.d. of the fitted ``g_i``. In the settings it becomes
    ``RenderSettings.cell_brightness_cv``.

    The gains are a random field (:attr:`Effect.random_field`): each cell's gain a
    draw from the population, fitted by empirical Bayes (the free fit shrunk by
    ``1 - k / |z|^2``), the CV reported from the free fit times the square root of
    the shrinkage.
    """

    name = "cell_intensity_variability"
    random_field = True
    explanation = (
        "Cells differ from each other in brightness (expression noise in fluorescence; "
        "thickness or refractive index in phase) more than the model's identical cells."
    )
    signature = "per-cell mean residuals over-dispersed relative to the pixel noise"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._ids = geometry.cell_ids
        self._own = geometry.cell_components
        if self._own is not None:
            total = self._own.sum(axis=0)
            # where the cells' part is largest: I_c = parts[0] / C there (exact, eq. 3)
            self._probe = int(np.argmax(np.abs(total)))
            self._probe_value = float(total.ravel()[self._probe])
        self._masks = (
            np.stack([geometry.nearest == i for i in self._ids]).astype(np.float64)
            if len(self._ids) and self._own is None
            else np.zeros((0, *geometry.shape))
        )

    def n_params(self) -> int:
        """One gain per cell; none for a single cell, whose gain is the fitted cell
        intensity's own (found as a user: a 96-row window of one cell accepted this
        effect at a CV of 0, which its settings then drew as nothing)."""
        return len(self._ids) if len(self._ids) >= 2 else 0

    def mean(self, theta, mu, parts, geo):
        if not len(theta):
            return mu
        if self._own is not None:
            if self._probe_value == 0:
                return mu
            intensity = parts[0].ravel()[self._probe] / self._probe_value
            return mu + intensity * weighted_sum(theta, self._own)
        return mu + weighted_sum(theta, self._masks) * parts[0]

    def summary(self, theta, mu):
        return {
            "cv": float(np.std(theta)) if len(theta) > 1 else 0.0,
            "cell_gains": {int(i): float(1 + g) for i, g in zip(self._ids, theta)},
        }

    def magnitude(self, summary):
        return summary["cv"]
