"""Pixel weight maps for U-Net training sets (DeLTA's ``wei/`` folders).

Segmentation (:func:`segmentation_weights`) uses the border weighting of the U-Net paper
(Ronneberger, Fischer & Brox 2015, eq. 2)::

    w(x) = w_c(x) + w0 * exp(-(d1(x) + d2(x))**2 / (2 * sigma**2))   outside cells
    w(x) = w_c(x)                                                     in cells

with ``d1``, ``d2`` the distances to the nearest and second-nearest cell, so that the
thin background gaps between touching cells, which a segmenter most easily closes, weigh
most. ``w0 = 12`` and ``sigma = 2`` px are DeLTA's defaults for mother-machine data.

Tracking (:func:`tracking_weights`) weighs, for one seed cell of the previous frame,
its own pixels (the mother and daughters to find in the current frame) most, other
cells by how close they are to them (the cells a tracker could confuse it with), and
the background least.

Maps are stored as 16-bit PNGs holding ``round(100 * w)``, like the weights DeLTA
computes for its own tracking sets (scaled by 100); read them with ``/ 100``. Only
ratios between pixels matter to a weighted loss.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["WEIGHT_SCALE", "segmentation_weights", "to_weight_png", "tracking_weights"]

#: Stored value per unit of weight in the ``wei/`` PNGs.
WEIGHT_SCALE = 100


def _box(mask: np.ndarray, margin: int) -> tuple[slice, slice]:
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return (
        slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, mask.shape[0])),
        slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, mask.shape[1])),
    )


def segmentation_weights(
    labels: np.ndarray, *, w0: float = 12.0, sigma_px: float = 2.0, cell_weight: float = 1.0
) -> np.ndarray:
    """U-Net border weight map of an instance mask (module notes; U-Net paper eq. 2).

    Parameters
    ----------
    labels
        ``(Y, X)`` instance mask, 0 = background.
    w0, sigma_px
        Amplitude and length scale of the border term.
    cell_weight
        Class weight ``w_c`` of cell pixels (background pixels have 1).

    Returns
    -------
    numpy.ndarray
        float32 weights, >= 1 everywhere.
    """
    labels = np.asarray(labels)
    inside = labels > 0
    margin = int(np.ceil(6 * sigma_px))  # exp(-(6 sigma)^2 / 2 sigma^2) ~ 1.5e-8
    nearest = np.full(labels.shape, np.inf)
    second = np.full(labels.shape, np.inf)
    for index, box in enumerate(ndimage.find_objects(labels.astype(np.int64)), start=1):
        if box is None:
            continue
        cell = labels == index
        rows, cols = _box(cell, margin)
        distance = ndimage.distance_transform_edt(~cell[rows, cols])
        near, sec = nearest[rows, cols], second[rows, cols]
        second[rows, cols] = np.where(distance < near, near, np.minimum(sec, distance))
        nearest[rows, cols] = np.minimum(near, distance)
    with np.errstate(invalid="ignore", over="ignore"):
        border = w0 * np.exp(-np.square(nearest + second) / (2 * sigma_px**2))
    border = np.where(np.isfinite(border) & ~inside, border, 0.0)
    return (np.where(inside, cell_weight, 1.0) + border).astype(np.float32)


def tracking_weights(
    track: np.ndarray,
    all_cells: np.ndarray,
    *,
    halo_px: float = 20.0,
    cell_weight: float = 20.0,
) -> np.ndarray:
    """Weight map of one tracking sample (module notes).

    Parameters
    ----------
    track
        ``(Y, X)`` boolean mask of the seed cell's mother and daughters in the current
        frame (empty if the cell left the field).
    all_cells
        ``(Y, X)`` boolean mask of every cell in the current frame.
    halo_px
        Length over which the weight of other cells decays with their distance from
        the tracked cells.
    cell_weight
        Weight of the tracked cells' pixels; other cells get up to this much.

    Returns
    -------
    numpy.ndarray
        float32 weights, >= 1 everywhere.
    """
    track = np.asarray(track, dtype=bool)
    others = np.asarray(all_cells, dtype=bool) & ~track
    weights = np.ones(track.shape, np.float32)
    if not track.any():  # the cell left: every cell is a wrong answer
        weights[others] = cell_weight
        return weights
    distance = ndimage.distance_transform_edt(~track)
    weights[others] = 1 + (cell_weight - 1) * np.exp(-distance[others] / halo_px)
    weights[track] = cell_weight
    return weights


def to_weight_png(weights: np.ndarray) -> np.ndarray:
    """``round(WEIGHT_SCALE * weights)`` as uint16, for a 16-bit PNG."""
    scaled = np.rint(np.asarray(weights, dtype=np.float64) * WEIGHT_SCALE)
    if scaled.size and (scaled.min() < 0 or scaled.max() > np.iinfo(np.uint16).max):
        raise ValueError(
            f"weights must lie in [0, {np.iinfo(np.uint16).max / WEIGHT_SCALE:g}] to be "
            "stored in a 16-bit PNG"
        )
    return scaled.astype(np.uint16)
