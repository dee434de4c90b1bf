"""The annotation outline convention: where a mask's edge sits relative to the cell.

A synthetic mask is the model cell (eq. 4-5: the rod's pixels at camera resolution).
Human annotators (or the probability maps they filtered) often draw the outline a
little outside it, where the blurred fluorescence fades into the background. A network
trained on model-sized masks then predicts cells narrower than the user's annotations.

:func:`outline_offset_px` measures that offset between a user's masks and the fitted
model cells of the same image; :func:`grow_masks` grows exported masks by it
(``ExportSettings.mask_dilation_um``), so the dataset follows the user's convention.

In fluorescence the convention is read in the image's light instead
(:func:`outline_level`, :func:`level_matched_growth_px`): the level, as a fraction of a
cell's core above the background, at which the annotation's outline lies, and the growth
of the model cells that puts their outline at that level of the model's image. A model
whose edge profile differs from the real cells' (on ColiCoords field 1 the real light at
the fitted model outline is 0.28 of the peak, the model's own 0.40) places the same
geometric offset at another level of the light, and a network learns the level.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = [
    "border_ids",
    "grow_masks",
    "level_matched_growth_px",
    "outline_level",
    "outline_offset_px",
]


def border_ids(labels: np.ndarray) -> np.ndarray:
    """Ids of the regions of ``labels`` that the image's border cuts."""
    labels = np.asarray(labels)
    edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    return np.unique(edge[edge > 0])


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


def outline_level(
    image: np.ndarray,
    labels: np.ndarray,
    *,
    valid: np.ndarray | None = None,
    far_px: float = 6.0,
) -> np.ndarray:
    """Light at each cell's outline as a fraction of its core's, above the background.

    For every cell of ``labels`` that the image's border does not cut: ``(median of its
    edge pixels - b) / (median of its core - b)``, the edge being the cell's pixels next
    to another label or the background (distance to the outside at most 1 px), the core
    its pixels at least half its largest inscribed radius (and 2 px) deep, and ``b`` the
    median of the ``valid`` pixels at least ``far_px`` from every cell.

    Parameters
    ----------
    image
        The image (bright cells on a dark background: fluorescence).
    labels
        Its instance mask.
    valid
        Pixels that may set the background (False: censored); default all.
    far_px
        Background pixels lie at least this far from every cell.

    Returns
    -------
    numpy.ndarray
        One level per whole cell with a core (empty when none, or no background).
    """
    image = np.asarray(image, dtype=np.float64)
    labels = np.asarray(labels)
    if image.shape != labels.shape:
        raise ValueError(f"image {image.shape} and labels {labels.shape} must have one shape")
    ok = np.ones(image.shape, bool) if valid is None else np.asarray(valid, bool)
    far = ok & (ndimage.distance_transform_edt(labels == 0) >= far_px)
    if not far.any():
        return np.zeros(0)
    background = float(np.median(image[far]))
    cut = set(border_ids(labels).tolist())
    levels = []
    for index, box in enumerate(ndimage.find_objects(labels.astype(np.int64)), start=1):
        if box is None or index in cut:
            continue
        cell = np.pad(labels[box] == index, 1)
        depth = ndimage.distance_transform_edt(cell)[1:-1, 1:-1]
        cell = cell[1:-1, 1:-1]
        core = depth >= max(2.0, 0.5 * depth.max())
        if not core.any():
            continue
        patch = image[box]
        light = float(np.median(patch[core])) - background
        if light > 0:
            edge = cell & (depth <= 1.0)
            levels.append((float(np.median(patch[edge])) - background) / light)
    return np.asarray(levels, dtype=float)


def level_matched_growth_px(
    level: float,
    model_image: np.ndarray,
    model_labels: np.ndarray,
    *,
    max_px: float = 8.0,
    step_px: float = 0.25,
) -> float | None:
    """How far to grow the model cells for their outline to lie at ``level``.

    The median :func:`outline_level` of ``model_image`` with ``model_labels`` grown by
    ``0, step_px, ... max_px`` (:func:`grow_masks`) falls as the outline moves out into
    the blurred edge; the growth where it first reaches ``level`` is interpolated
    between the two steps around it. 0 when the model's own outline already lies at or
    below ``level`` (masks are never shrunk), ``max_px`` when even that growth stays
    above it, ``None`` when no model cell has a level.
    """
    growths = np.arange(0.0, max_px + step_px / 2, step_px)
    previous = None
    for growth in growths:
        levels = outline_level(model_image, grow_masks(model_labels, float(growth)))
        if not levels.size:
            return None
        here = float(np.median(levels))
        if here <= level:
            if previous is None:
                return 0.0
            before_growth, before = previous
            return float(before_growth + (before - level) / (before - here) * step_px)
        previous = (float(growth), here)
    return float(max_px)
