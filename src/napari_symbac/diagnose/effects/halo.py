"""Phase-contrast halo (shade-off) stronger or weaker than modelled."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect, gaussian
from napari_symbac.diagnose.model import Geometry
from napari_symbac.optics.forward import Stage, block_average

__all__ = ["Halo"]

#: Inner and outer widths (um) of the difference-of-Gaussians ring.
INNER_UM, OUTER_UM = 0.1, 0.35


def halo_ring(cell_fraction: np.ndarray, pixel_size_um: float) -> np.ndarray:
    """Unit-peak ring around the cells: ``G_outer * F - G_inner * F`` (``(T, Y, X)``)."""
    ring = gaussian(cell_fraction, OUTER_UM / pixel_size_um) - gaussian(
        cell_fraction, INNER_UM / pixel_size_um
    )
    peak = float(np.abs(ring).max())
    return ring / peak if peak > 0 else ring


class Halo(Effect):
    """A bright ring just outside every cell and a darker rim inside: ``mu + a R``.

    ``R`` is a difference of Gaussians (0.1 and 0.35 um) of the cell mask, scaled to
    a peak of 1, and ``a`` its amplitude in ADU: the part of the phase ring's halo
    (eq. 10-13) that the fitted ring contrast and apodisation did not capture.
    """

    name = "halo"
    explanation = (
        "The bright halo that phase contrast draws around each cell is stronger (or weaker) "
        "than the model's phase ring gives: a thin bright band outside the cell edge and a "
        "dark rim inside it."
    )
    signature = "mean residual against signed distance to the nearest cell edge (ring at 0-4 px)"
    modalities = ("phase",)

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._ring = halo_ring(geometry.cell_fraction, geometry.pixel_size_um)

    def n_params(self) -> int:
        return 1

    def steps(self, theta):
        return np.ones(1)

    def mean(self, theta, mu, parts, geo):
        return mu + theta[0] * self._ring

    def summary(self, theta, mu):
        return {"amplitude_adu": float(theta[0])}


def stage(parameters: dict) -> Stage:
    """Forward-model stage adding the fitted ring around the scene's cells."""
    amplitude = float(parameters["amplitude_adu"])

    def apply(image: np.ndarray, scene) -> np.ndarray:
        fraction = block_average(scene.interior(scene.cells), scene.upsample)[None]
        px = scene.pixel_size_um * scene.upsample
        return image + np.float32(amplitude) * halo_ring(fraction, px)[0].astype(np.float32)

    return Stage(Halo.name, False, dict(parameters), apply)
