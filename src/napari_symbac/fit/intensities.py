"""Intensity statistics of cells, media and device from rough labels (eq. 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from napari_symbac.fit.inputs import CLASS_VALUES, as_image_stack, as_label_stack

__all__ = ["ClassStatistics", "class_statistics", "rough_class_means"]


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


def rough_class_means(image: np.ndarray, modality: str, *, field: bool) -> dict[str, float]:
    """Mean intensity of the cells and of the background of an image nobody painted.

    A start for eq. 3's intensities before classes are painted or a fit is run, not a
    measurement. The image is smoothed over 1 px and split at Otsu's thresholds; each
    class's mean is taken of the unsmoothed pixels (eq. 2 with the split as its labels):

    * fluorescence: the cells are the bright side of one threshold, the background the
      median of the dark side;
    * phase contrast in a trench: the cells (with the PDMS) the dark side of one
      threshold, the media the bright side;
    * phase contrast in a field (an agar pad, mostly background): the background its
      median, the cells the darkest of three classes (the bright third is the halo,
      which a single threshold took for the background: Omnipose's Sample000252 gave
      201 against 140 measured with its masks away from the cells; its median 137);
    * bright field, whose cells differ from the background by a few per cent either
      way: only the median, as the background.

    Parameters
    ----------
    image
        2D image, any integer or float dtype; non-finite pixels are left out.
    modality
        ``"phase"``, ``"fluorescence"`` or ``"brightfield"``.
    field
        Whether the image is an open field (an agar pad) rather than a trench.

    Returns
    -------
    dict
        ``{"cell": mean, "media": mean}`` in the image's units; ``{"media": median}`` in
        bright field and for an image of too few levels to split.
    """
    from scipy.ndimage import gaussian_filter
    from skimage.filters import threshold_multiotsu, threshold_otsu

    values = np.asarray(image, np.float64)
    finite = np.isfinite(values)
    if not finite.any():
        raise ValueError("the image has no finite pixel to take intensities from")
    median = float(np.median(values[finite]))
    smooth = gaussian_filter(np.where(finite, values, median), 1.0)
    levels = np.unique(smooth[finite])
    if modality == "brightfield" or levels.size < 4:
        return {"media": median}
    if modality == "fluorescence":
        bright = (smooth > threshold_otsu(smooth[finite])) & finite
        cells, background = bright, ~bright & finite
        media = float(np.median(values[background])) if background.any() else median
    elif field:
        cells = (smooth <= threshold_multiotsu(smooth[finite], 3)[0]) & finite
        media = median
    else:
        cells = (smooth <= threshold_otsu(smooth[finite])) & finite
        background = ~cells & finite
        media = float(values[background].mean()) if background.any() else median
    if not cells.any():
        return {"media": median}
    return {"cell": float(values[cells].mean()), "media": media}
