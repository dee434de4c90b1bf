"""Phase-contrast halo (shade-off) stronger or weaker than modelled."""

from __future__ import annotations

import math

import numpy as np

from napari_symbac.diagnose.effects.base import CellPatternEffect, gaussian
from napari_symbac.optics.forward import Stage

__all__ = ["Halo"]

#: Inner and outer widths (um) of the difference-of-Gaussians ring.
INNER_UM, OUTER_UM = 0.1, 0.35


def _edge_peak(inner: float, outer: float) -> float:
    """The ring across a straight edge, ``Phi(d / outer) - Phi(d / inner)``, at the
    distance ``d`` from it where the two Gaussians' slopes are equal (its extreme)."""
    d = math.sqrt(2 * math.log(outer / inner) / (1 / inner**2 - 1 / outer**2))
    return 0.5 * (math.erf(d / (outer * math.sqrt(2))) - math.erf(d / (inner * math.sqrt(2))))


#: The ring's extreme across a straight edge (:func:`_edge_peak`): 0.269, positive
#: just outside the edge and negative just inside.
EDGE_PEAK = abs(_edge_peak(INNER_UM, OUTER_UM))


def halo_ring(cell_fraction: np.ndarray, pixel_size_um: float) -> np.ndarray:
    """Ring around the cells, ``(G_outer * F - G_inner * F) / EDGE_PEAK`` (``(T, Y,
    X)``): 1 at its bright band beside a straight cell edge (a rod's side), -1.68 at
    the middle of a 1 um wide cell."""
    ring = gaussian(cell_fraction, OUTER_UM / pixel_size_um) - gaussian(
        cell_fraction, INNER_UM / pixel_size_um
    )
    return ring / EDGE_PEAK


class Halo(CellPatternEffect):
    """A bright ring just outside every cell and a darker rim inside: ``mu + a R``.

    ``R`` is a difference of Gaussians (0.1 and 0.35 um) of the cell mask, 1 at its
    peak beside a straight edge (:func:`halo_ring`), and ``a`` its amplitude in ADU:
    the part of the phase ring's halo (eq. 10-13) that the fitted ring contrast and
    apodisation did not capture.
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
    amplitude_at = "beside a straight cell edge"


def stage(parameters: dict) -> Stage:
    """Forward-model stage of the fitted effect (:meth:`CellPatternEffect.stage`)."""
    return Halo.stage(parameters)
