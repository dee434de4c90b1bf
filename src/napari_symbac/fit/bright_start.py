"""Bright cells on a dark background (fluorescence): one threshold per cell.

A single (Otsu) threshold follows the brightest cells: on the ColiCoords ds1
fluorescence fields, whose cells differ up to 10x in brightness, its regions
covered 38 of the 52 masked cells. Here every cell gets its own threshold, half of its own peak
above the background, so that a dim cell next to a bright one is found as well as
the bright one.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["bright_instances", "brightest_contrast", "touching_cells"]

#: Gaussian smoothing before detection (um): about the blur of a cell's edge, so
#: that the texture inside a cell does not split it.
DETECT_SIGMA_UM = 0.16
#: A cell's smoothed peak must stand this many s.d. of the smoothed background above
#: it. Measured on ColiCoords ds1 (10 fields, 80 nm pixels): masked cells 45-835,
#: cell-sized unmasked background structure up to 34.
DETECT_SNR = 40.0
#: A peak whose half-maximum region covers pixels painted as cell needs only this many
#: s.d.: the user has said a cell is there (found as a user: a crop of ColiCoords' 01
#: around one cell, its glow most of the crop, stood 30 s.d. against painted media and
#: was refused, though its strokes were painted as the refusal advised).
PAINTED_SNR = 5.0
#: Two maxima are two cells when the saddle between them is below the lower peak
#: divided by this (heights above the background); a shallower dip is texture.
SPLIT_RATIO = 2.0
#: A half-maximum region smaller than this is a spot (a diffraction-limited dot,
#: 0.3-0.5 um^2 on ds1), not a cell (a 1 x 0.8 um cell is 0.7 um^2).
MIN_BRIGHT_AREA_UM2 = 0.6
#: The fewest painted background pixels :func:`bright_instances` measures the
#: background on (a stroke of 3 x 10 px is 30).
MIN_BACKGROUND_PIXELS = 20
#: Finer seeds for touching cells: the valley between two touching daughters is
#: shallower than :data:`SPLIT_RATIO` at :data:`DETECT_SIGMA_UM` (a touching colony
#: of 4-6 cells is one blob), but shows at this smoothing (um) ...
TOUCHING_SIGMA_UM = 0.12
#: ... as maxima whose dynamics exceed this factor: on the touching colony of
#: ``docs/scripts/fit_touching_colony.py`` they are the true count in every frame.
TOUCHING_RATIO = 1.4


def bright_instances(
    image: np.ndarray,
    pixel_size_um: float,
    *,
    valid: np.ndarray | None = None,
    region: np.ndarray | None = None,
    background: np.ndarray | None = None,
    painted_cells: np.ndarray | None = None,
) -> np.ndarray:
    """Instance labels of bright cells, each cut at half its own peak.

    Method: the image (censored pixels set to the background) is smoothed by a
    Gaussian of :data:`DETECT_SIGMA_UM`; the background ``b`` is its median over
    ``region`` and its noise ``s`` the distance from the median to the 15.9th
    percentile (the lower tail, free of cells). Pixels above ``b + 3 s`` are cut
    into basins by a watershed from the maxima whose dynamics exceed a factor
    :data:`SPLIT_RATIO` (h-maxima of ``log(smooth - b)``). In each basin the pixels
    above half the basin's peak (above ``b``), connected to the peak, are a cell
    when the peak is at least :data:`DETECT_SNR` ``s`` above ``b`` (:data:`PAINTED_SNR`
    when the region covers ``painted_cells``) and the region at
    least :data:`MIN_BRIGHT_AREA_UM2`; a smaller one is a spot, taken out of the
    basin (with a 3-pixel margin) before the basin's next peak is tried, so that a
    dim cell under a bright spot is still found.

    Parameters
    ----------
    image
        The frame (ADU), cells brighter than the background.
    pixel_size_um
        Camera pixel size.
    valid
        Pixels to trust (False: censored); default all.
    region
        Where cells may be (e.g. inside a trench); default the whole image.
    background
        Pixels known to hold no cell (painted media): ``b`` and ``s`` are measured on
        them instead of on ``region``'s lower half, which in a crop around a few cells
        is mostly their glow (at least :data:`MIN_BACKGROUND_PIXELS` of them inside
        ``region``; fewer are not used).
    painted_cells
        Pixels painted as cell (rough strokes): a region over them is a cell from
        :data:`PAINTED_SNR` background s.d. up.

    Returns
    -------
    numpy.ndarray
        Instance labels ``1..n`` (0 background), in the order of the basins.
    """
    from skimage.morphology import h_maxima
    from skimage.segmentation import watershed

    image = np.asarray(image, float)
    region = np.ones(image.shape, bool) if region is None else np.asarray(region, bool)
    smoothed = _smoothed(image, pixel_size_um, valid, region, background)
    if smoothed is None:
        return np.zeros(image.shape, np.int64)
    smooth, background, noise = smoothed
    above = (smooth > background + 3 * noise) & region
    height = np.log(np.maximum(smooth - background, 3 * noise))
    markers = ndimage.label(h_maxima(height, math.log(SPLIT_RATIO)) & above)[0]
    basins = watershed(-smooth, markers, mask=above)
    instances = np.zeros(image.shape, np.int64)
    min_pixels = MIN_BRIGHT_AREA_UM2 / pixel_size_um**2
    painted = None if painted_cells is None else np.asarray(painted_cells, bool)
    count = 0
    for box_index, box in enumerate(ndimage.find_objects(basins), start=1):
        if box is None:
            continue
        remaining = basins[box] == box_index
        local = smooth[box]
        for _ in range(4):  # a basin holds a cell under at most a few spots
            if not remaining.any():
                break
            masked = np.where(remaining, local, -np.inf)
            peak_at = np.unravel_index(int(np.argmax(masked)), local.shape)
            peak = float(local[peak_at])
            if peak - background < min(DETECT_SNR, PAINTED_SNR) * noise:
                break
            half = remaining & (local > background + 0.5 * (peak - background))
            parts = ndimage.label(half)[0]
            half = parts == parts[peak_at]
            said = painted is not None and bool((painted[box] & half).any())
            if peak - background < (PAINTED_SNR if said else DETECT_SNR) * noise:
                break
            if half.sum() >= min_pixels:
                count += 1
                instances[box][half] = count
                break
            remaining &= ~ndimage.binary_dilation(half, iterations=3)
    return instances


def brightest_contrast(
    image: np.ndarray,
    pixel_size_um: float,
    *,
    valid: np.ndarray | None = None,
    region: np.ndarray | None = None,
    background: np.ndarray | None = None,
) -> float:
    """How far the brightest smoothed pixel stands above the background, in the
    background spreads that :func:`bright_instances` asks :data:`DETECT_SNR` of (0
    when no pixel is usable): what an automatic start that found no cell says."""
    image = np.asarray(image, float)
    region = np.ones(image.shape, bool) if region is None else np.asarray(region, bool)
    smoothed = _smoothed(image, pixel_size_um, valid, region, background)
    if smoothed is None:
        return 0.0
    smooth, background, noise = smoothed
    return (float(smooth[region].max()) - background) / noise


def _smoothed(
    image: np.ndarray,
    pixel_size_um: float,
    valid: np.ndarray | None,
    region: np.ndarray,
    background: np.ndarray | None,
) -> tuple[np.ndarray, float, float] | None:
    """The image smoothed by :data:`DETECT_SIGMA_UM` (censored pixels set to the
    median), its background level and the background's spread; ``None`` when no pixel
    of ``region`` is valid. On the ``background`` pixels (valid, in ``region``) when
    there are :data:`MIN_BACKGROUND_PIXELS`: their median and their robust s.d. (half
    the 15.9-84.1 percentile range); else on ``region``: its median and the median
    less the 15.9th percentile (the lower tail, free of cells)."""
    valid = np.ones(image.shape, bool) if valid is None else np.asarray(valid, bool)
    usable = valid & region
    if not usable.any():
        return None
    filled = np.where(valid, image, np.median(image[usable]))
    smooth = ndimage.gaussian_filter(filled, DETECT_SIGMA_UM / pixel_size_um)
    inside = smooth[region]
    known = None if background is None else smooth[np.asarray(background, bool) & usable]
    if known is not None and known.size >= MIN_BACKGROUND_PIXELS:
        level = float(np.median(known))
        low, high = np.percentile(known, [15.87, 84.13])
        spread = float(high - low) / 2
    else:
        level = float(np.median(inside))
        spread = level - float(np.percentile(inside, 15.87))
    spread = max(spread, 1e-6 * max(float(inside.max()) - level, 1.0))
    return smooth, level, spread


def touching_cells(
    image: np.ndarray,
    pixel_size_um: float,
    blobs: np.ndarray,
    *,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Bright blobs, each cut into the touching cells its finer maxima show.

    The image (censored pixels set to the blobs' median) is smoothed by a Gaussian
    of :data:`TOUCHING_SIGMA_UM`; its maxima inside the blobs whose dynamics exceed
    a factor :data:`TOUCHING_RATIO` above the image's median (h-maxima of
    ``log(smooth - median)``, found once for the whole image) seed a watershed of
    each blob. A proposal only: the fit keeps it when the penalised likelihood says
    so (:mod:`napari_symbac.fit.moves`).

    Parameters
    ----------
    image
        The frame (ADU), cells brighter than the background.
    pixel_size_um
        Camera pixel size.
    blobs
        Instance labels of the blobs to cut (one cell or several touching ones
        each), e.g. of :func:`bright_instances`.
    valid
        Pixels to trust (False: censored); default all.

    Returns
    -------
    numpy.ndarray
        Instance labels ``1..k`` of the cut blobs' parts, blob by blob (0 outside the
        blobs); a blob without a seed stays whole.
    """
    from skimage.morphology import h_maxima
    from skimage.segmentation import watershed

    image = np.asarray(image, float)
    blobs = np.asarray(blobs, np.int64)
    out = np.zeros(image.shape, np.int64)
    valid = np.ones(image.shape, bool) if valid is None else np.asarray(valid, bool)
    trusted = (blobs > 0) & valid
    if not trusted.any():
        return out
    filled = np.where(valid, image, np.median(image[trusted]))
    smooth = ndimage.gaussian_filter(filled, TOUCHING_SIGMA_UM / pixel_size_um)
    floor = float(np.median(smooth))
    height = np.log(np.maximum(smooth - floor, 1e-6 * max(float(smooth.max()) - floor, 1.0)))
    peaks = h_maxima(height, math.log(TOUCHING_RATIO)).astype(bool) & (blobs > 0)
    count = 0
    for index, box in enumerate(ndimage.find_objects(blobs), start=1):
        if box is None:
            continue
        blob = blobs[box] == index
        seeds = ndimage.label(peaks[box] & blob)[0]
        parts = watershed(-smooth[box], seeds, mask=blob) if seeds.max() else blob.astype(int)
        out[box][parts > 0] = parts[parts > 0] + count
        count += int(parts.max())
    return out
