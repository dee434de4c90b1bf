"""Measurements of a phase image against its instance masks.

What a fit of the optics to a real colony is judged by: the pixel size implied by
the cells' widths, the per-image normalised medians of cells and background, and
the mean intensity against the signed distance to the cells' and to the colony's
outline (the halo and the shade-off).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = [
    "cell_widths_px",
    "class_medians",
    "distance_profile",
    "estimate_pixel_size_um",
    "normalise_percentiles",
]


def _labels(labels: np.ndarray) -> np.ndarray:
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be a 2-D integer instance mask, got {labels.shape}")
    if not np.any(labels > 0):
        raise ValueError("labels hold no cell (all 0): give the instance mask of the image")
    return labels


def cell_widths_px(labels: np.ndarray) -> np.ndarray:
    """Width of every region: twice its largest inscribed radius, minus one pixel.

    The Euclidean distance transform of a region, measured from pixel centres to
    the nearest pixel outside, peaks at ``w / 2 + 1/2`` on the centre line of a rod
    ``w`` pixels wide, so ``w = 2 max(d) - 1``.
    """
    labels = _labels(labels)
    widths = []
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        region = np.pad(labels[box] == index, 1)
        widths.append(2.0 * ndimage.distance_transform_edt(region).max() - 1.0)
    return np.array(widths)


def estimate_pixel_size_um(labels: np.ndarray, cell_width_um: float = 1.0) -> float:
    """Pixel size from the median cell width of the masks and a known cell width.

    Parameters
    ----------
    labels
        Instance mask of the image.
    cell_width_um
        The species' width (E. coli on a pad: ~1 um).
    """
    if not (np.isfinite(cell_width_um) and cell_width_um > 0):
        raise ValueError(f"cell_width_um must be positive, got {cell_width_um!r}")
    return float(cell_width_um / np.median(cell_widths_px(labels)))


def normalise_percentiles(image: np.ndarray, low: float = 1.0, high: float = 99.0) -> np.ndarray:
    """``(image - p_low) / (p_high - p_low)``, the per-image normalisation of a network."""
    image = np.asarray(image, np.float64)
    lo, hi = np.percentile(image, [low, high])
    if hi <= lo:
        raise ValueError("the image is flat between its percentiles: nothing to normalise")
    return (image - lo) / (hi - lo)


def class_medians(
    image: np.ndarray, labels: np.ndarray, far_px: float
) -> dict[str, float]:
    """Medians of the 1-99 percentile normalised image over cells, halo and background.

    Parameters
    ----------
    image
        Phase image (any units).
    labels
        Its instance mask (cells = ``labels > 0``).
    far_px
        Background = pixels at least this far (Euclidean, pixels) from every cell.

    Returns
    -------
    dict
        ``{"cells", "halo", "background"}``; halo = pixels within 3 px outside a cell.
    """
    labels = _labels(labels)
    norm = normalise_percentiles(image)
    if norm.shape != labels.shape:
        raise ValueError(f"image {norm.shape} and labels {labels.shape} differ in shape")
    distance = ndimage.distance_transform_edt(labels == 0)
    far = distance >= far_px
    if not far.any():
        raise ValueError(f"no pixel is {far_px} px from every cell: use a smaller far_px")
    return {
        "cells": float(np.median(norm[labels > 0])),
        "halo": float(np.median(norm[(distance > 0) & (distance <= 3)])),
        "background": float(np.median(norm[far])),
    }


def distance_profile(
    image: np.ndarray, mask: np.ndarray, edges_px: np.ndarray
) -> np.ndarray:
    """Mean of ``image`` in bins of signed distance to the outline of ``mask``.

    Negative inside the mask, positive outside (pixel centres, so the first pixels
    either side are at -0.5 and +0.5). With ``mask = labels > 0`` it is the profile
    across cell edges (gaps inside a colony count as outside); with a colony's
    filled outline it is the profile across the colony's edge. Empty bins are nan.
    """
    mask = np.asarray(mask, bool)
    image = np.asarray(image, np.float64)
    if mask.shape != image.shape:
        raise ValueError(f"image {image.shape} and mask {mask.shape} differ in shape")
    signed = np.where(
        mask,
        -(ndimage.distance_transform_edt(mask) - 0.5),
        ndimage.distance_transform_edt(~mask) - 0.5,
    )
    index = np.digitize(signed.ravel(), edges_px) - 1
    ok = (index >= 0) & (index < len(edges_px) - 1)
    total = np.bincount(index[ok], image.ravel()[ok], minlength=len(edges_px) - 1)
    count = np.bincount(index[ok], minlength=len(edges_px) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)
