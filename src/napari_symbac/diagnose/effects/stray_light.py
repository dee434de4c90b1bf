"""Stray light / haze spreading from the cells over microns."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import CellPatternEffect, gaussian
from napari_symbac.optics.forward import Stage

__all__ = ["StrayLight"]

#: Width (Gaussian s.d., um) of the stray-light kernel: far wider than the PSF.
WIDTH_UM = 1.5


def haze(cell_fraction: np.ndarray, pixel_size_um: float) -> np.ndarray:
    """The cell mask blurred over :data:`WIDTH_UM`, scaled to a peak of 1."""
    field = gaussian(cell_fraction, WIDTH_UM / pixel_size_um)
    peak = float(field.max())
    return field / peak if peak > 0 else field


class StrayLight(CellPatternEffect):
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
    sign_words = (
        "a haze brightening the microns around the cells",
        "the cells darken the microns around them (less light there than modelled)",
    )

    pattern = staticmethod(haze)


def stage(parameters: dict) -> Stage:
    """Forward-model stage of the fitted effect (:meth:`CellPatternEffect.stage`)."""
    return StrayLight.stage(parameters)
