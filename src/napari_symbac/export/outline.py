"""The annotation outline convention: where a mask's edge sits relative to the cell.

A synthetic mask is the model cell (eq. 4-5: the rod's pixels at camera resolution).
Human annotators (or the probability maps they filtered) often draw the outline a
little outside it, where the blurred fluorescence fades into the background. A network
trained on model-sized masks then predicts cells narrower than the user's annotations.

:func:`outline_offset_px` measures that offset between a user's masks and the fitted
model cells of the same image; :func:`grow_masks` grows exported masks by it
(``ExportSettings.mask_dilation_um``), so the dataset follows the user's convention.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["grow_masks", "outline_offset_px"]


def grow_masks(labels: np.ndarray, distance_px: float) -> np.ndarray:
    """Every cell of ``labels`` grown outwards by ``distance_px`` into the background.

    A background pixel joins the nearest cell within ``distance_px`` (Euclidean, from
    pixel centres); cells never grow into each other, and a pixel as far from two
    cells goes to one of them (``skimage.segmentation.expand_labels``).

    Parameters
    ----------
    labels
        Instance mask (0 background).
    distance_px
        How far to grow, pixels, ``>= 0`` (0: unchanged copy).

    Returns
    -------
    numpy.ndarray
        The grown instance mask, same dtype.
    """
    from skimage.segmentation import expand_labels

    if not np.isfinite(distance_px) or distance_px < 0:
        raise ValueError(f"distance_px must be a finite number >= 0, got {distance_px!r}")
    labels = np.asarray(labels)
    if distance_px == 0:
        return labels.copy()
    return expand_labels(labels, distance=distance_px).astype(labels.dtype)


def outline_offset_px(user_masks: np.ndarray, model_labels: np.ndarray) -> np.ndarray:
    """How far each user mask's outline lies outside its model cell, pixels.

    Each user cell is paired with the model cell it overlaps most (and that overlaps it
    most back: a one-to-one match); the offset of a pair is the area difference over
    the model cell's perimeter, ``(A_user - A_model) / P_model``: the width of the band
    the user's outline adds around the model outline (negative: inside it). Sub-pixel,
    unlike a difference of widths.

    Parameters
    ----------
    user_masks
        Instance masks the user drew.
    model_labels
        Instance labels of the fitted model cells on the same pixels.

    Returns
    -------
    numpy.ndarray
        One offset per matched pair (empty when none overlaps).
    """
    from skimage.measure import perimeter

    user, model = np.asarray(user_masks), np.asarray(model_labels)
    if user.shape != model.shape:
        raise ValueError(
            f"user masks {user.shape} and model labels {model.shape} must have one shape"
        )
    both = (user > 0) & (model > 0)
    if not both.any():
        return np.zeros(0)
    pairs, overlap = np.unique(np.stack([user[both], model[both]]), axis=1, return_counts=True)
    best_of_user: dict[int, tuple[int, int]] = {}
    best_of_model: dict[int, tuple[int, int]] = {}
    for (u, m), n in zip(pairs.T.tolist(), overlap.tolist(), strict=True):
        if n > best_of_user.get(u, (0, 0))[1]:
            best_of_user[u] = (m, n)
        if n > best_of_model.get(m, (0, 0))[1]:
            best_of_model[m] = (u, n)
    user_area = np.bincount(user.ravel())
    model_area = np.bincount(model.ravel())
    boxes = ndimage.find_objects(model)
    offsets = []
    for u, (m, _) in sorted(best_of_user.items()):
        if best_of_model[m][0] != u:
            continue
        cell = np.pad(model[boxes[m - 1]] == m, 1)
        offsets.append((user_area[u] - model_area[m]) / max(perimeter(cell), 1.0))
    return np.asarray(offsets, dtype=float)
