"""Stray light / haze spreading from the cells over microns."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect, gaussian
from napari_symbac.diagnose.model import Geometry
from napari_symbac.optics.forward import Stage, block_average

__all__ = ["StrayLight"]

#: Width (Gaussian s.d., um) of the stray-light kernel: far wider than the PSF.
WIDTH_UM = 1.5


def haze(cell_fraction: np.ndarray, pixel_size_um: float) -> np.ndarray:
    """The cell mask blurred over :data:`WIDTH_UM`, scaled to a peak of 1."""
    field = gaussian(cell_fraction, WIDTH_UM / pixel_size_um)
    peak = float(field.max())
    return field / peak if peak > 0 else field


class StrayLight(Effect):
    """Light scattered by the cells over microns: ``mu + s G_L * F`` (``L`` = 1.5 um).

    ``F`` is the cell mask, the blurred mask scaled to peak 1, ``s`` in ADU (negative:
    the cells shadow their surroundings).
    """

    name = "stray_light"
    explanation = (
        "Light scattered by the cells (or out-of-focus glow in fluorescence) spreads a "
        "faint haze over several microns around them, so crowded places look brighter "
        "(or darker) than empty ones."
    )
    signature = "residual against distance to the nearest cell, long tail beyond 1 um"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._haze = haze(geometry.cell_fraction, geometry.pixel_size_um)

    def n_params(self) -> int:
        return 1

    def steps(self, theta):
        return np.ones(1)

    def mean(self, theta, mu, parts, geo):
        return mu + theta[0] * self._haze

    def summary(self, theta, mu):
        return {"amplitude_adu": float(theta[0])}


def stage(parameters: dict) -> Stage:
    """Forward-model stage adding the fitted haze around the scene's cells."""
    amplitude = float(parameters["amplitude_adu"])

    def apply(image: np.ndarray, scene) -> np.ndarray:
        fraction = block_average(scene.interior(scene.cells), scene.upsample)[None]
        px = scene.pixel_size_um * scene.upsample
        return image + np.float32(amplitude) * haze(fraction, px)[0].astype(np.float32)

    return Stage(StrayLight.name, False, dict(parameters), apply)
