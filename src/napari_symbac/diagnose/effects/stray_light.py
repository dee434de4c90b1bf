"""Stray light / haze spreading from the cells over microns."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import CellPatternEffect, gaussian
from napari_symbac.optics.forward import Stage

__all__ = ["StrayLight"]

#: Width (Gaussian s.d., um) of the stray-light kernel: far wider than the PSF.
WIDTH_UM = 1.5


def haze(cell_fraction: np.ndarray, pixel_size_um: float) -> np.ndarray:
    """The cell mask blurred over :data:`WIDTH_UM`: the share of each pixel's
    surroundings (a Gaussian of that s.d.) that is cell, 1 where cells fill them (0.26
    at the middle of a trench filled by 1 um wide cells, 0.18 at the centre of one
    1 x 3 um cell alone)."""
    return gaussian(cell_fraction, WIDTH_UM / pixel_size_um)


class StrayLight(CellPatternEffect):
    """Light scattered by the cells over microns: ``mu + s G_L * F`` (``L`` = 1.5 um).

    ``F`` is the cell mask, ``G_L * F`` the share of each pixel's surroundings that
    is cell (:func:`haze`), ``s`` in ADU where cells fill them (negative: the cells
    shadow their surroundings).
    """

    name = "stray_light"
    explanation = (
        "Light scattered by the cells (or out-of-focus glow in fluorescence) spreads a "
        "faint haze over several microns around them, so crowded places look brighter "
        "(or darker) than empty ones."
    )
    signature = "residual against distance to the nearest cell, long tail beyond 1 um"
    sign_words = (
        "a haze brightening the microns around the cells",
        "the cells darken the microns around them (less light there than modelled)",
    )

    pattern = staticmethod(haze)
    amplitude_at = "where cells fill the surroundings"


def stage(parameters: dict) -> Stage:
    """Forward-model stage of the fitted effect (:meth:`CellPatternEffect.stage`)."""
    return StrayLight.stage(parameters)
