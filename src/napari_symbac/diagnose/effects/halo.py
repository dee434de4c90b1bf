"""Phase-contrast halo (shade-off) stronger or weaker than modelled."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import CellPatternEffect, gaussian
from napari_symbac.optics.forward import Stage

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


class Halo(CellPatternEffect):
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
    sign_words = (
        "a stronger halo than the model's: brighter just outside the cells, darker rims",
        "a weaker halo than the model's: dimmer just outside the cells, lighter rims",
    )

    pattern = staticmethod(halo_ring)


def stage(parameters: dict) -> Stage:
    """Forward-model stage of the fitted effect (:meth:`CellPatternEffect.stage`)."""
    return Halo.stage(parameters)
