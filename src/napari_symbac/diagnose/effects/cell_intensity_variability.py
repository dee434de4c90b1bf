"""Cell-to-cell brightness variability (expression noise, thickness, refractive index)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry

__all__ = ["CellIntensityVariability"]


class CellIntensityVariability(Effect):
    """Each cell ``i`` has its own gain: ``mu + sum_i g_i P_c 1[near i]``.

    ``P_c`` is the cells' contribution (intensity times convolved cell component)
    and ``1[near i]`` the pixels whose nearest cell is ``i`` (within 4 px); the
    reported coefficient of variation is the s.d. of the fitted ``g_i``. In the
    settings it becomes ``RenderSettings.cell_brightness_cv``.
    """

    name = "cell_intensity_variability"
    explanation = (
        "Cells differ from each other in brightness (expression noise in fluorescence; "
        "thickness or refractive index in phase) more than the model's identical cells."
    )
    signature = "per-cell mean residuals over-dispersed relative to the pixel noise"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._ids = geometry.cell_ids
        self._masks = (
            np.stack([geometry.nearest == i for i in self._ids]).astype(np.float64)
            if len(self._ids)
            else np.zeros((0, *geometry.shape))
        )

    def n_params(self) -> int:
        return len(self._ids)

    def mean(self, theta, mu, parts, geo):
        gain = np.tensordot(theta, self._masks, axes=1) if len(theta) else 0.0
        return mu + gain * parts[0]

    def summary(self, theta, mu):
        return {
            "cv": float(np.std(theta)) if len(theta) > 1 else 0.0,
            "cell_gains": {int(i): float(1 + g) for i, g in zip(self._ids, theta)},
        }

    def magnitude(self, summary):
        return summary["cv"]
