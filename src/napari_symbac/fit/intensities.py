"""Intensity statistics of cells, media and device from rough labels (eq. 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from napari_symbac.fit.inputs import CLASS_VALUES, as_image_stack, as_label_stack

__all__ = ["ClassStatistics", "class_statistics"]


@dataclass(frozen=True)
class ClassStatistics:
    """Mean, variance and pixel count of one painted class."""

    mean: float
    variance: float
    n_pixels: int


def class_statistics(
    image: np.ndarray,
    labels: np.ndarray,
    *,
    required: tuple[str, ...] = ("cell", "media", "device"),
) -> dict[str, ClassStatistics]:
    """Mean and variance of the real image inside each painted class (eq. 2).

    Eq. 2 of the supplement writes ``I_c = (1 / MN) sum(Y * c)``; as its text says, the
    quantity wanted is the *mean intensity of the class*, so the sum is divided by the
    number of painted pixels ``sum(c)`` rather than by the image size ``MN``.

    Parameters
    ----------
    image
        2D image or ``(T, Y, X)`` time series, any integer or float dtype.
    labels
        Class map of the same shape (or 2D for every frame): 1 = cell, 2 = media,
        3 = device, 0 = unpainted. Rough, sparse strokes are enough.
    required
        Classes that must be present; the mother-machine device class can be left
        out for agar pads with ``required=("cell", "media")``.

    Returns
    -------
    dict
        ``{"cell": ClassStatistics, "media": ..., "device": ...}`` for the painted classes.
    """
    stack = as_image_stack(image)
    classes = as_label_stack(labels, stack.shape, required=required)
    result = {}
    for name, value in CLASS_VALUES.items():
        pixels = stack[classes == value]
        if pixels.size:
            result[name] = ClassStatistics(
                mean=float(pixels.mean()), variance=float(pixels.var()), n_pixels=int(pixels.size)
            )
    return result
