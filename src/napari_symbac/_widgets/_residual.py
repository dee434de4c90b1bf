"""Residual layers: the image minus the model in blue-white-red, white at 0, with its
colour bar, as the commands' residuals.png draws them (found as a user: the layers were
PiYG with no legend of which colour was "image brighter", and Auto-fit's residual took
napari's min-max limits, so its white was not 0)."""

from __future__ import annotations

import numpy as np

RESIDUAL_COLORMAP = "bwr"  # figure_layout.diverging's colours
#: What the colours mean, for status lines and reports.
RESIDUAL_LEGEND = "red where the image is brighter than the model, blue where darker"


def symmetric_limits(data, floor: float = 0.0) -> tuple[float, float]:
    """``(-L, L)`` with ``L`` the 99th percentile of ``|data|`` (finite values; censored
    pixels may be NaN), at least ``floor``."""
    magnitude = np.abs(np.asarray(data, float))
    magnitude = magnitude[np.isfinite(magnitude)]
    limit = float(np.percentile(magnitude, 99)) if magnitude.size else 0.0
    limit = max(limit, floor, 1e-12)
    return (-limit, limit)


def add_residual_layer(viewer, data, *, name: str, limits=None, **kwargs):
    """Add ``data`` (image minus model) as a residual layer: white at 0, its colour
    bar shown while the layer is. ``limits`` defaults to :func:`symmetric_limits`."""
    layer = viewer.add_image(
        data,
        name=name,
        colormap=RESIDUAL_COLORMAP,
        contrast_limits=symmetric_limits(data) if limits is None else limits,
        **kwargs,
    )
    layer.colorbar.visible = True
    return layer
