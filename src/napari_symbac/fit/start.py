"""Starting scenes for the scene fit: cells from a segmentation, labels or a mask.

Every start ends in :func:`cells_from_instances` (region moments of an instance
mask). The instance mask comes from the user (``masks``: theirs or any
segmenter's), from painted labels (connected components of class 1, split at
septa) or from a plain Otsu segmentation (:func:`otsu_cells`). The polarity
(cells darker or brighter than their surroundings) comes from painted labels when
there are any, else from the modality (phase: dark; fluorescence: bright); it is
never assumed.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from scipy import ndimage

from napari_symbac.fit.bright_start import (
    DETECT_SNR,
    PAINTED_SNR,
    bright_instances,
    brightest_contrast,
)
from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.fit.preflight import as_instance_ids
from napari_symbac.settings import Microscope
from napari_symbac.sim import FrameCells

__all__ = [
    "MAX_BLOB_SHARE",
    "MAX_START_WIDTH_UM",
    "FaintStartError",
    "WideStartError",
    "brightfield_instances",
    "cells_from_instances",
    "cut_by_edge",
    "otsu_cells",
    "polarity_of",
    "refuse_blobs",
    "refuse_wide_cells",
    "start_scene",
    "too_wide",
]


def _spherocylinder_width(area_um2: float, length_um: float) -> float:
    """Width of the spherocylinder of given area and length: ``A = w L - (1 - pi/4) w^2``."""
    k = 1 - math.pi / 4
    disc = max(length_um**2 - 4 * k * area_um2, 0.0)
    return (length_um - math.sqrt(disc)) / (2 * k)


def _trench_columns(smooth: np.ndarray) -> np.ndarray:
    """The columns of a phase-contrast frame (dark cells, smoothed) that lie in a trench.
    Device columns are dark all along; trench columns hold bright media or halo
    somewhere: the 90th percentile of each column separates them."""
    columns = np.percentile(smooth, 90, axis=0)
    low, high = np.percentile(columns, 10), columns.max()
    above = columns > low + 0.3 * (high - low)
    return ndimage.binary_closing(above, np.ones(7, bool)) | above  # dips between halos


def _trench_runs(trench_columns: np.ndarray, px: float) -> list[np.ndarray]:
    """The runs of trench columns (each an array of column indices) at least half as
    wide as the widest and 0.5 um wide."""
    labels, n = ndimage.label(trench_columns)
    sizes = ndimage.sum(trench_columns, labels, range(1, n + 1))
    return [
        np.flatnonzero(labels == k + 1)
        for k in range(n)
        if sizes[k] >= max(0.5 * sizes.max(), 0.5 / px)
    ]


def _refuse_trenches_side_by_side(runs: list[np.ndarray]) -> None:
    if len(runs) > 1:
        where = ", ".join(f"{r[0]}-{r[-1]}" for r in runs)
        raise ValueError(
            f"the image holds {len(runs)} trenches side by side (columns {where}): the fit "
            "places one trench: crop each trench, with about 1 um of PDMS either side, into "
            "an image of its own"
        )


def _trench_run(trench_columns: np.ndarray, px: float) -> tuple[int, int] | None:
    """The first and last column of the trench (the longest run of trench columns), or
    ``None`` when there is none. A frame holding several trenches side by side (runs at
    least half as wide as the widest and 0.5 um wide) is refused: the fit places one
    trench. Found as a user: four trenches side by side, fitted with ``--geometry
    trench``, had the first fitted and the other three left in the residual, exit 0."""
    _refuse_trenches_side_by_side(_trench_runs(trench_columns, px))
    labels, n = ndimage.label(trench_columns)
    if n == 0:
        return None
    sizes = ndimage.sum(trench_columns, labels, range(1, n + 1))
    idx = np.flatnonzero(labels == int(np.argmax(sizes)) + 1)
    return int(idx[0]), int(idx[-1])


#: The widest run of columns (um) taken for one trench in a frame of several side by
#: side (mother-machine trenches hold cells in single file: the SyMBac and DeLTA
#: trenches' runs are 1.5 and 1.4 um).
SIDE_BY_SIDE_TRENCH_MAX_WIDTH_UM = 4.0


def refuse_trenches_in_a_field(image: np.ndarray, px: float) -> None:
    """Refuse a phase-contrast frame too wide to be taken for a trench that holds
    several trenches side by side: at least two runs of trench columns of like widths
    (within a factor 1.5), each at most :data:`SIDE_BY_SIDE_TRENCH_MAX_WIDTH_UM` wide.
    Found as a user: four trenches side by side (274 px wide) were refused as a colony
    ("give instance masks") where the fix is to crop one trench. A colony's columns make
    runs of several micrometres."""
    smooth = ndimage.gaussian_filter(np.asarray(image, float), 1.0)
    runs = _trench_runs(_trench_columns(smooth), px)
    widths_um = np.array([r.size * px for r in runs])
    if (
        widths_um.size
        and widths_um.max() <= min(SIDE_BY_SIDE_TRENCH_MAX_WIDTH_UM, 1.5 * widths_um.min())
        and _runs_hold_down_the_frame(smooth, runs, px)
    ):
        _refuse_trenches_side_by_side(runs)


def _runs_hold_down_the_frame(smooth: np.ndarray, runs: list[np.ndarray], px: float) -> bool:
    """Whether the top, middle and bottom third of the rows each show the same runs of
    trench columns as the whole frame (as many, each overlapping its own by half or
    more): trenches are straight channels through the frame. Found as a user: windows
    of a dense colony fitted as an open field were refused as "N trenches side by side"
    (216 of 1530 windows of 64, 96 and 128 px, half-overlapping, of the three Omnipose
    colonies at 0.118 um/px; 7, all 64 px, with this check), the wrong fix for a colony."""
    for part in np.array_split(smooth, 3, axis=0):
        found = _trench_runs(_trench_columns(part), px)
        if len(found) != len(runs):
            return False
        for run, other in zip(runs, found):
            if np.intersect1d(run, other).size < 0.5 * min(run.size, other.size):
                return False
    return True


#: A frame is blank when its smoothed image (Gaussian, s.d. 2 px) departs from its
#: median by at most this many s.d. of the smoothed noise: pure noise reaches 4-5.4
#: (96 x 96 to 1024 x 1024 px), every frame of the 46 real images of ../shared 120 or more.
BLANK_MAX_Z = 10.0


#: The smoothing (Gaussian s.d., px) of :func:`departure_z`.
DEPARTURE_SMOOTH_PX = 2.0


def departure_z(image: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray | None:
    """How far each pixel of the smoothed frame departs from its median, in s.d. of the
    pixel noise smoothed alike (Gaussian of :data:`DEPARTURE_SMOOTH_PX`); 0 where not
    judged. What stands out of a frame's noise: :func:`refuse_blank` and the
    diagnosis' window of cells (``diagnose.region.cells_region``).

    Only the ``valid`` pixels count: the smoothing is normalised by the valid pixels'
    weight (pixels with less than half of it are not judged), and the noise is measured
    where a pixel's four neighbours are valid too. ``None`` for a frame with too few
    such pixels (a held-out checkerboard). Where the frame has no measurable noise (a
    constant frame, too few grey levels) every departure is infinite.
    """
    valid = np.ones(image.shape, bool) if valid is None else np.asarray(valid, bool)
    inner = valid & ndimage.binary_erosion(valid, border_value=1)
    if inner.mean() < 0.25:
        return None
    data = np.where(valid, np.asarray(image, float), 0.0)
    weight = ndimage.gaussian_filter(valid.astype(float), DEPARTURE_SMOOTH_PX)
    judged = valid & (weight > 0.5)
    smooth = ndimage.gaussian_filter(data, DEPARTURE_SMOOTH_PX)[judged] / weight[judged]
    departure = np.zeros(image.shape)
    departure[judged] = np.abs(smooth - np.median(smooth))
    # the s.d. of white noise after a Gaussian of s.d. r px: s / (2 r sqrt(pi)), more
    # where fewer pixels are valid
    noise = _pixel_noise(data, inner) / (
        2 * DEPARTURE_SMOOTH_PX * math.sqrt(math.pi) * math.sqrt(valid.mean())
    )
    if noise > 0:
        return departure / noise
    return np.where(departure > 0, np.inf, 0.0)


def refuse_blank(image: np.ndarray, valid: np.ndarray | None = None) -> None:
    """Refuse a frame that holds nothing but noise (a blank frame, a dark frame, an
    empty channel): no pixel of it departs by more than :data:`BLANK_MAX_Z`
    (:func:`departure_z`; a frame it cannot judge is not refused). Found as a user: a
    frame of pure noise was told it held "2 trenches side by side" as a trench, and
    took 50 s to be told it held no cells as a field.
    """
    departures = departure_z(image, valid)
    if departures is None:
        return
    z = float(departures.max())
    if z <= BLANK_MAX_Z:  # a constant frame too
        raise ValueError(
            f"the start found no cells in the image: nothing in it departs from its "
            f"median by more than its noise allows ({z:.2g} s.d. of the noise smoothed "
            "over 2 px at most), as in a blank or dark frame or an empty channel: check "
            "the frame and the channel"
        )


#: Rows (um) of device across the trench that make a closed end at an image's edge.
CLOSED_END_ROWS_UM = 0.4


def _refuse_a_closed_end_below(
    smooth: np.ndarray, inside: np.ndarray, columns: tuple[int, int], px: float
) -> None:
    """Refuse a trench whose closed end is at the bottom of the image: rows at the
    bottom edge where the trench's columns are as dark as the device beside it (within
    a quarter of the way to the trench's bright media), none at the top. The fit and
    the simulation put the closed end at the top. Found as a user: the SyMBac trench
    upside down was fitted with its closed end missing (5 cells for 4, reduced
    chi-square 40.6 against 15.5), exit 0."""
    c0, c1 = columns
    beside = np.ones(smooth.shape[1], bool)
    beside[max(c0 - 3, 0) : c1 + 4] = False
    if not beside.any():
        return
    device = float(np.median(smooth[:, beside]))
    bright = float(np.percentile(inside, 90))
    if bright <= device:
        return
    dark = inside < device + 0.25 * (bright - device)
    needed = max(5, round(CLOSED_END_ROWS_UM / px))
    top, bottom = (int(np.argmin(np.append(d, False))) for d in (dark, dark[::-1]))
    if bottom >= needed and top == 0:
        raise ValueError(
            f"the trench's closed end is at the bottom of the image (its last {bottom} rows "
            "are device across the trench), and the fit and the simulation draw it at the "
            "top: flip the image upside down (numpy.flipud; Fiji: Image > Transform > Flip "
            "Vertically)"
        )


#: Rows (um) above a closed end that its own halo reaches, left out of the judgement of
#: the rows above it (:func:`_closed_end_in_view`): on the real trench the two rows
#: above its end spread 907 and 1687 ADU across, and the profile's end moves by two
#: rows with the window.
CLOSED_END_HALO_UM = 0.4


def _closed_end_in_view(smooth: np.ndarray, first: int, px: float) -> bool:
    """Whether the rows above the closed end that the trench's row profile places at
    row ``first`` show the device alone: rows of PDMS have little structure across
    them, while every row of the trench shows its walls' edges and the media's halo.
    Their spread across the row (90th less 10th percentile) must be a quarter or less
    of the trench rows' (the real trench: 70-390 ADU above its closed end, 2400-5500
    below). The rows that the end's own halo reaches (:data:`CLOSED_END_HALO_UM`) are
    not judged; a closed end within them of the image's top is taken as placed.

    Found as a user: windows of the real trench below its closed end (126 rows from
    row 110) took a bright septum between two cells for the closed end, so the start
    dropped the rows above it and the fit drew one 11.9 um cell for two and a half
    (reduced chi-square 76 against 12.6 for a window whose septum the profile missed).
    """
    if first <= 0:
        return False
    judged = first - max(round(CLOSED_END_HALO_UM / px), 1)
    if judged <= 0:
        return True
    spread = np.percentile(smooth, 90, axis=1) - np.percentile(smooth, 10, axis=1)
    return bool(np.median(spread[:judged]) <= 0.25 * np.median(spread[first:]))


#: Septum split of the Otsu start (:func:`_split_at_septa`): a bright band across a
#: region counts as a septum when its prominence in the intensity profile along the
#: region's axis is at least this many s.d. of the profile's noise ...
SEPTUM_NOISE_SD = 6.0
#: ... and at least this fraction of the media-cell contrast of the image (phase-contrast
#: texture inside real cells, nucleoids and the halo, reaches ~0.1 of it; septa ~0.4).
SEPTUM_CONTRAST = 0.2


def _pixel_noise(image: np.ndarray, where: np.ndarray) -> float:
    """Robust s.d. of the pixel noise of ``image`` over ``where``.

    The difference of a pixel and the mean of its four neighbours has variance
    ``1.25 s^2`` for white noise and is nearly free of the (smooth) image structure;
    its median absolute deviation gives ``s``.
    """
    neighbours = ndimage.convolve(
        image, np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]]), mode="nearest"
    )
    high = (image - neighbours)[where]
    if high.size < 10:
        return 0.0
    mad = np.median(np.abs(high - np.median(high)))
    return float(1.4826 * mad / math.sqrt(1.25))


def prominent_maxima(profile: np.ndarray, min_prominence: float) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of a 1-D profile and their topographic prominences, as
    ``scipy.signal.find_peaks(profile, prominence=min_prominence)`` gives them.

    A maximum is a sample (the middle one of a flat top) higher than both its
    neighbours; its prominence is its height above the higher of the lowest points
    between it and the nearest higher sample (or the profile's end) on each side.
    Written out because importing :mod:`scipy.signal` takes 1-3 s, more than the
    rest of a trench fit's start.
    """
    x = np.asarray(profile, np.float64)
    peaks: list[int] = []
    i = 1
    while i < x.size - 1:
        if x[i - 1] < x[i]:
            ahead = i + 1
            while ahead < x.size - 1 and x[ahead] == x[i]:
                ahead += 1
            if x[ahead] < x[i]:
                peaks.append((i + ahead - 1) // 2)
                i = ahead
        i += 1
    found, prominences = [], []
    for peak in peaks:
        top = x[peak]
        left = peak
        while left > 0 and x[left - 1] <= top:
            left -= 1
        right = peak
        while right < x.size - 1 and x[right + 1] <= top:
            right += 1
        prominence = top - max(x[left : peak + 1].min(), x[peak : right + 1].min())
        if prominence >= min_prominence:
            found.append(peak)
            prominences.append(prominence)
    return np.array(found, np.int64), np.array(prominences, np.float64)


def _septum_cuts(
    profile: np.ndarray, noise: np.ndarray, min_prominence: float, min_length: int
) -> list[int]:
    """Positions of septa in a 1-D intensity profile along a region's axis.

    Local maxima (bright septa between dark cell bodies) whose topographic prominence
    is above ``min_prominence`` and above :data:`SEPTUM_NOISE_SD` times the profile's
    noise there, accepted greedily by decreasing prominence as long as every piece
    they cut the region into stays at least ``min_length`` bins long.
    """
    peaks, prominences = prominent_maxima(profile, min_prominence)
    keep = prominences >= SEPTUM_NOISE_SD * noise[peaks]
    peaks, prominences = peaks[keep], prominences[keep]
    cuts: list[int] = []
    for peak in peaks[np.argsort(-prominences, kind="stable")]:
        edges = np.array(sorted([0, len(profile), *cuts, int(peak)]))
        if np.diff(edges).min() >= min_length:
            cuts.append(int(peak))
    return sorted(cuts)


def _split_at_septa(
    instances: np.ndarray,
    image: np.ndarray,
    region: np.ndarray,
    pixel_size_um: float,
    min_cell_length_um: float = 0.8,
) -> np.ndarray:
    """Split touching cells of an instance segmentation at bright septa.

    Method (septum profile split): for each region, the image (raw, not smoothed) is
    averaged over a band along the region's principal axis, as wide as the region
    (90th percentile of the pixels' distance from the axis) and restricted to
    ``region``, in bins of one pixel, and the profile is smoothed by a Gaussian of
    one bin. In phase contrast touching cells are dark bodies separated by a bright
    septum, so septa are local maxima of this profile. A maximum is a septum when its
    prominence is at least :data:`SEPTUM_NOISE_SD` times the noise of the profile
    (pixel noise from :func:`_pixel_noise` over the number of pixels averaged) and at
    least :data:`SEPTUM_CONTRAST` times the media-cell contrast (median of
    ``region`` outside the cells minus median inside), and every piece is at least
    ``min_cell_length_um`` long (:func:`_septum_cuts`). The pieces are then drawn
    by a watershed of the smoothed image inside the region's mask, seeded with the
    region's pixels more than 0.2 um (along the axis) from every cut, so that a
    tilted septum is followed rather than cut square. Deterministic; a region with
    no septum is returned unchanged.

    Parameters
    ----------
    instances
        Instance labels (0 = background) of the thresholded cells.
    image
        The image (phase contrast: cells dark).
    region
        Where the profile may look (inside the trench).
    pixel_size_um
        Camera pixel size.
    min_cell_length_um
        Shortest piece a septum may leave at either side.

    Returns
    -------
    numpy.ndarray
        Instance labels, ``1..n`` in the order of the regions and, within a region,
        along its axis.
    """
    from skimage.segmentation import watershed

    mask = instances > 0
    if not mask.any():
        return instances
    sigma = _pixel_noise(image, region)
    outside = region & ~mask
    contrast = float(np.median(image[outside]) - np.median(image[mask])) if outside.any() else 0.0
    smooth = ndimage.gaussian_filter(image, 1.0)
    rows, cols = np.indices(image.shape)
    out = np.zeros_like(instances)
    n_out = 0
    seed_px = max(round(0.2 / pixel_size_um), 1)
    min_length = max(round(min_cell_length_um / pixel_size_um), 2)
    for index in range(1, int(instances.max()) + 1):
        inside = instances == index
        rr, cc = np.nonzero(inside)
        if rr.size < 6:
            continue
        cy, cx = rr.mean(), cc.mean()
        _evals, evecs = np.linalg.eigh(np.cov(np.stack([cc - cx, rr - cy])))
        vx, vy = evecs[:, 1]
        along = (cols - cx) * vx + (rows - cy) * vy
        across = (rows - cy) * vx - (cols - cx) * vy
        s0, s1 = along[inside].min(), along[inside].max()
        half = np.percentile(np.abs(across[inside]), 90)
        band = region & (np.abs(across) <= half) & (along >= s0) & (along <= s1)
        bins = np.round(along[band] - s0).astype(int)
        count = np.bincount(bins, minlength=int(s1 - s0 + 0.5) + 1).astype(float)
        total = np.bincount(bins, image[band], minlength=count.size)
        seen = count > 0
        mean = np.interp(np.arange(count.size), np.flatnonzero(seen), total[seen] / count[seen])
        profile = ndimage.gaussian_filter1d(mean, 1.0)
        # s.d. of a bin mean after the 1-bin Gaussian (sum of squared weights ~ 0.28).
        noise = sigma * math.sqrt(0.28) / np.sqrt(np.maximum(count, 1.0))
        cuts = _septum_cuts(profile, noise, SEPTUM_CONTRAST * contrast, min_length)
        if not cuts:
            n_out += 1
            out[inside] = n_out
            continue
        edges = [0, *cuts, count.size]
        position = along - s0
        markers = np.zeros_like(instances)
        for j in range(len(edges) - 1):
            core = inside & (position >= edges[j] + seed_px) & (position <= edges[j + 1] - seed_px)
            markers[core] = n_out + j + 1
        out += watershed(smooth, markers, mask=inside) * inside
        n_out += len(edges) - 1
    return out


def otsu_cells(
    image: np.ndarray,
    microscope: Microscope,
    *,
    geometry: Literal["trench", "open"] = "trench",
    depth_um: float = 1.2,
    max_cell_length_um: float = 4.0,
    polarity: Literal["dark", "bright"] = "dark",
    trench: TrenchPlacement | None = None,
    valid: np.ndarray | None = None,
    background: np.ndarray | None = None,
    painted_cells: np.ndarray | None = None,
) -> tuple[FrameCells, np.ndarray, TrenchPlacement | None, np.ndarray]:
    """Plain segmentation: Otsu threshold, watershed, region moments.

    ``polarity="dark"``: cells darker than the media around them (phase contrast);
    ``"bright"``: cells brighter than their background (fluorescence), which differ
    in brightness, so each is cut at half its own peak instead of at one Otsu
    threshold (:func:`~napari_symbac.fit.bright_start.bright_instances`; measured
    against the ``background`` pixels, painted media, when given; a region over
    ``painted_cells`` is a cell at a lower contrast). Pixels
    outside ``valid`` (clipped) are left out of the thresholds. In a trench, unless
    ``trench`` gives its placement, the trench is found first from the column
    profile (90th percentile of each column, longest run above 30 % of its range)
    and its closed end from the row profile (Otsu threshold). Touching cells that
    the threshold and watershed leave in one region are split at their bright septa
    (septum profile split, :func:`_split_at_septa`). A region still longer than
    ``max_cell_length_um`` is taken as several touching cells and starts as equal
    rods along its axis.

    Returns
    -------
    cells
        One spherocylinder per region: centroid, principal-axis angle, extent along
        the axis (length) and the width of the spherocylinder with the region's area
        and length (image coordinates, um).
    otsu_width_um
        That width per cell: the Otsu estimate of the cell width (section 1.3).
    trench
        The trench placement, or ``None`` for ``geometry="open"``.
    mask
        The instance labels of the segmentation (camera pixels).
    """
    from skimage.filters import threshold_otsu
    from skimage.morphology import remove_small_objects

    px = microscope.pixel_size_um
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity must be 'dark' or 'bright', got {polarity!r}")
    image = np.asarray(image, float)
    if polarity == "bright":
        image = -image
    if valid is not None and not valid.all() and valid.any():
        image = np.where(valid, image, np.median(image[valid]))
    smooth = ndimage.gaussian_filter(image, 1.0)
    region = np.ones(image.shape, bool)
    if geometry == "trench" and trench is not None:
        c0 = max(round(trench.left_um / px), 0)
        c1 = min(round((trench.left_um + trench.width_um) / px), image.shape[1])
        region[:, :c0] = False
        region[:, c1:] = False
        region[: max(round(trench.top_um / px), 0)] = False
    elif geometry == "trench" and polarity == "bright":
        raise ValueError(
            "a fluorescence image shows no trench walls to find: pass trench=TrenchPlacement(...)"
            " or geometry='open'"
        )
    elif geometry == "trench":
        run = _trench_run(_trench_columns(smooth), px)
        if run is None:
            raise ValueError("no trench found in the image: is it a mother-machine trench?")
        c0, c1 = run
        inside = smooth[:, c0 : c1 + 1].mean(axis=1)
        _refuse_a_closed_end_below(smooth, inside, (c0, c1), px)
        above = inside > threshold_otsu(inside)
        first = int(np.argmax(np.convolve(above, np.ones(3), "same") >= 2))
        first = first if _closed_end_in_view(smooth, first, px) else 0
        top_um = first * px if first > 0 else -2.0
        trench = TrenchPlacement(c0 * px, (c1 - c0 + 1) * px, top_um, depth_um)
        region[:, :c0] = False
        region[:, c1 + 1 :] = False
        region[: max(first, 0), :] = False
        # The dark shade-off of the walls can fall inside the columns found: trim
        # edge columns (and the top row) that are below the Otsu threshold almost all
        # along, as no cell is (cells leave bright septa and gaps between them).
        dark = (smooth < threshold_otsu(smooth[region])) & region
        for _ in range(3):
            cols = np.flatnonzero(region.any(axis=0))
            rows_in = np.flatnonzero(region.any(axis=1))
            if cols.size < 6 or rows_in.size < 6:
                break
            trimmed = False
            for c in (cols[0], cols[-1]):
                if dark[:, c].sum() > 0.8 * rows_in.size:
                    region[:, c] = False
                    trimmed = True
            if dark[rows_in[0]].sum() > 0.8 * cols.size:
                region[rows_in[0]] = False
                trimmed = True
            if not trimmed:
                break
    elif geometry != "open":
        raise ValueError(f"geometry must be 'trench' or 'open', got {geometry!r}")
    if polarity == "bright":
        # Fluorescent cells differ in brightness: one threshold per cell, not Otsu's.
        known = {"valid": valid, "region": region, "background": background}
        instances = bright_instances(-image, px, painted_cells=painted_cells, **known)
        if not instances.any():
            # found as a user: a crop around one cell (ColiCoords' 01) said "no region
            # of 6 pixels or more" of a cell 40 x 17 px; its glow is most of the crop
            stand = brightest_contrast(-image, px, **known)
            painted = painted_cells is not None and bool(np.any(painted_cells))
            needed = PAINTED_SNR if painted else DETECT_SNR
            # found as a user: a phase trench given as fluorescence was told its cells
            # were "not fluorescence", and not what to set instead
            raise FaintStartError(
                "the start found no cells in the image: no bright region stands "
                f"{needed:g} times the background's spread above it (the brightest "
                f"stands {stand:.0f} times: a faint field, a crop around a few cells "
                "whose glow is most of the image, which then is no background, or cells "
                "darker than their background, as phase contrast and bright field show "
                "them: not fluorescence, set the modality to phase or brightfield)"
            )
        cells, widths = cells_from_instances(instances, px, max_cell_length_um)
        return cells, widths, (trench if geometry == "trench" else None), instances
    threshold = threshold_otsu(smooth[region])
    mask = (smooth < threshold) & region
    mask = ndimage.binary_opening(mask)
    mask = remove_small_objects(mask, max_size=max(int(0.4 / px**2), 4))
    # Cells in phase contrast are separated by bright septa: the components of the
    # mask eroded by ~0.1 um (which breaks thin necks between touching cells) are the
    # markers of a watershed that grows them back inside the mask.
    from skimage.segmentation import watershed

    erode_px = max(round(0.1 / px), 1)
    markers, _ = ndimage.label(ndimage.binary_erosion(mask, iterations=erode_px))
    distance = ndimage.distance_transform_edt(mask)
    instances = watershed(-distance, markers, mask=mask)
    # Touching cells whose neck survived the erosion: split at bright septa.
    instances = _split_at_septa(instances, image, region, px)
    cells, widths = cells_from_instances(instances, px, max_cell_length_um)
    return cells, widths, (trench if geometry == "trench" else None), instances


#: Regions smaller than this are fragments, not cells (a 0.6 um sphere is 0.28 um^2).
MIN_CELL_AREA_UM2 = 0.25


def cut_by_edge(instances: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Whether each region of ``ids`` in an instance mask reaches the image's border
    (only its part in view is measured: :func:`~napari_symbac.fit.link_cells`)."""
    instances = np.asarray(instances)
    border = np.concatenate(
        [instances[0], instances[-1], instances[:, 0], instances[:, -1]]
    )
    return np.isin(np.asarray(ids), border[border > 0])


def cells_from_instances(
    instances: np.ndarray,
    pixel_size_um: float,
    max_cell_length_um: float = 4.0,
    *,
    keep_labels: bool = False,
) -> tuple[FrameCells, np.ndarray]:
    """One spherocylinder per region of an instance mask (region moments).

    Centroid, principal-axis angle, extent along the axis (length) and the width of
    the spherocylinder with the region's area and length (image coordinates, um).
    A region longer than ``max_cell_length_um`` is taken as several touching cells
    and starts as equal rods along its axis. Regions of fewer than 6 pixels or
    smaller than :data:`MIN_CELL_AREA_UM2` are left out (fragments).

    With ``keep_labels`` each cell's id is its region's label (one cell per region:
    ``max_cell_length_um`` must be infinite); otherwise ids are ``1..n``.

    Returns
    -------
    cells, widths
        The cells (sorted by ``y`` then ``x``) and their moment widths (um).
    """
    if keep_labels and math.isfinite(max_cell_length_um):
        raise ValueError("keep_labels keeps one cell per region: pass max_cell_length_um=inf")
    px = pixel_size_um
    rows_list = []
    instances = np.asarray(instances)
    for index, box in enumerate(ndimage.find_objects(instances.astype(np.int64)), start=1):
        if box is None:
            continue
        rr, cc = np.nonzero(instances[box] == index)
        rr, cc = rr + box[0].start, cc + box[1].start
        if rr.size < 6 or rr.size * px * px < MIN_CELL_AREA_UM2:
            continue
        x = (cc + 0.5) * px
        y = (rr + 0.5) * px
        cx, cy = x.mean(), y.mean()
        cov = np.cov(np.stack([x - cx, y - cy]))
        _evals, evecs = np.linalg.eigh(cov)
        vx, vy = evecs[:, 1]
        if vy < 0:
            vx, vy = -vx, -vy
        angle = math.atan2(vx, vy)
        along = (x - cx) * vx + (y - cy) * vy
        length = float(along.max() - along.min() + px)
        area = rr.size * px * px
        width = _spherocylinder_width(area, length)
        width = min(max(width, 2 * px), length)
        # A region much longer than a cell is several touching cells: start with
        # equal rods along its axis (the fit moves and sizes them).
        k = (
            max(math.ceil(length / (0.75 * max_cell_length_um)), 1)
            if length > max_cell_length_um
            else 1
        )
        for j in range(k):
            offset = (j + 0.5) * length / k - length / 2
            rows_list.append(
                (cx + offset * vx, cy + offset * vy, angle, max(length / k, width), width, index)
            )
    if not rows_list:
        raise ValueError("the start found no cells in the image (no region of 6 pixels or more)")
    rows_list.sort(key=lambda row: (row[1], row[0]))
    table = np.array(rows_list)
    cells = FrameCells(
        ids=table[:, 5].astype(np.int64) if keep_labels else np.arange(1, len(table) + 1),
        x_um=table[:, 0],
        y_um=table[:, 1],
        angle_rad=table[:, 2],
        length_um=table[:, 3],
        width_um=table[:, 4],
    )
    return cells, table[:, 4].copy()


def polarity_of(
    image: np.ndarray, modality: str, labels: np.ndarray | None = None
) -> Literal["dark", "bright"]:
    """Whether cells are darker or brighter than their surroundings.

    From painted labels when they hold both cells (1) and media (2): the sign of the
    difference of the class medians. Otherwise from the modality: phase contrast
    shows dark cells, fluorescence bright ones; bright field dark ones (absorption; the
    automatic start segments its cells on their contrast either way,
    :func:`brightfield_instances`).
    """
    if labels is not None:
        cell, media = labels == 1, labels == 2
        if cell.any() and media.any():
            return "dark" if np.median(image[cell]) < np.median(image[media]) else "bright"
    if modality == "fluorescence":
        return "bright"
    if modality in ("phase", "brightfield"):
        return "dark"
    raise ValueError(f"unknown modality {modality!r}: paint cells and media to give the polarity")


#: The widest rod-shaped bacterium a start may find (um). Rods are 0.4-2 um wide
#: (B. megaterium, among the widest, ~1.5 um; Otsu widths run narrow, section 1.3);
#: a start cell wider than this is several touching cells taken as one region, or the
#: image is read at the wrong pixel size.
MAX_START_WIDTH_UM = 3.0
#: The share of such cells at which a start is refused: the automatic start of the
#: three Omnipose colonies (at 1 um per median mask width) has 46-100 % of its cells
#: wider than :data:`MAX_START_WIDTH_UM`, the SyMBac and DeLTA trenches and the
#: ColiCoords fields none; a clump or a blob of debris among sparse cells is one cell.
MAX_BLOB_SHARE = 0.25


class WideStartError(ValueError):
    """The automatic start found cells wider than any rod (:func:`refuse_blobs`).

    ``cause`` says what was found and why; the message adds the fix of an interface
    that takes masks. One that takes none (diagnose) words its own from ``cause``.
    """

    def __init__(self, cause: str) -> None:
        self.cause = cause
        super().__init__(
            f"{cause}; give the cells' instance masks (e.g. from Omnipose or Cellpose): a "
            "dense phase-contrast colony is then fitted with its own model"
        )


class FaintStartError(ValueError):
    """The automatic start of bright cells found none (:func:`otsu_cells`).

    ``cause`` says how far the brightest region stands out; the message adds the fix
    in general words, each interface words its own from ``cause`` (the CLI's flags, a
    dock's layers).
    """

    def __init__(self, cause: str) -> None:
        self.cause = cause
        super().__init__(f"{cause}; give the cells' instance masks or painted labels")


def too_wide(widths_um: np.ndarray) -> bool:
    """Whether cells of these widths (um) are wider than any rod: at least
    :data:`MAX_BLOB_SHARE` of them wider than :data:`MAX_START_WIDTH_UM` (the rule of
    :func:`refuse_blobs`, and of calibrate's cells from masks or a fit)."""
    widths_um = np.asarray(widths_um, np.float64)
    return bool(widths_um.size) and float(np.mean(widths_um > MAX_START_WIDTH_UM)) >= MAX_BLOB_SHARE


def refuse_blobs(widths_um: np.ndarray, pixel_size_um: float) -> None:
    """Refuse an automatic start whose cells are wider than any rod.

    Such a start is a colony's touching cells seen as a few wide regions (Otsu of a
    dense phase-contrast colony takes ~90 % of the frame) or an image read at too
    large a pixel size; a fit from it runs long and ends with a handful of cells.

    Raises
    ------
    WideStartError
        When at least :data:`MAX_BLOB_SHARE` of the cells are wider than
        :data:`MAX_START_WIDTH_UM`; the message names both causes.
    """
    widths_um = np.asarray(widths_um, np.float64)
    if not too_wide(widths_um):
        return
    wide = widths_um > MAX_START_WIDTH_UM
    raise WideStartError(
        f"{int(wide.sum())} of the {widths_um.size} cells the automatic start found are "
        f"wider than any rod-shaped bacterium (over {MAX_START_WIDTH_UM:g} um; median "
        f"{float(np.median(widths_um[wide])):.1f} um): the cells touch in a colony that "
        f"the start cannot separate, or the pixel size ({pixel_size_um:g} um) is too large"
    )


#: An automatic start of at least this many cells is judged by what the fit keeps of it:
#: half or fewer, the rest removed as explaining the image no better than its background
#: (BIC), and the start's cells were not the image's. Found as a user: a 64 x 64 px
#: window of the Omnipose colony Sample000033 started with 13 rods across its touching
#: cells and ended with 2, exit 0.
MIN_START_JUDGED = 4


def refuse_a_start_mostly_removed(n_start: int, n_removed: int, n_kept: int) -> None:
    """Refuse a fit that removed half or more of its automatic start's cells and kept
    half or fewer (cells it added count among those kept and removed).

    Raises
    ------
    WideStartError
        When ``n_start >= MIN_START_JUDGED``, ``2 n_removed >= n_start`` and ``2 n_kept
        <= n_start``; its ``cause`` says how many were kept and why that means the start
        was wrong.
    """
    if n_start < MIN_START_JUDGED or 2 * n_removed < n_start or 2 * n_kept > n_start:
        return
    raise WideStartError(
        f"the fit kept {n_kept} of the {n_start} cells its automatic start found, the "
        "others explaining the image no better than its background: the start's cells "
        "are not the image's, as where touching cells in a colony cannot be told apart "
        "or a textured background is taken for cells"
    )


def refuse_wide_cells(widths_um: np.ndarray, whose: str, pixel_note: str, fix: str = "") -> None:
    """Refuse given cells (masks', or a fit's) wider than any rod (:func:`too_wide`, the
    automatic start's rule): the pixel size is too large. Found as a user: 0.8 um for
    ColiCoords' 0.08 um made cells 15 um wide, fitted at their bounds, exit 0.

    Raises
    ------
    ValueError
        Naming ``whose`` cells, their median width, the pixel size and where it came
        from (``pixel_note``), and the fix (``fix``: the caller's other way, if any).
    """
    widths_um = np.asarray(widths_um, np.float64)
    if not too_wide(widths_um):
        return
    raise ValueError(
        f"{whose} are {float(np.median(widths_um)):.1f} um wide (median), wider than any "
        f"rod-shaped bacterium (over {MAX_START_WIDTH_UM:g} um): the pixel size is too "
        f"large ({pixel_note}). Check pixel_size_um (um in the sample: the camera pixel / "
        f"magnification, 6.5 um / 100x = 0.065){fix}"
    )


def start_scene(
    image: np.ndarray,
    microscope: Microscope,
    *,
    geometry: Literal["trench", "open"] = "trench",
    labels: np.ndarray | None = None,
    masks: np.ndarray | None = None,
    trench: TrenchPlacement | None = None,
    depth_um: float = 1.2,
    valid: np.ndarray | None = None,
    max_cell_length_um: float = 4.0,
    refuse_wide: bool = True,
) -> tuple[FrameCells, np.ndarray, TrenchPlacement | None, np.ndarray]:
    """The starting cells of a scene fit, from a mask, painted labels or the image.

    Parameters
    ----------
    image
        The real frame (ADU).
    microscope
        Pixel size and modality (which gives the polarity without labels).
    geometry
        ``"trench"`` or ``"open"``.
    labels
        Painted classes (1 cell, 2 media, 3 device, 0 unpainted): rough strokes. They
        give the polarity (cells darker or brighter than media); the cells come from
        the automatic segmentation (bright cells measured against the painted media),
        less any region that lies mostly on painted media or device. Paint whole
        cells? Pass them as ``masks``.
    masks
        Instance mask (0 background, one integer per cell), or a binary mask whose
        connected components are the cells. Used as given (no split).
    trench
        Trench placement; found from the image (phase) when ``None``.
    depth_um, valid, max_cell_length_um
        As in :func:`otsu_cells`.
    refuse_wide
        Refuse a start whose cells are wider than any rod (without ``masks``:
        :func:`refuse_blobs`; with them: :func:`refuse_wide_cells`, the pixel size is too
        large); ``False`` where the caller starts from other cells (a series fit's
        previous frame) and takes only the trench from here.

    Returns
    -------
    cells, widths, trench, instances
        As :func:`otsu_cells`.

    Raises
    ------
    WideStartError
        Without ``masks``, when the cells found are wider than any rod
        (:func:`refuse_blobs`) and ``refuse_wide``.
    ValueError
        With ``masks``, when their cells are wider than any rod
        (:func:`refuse_wide_cells`) and ``refuse_wide``.
    FaintStartError
        Without ``masks``, when no bright cell stands out of the background
        (fluorescence).
    ValueError
        Without ``masks`` or ``labels``, when the image holds nothing but noise
        (:func:`refuse_blank`; painted classes say where faint cells are).
    """
    if masks is None and labels is None:
        refuse_blank(image, valid)
    polarity = polarity_of(image, microscope.modality, labels)
    px = microscope.pixel_size_um
    if microscope.modality == "brightfield" and masks is None and geometry == "open":
        media = None if labels is None else np.asarray(labels) == 2
        instances = brightfield_instances(image, px, media, valid)
        if labels is not None:
            instances = _off_painted_empty(instances, np.asarray(labels))
        if not instances.any():
            raise ValueError(
                "the start found no cells in the image: nothing departs from its background "
                "more than its noise does"
            )
        cells, widths = cells_from_instances(instances, px, max_cell_length_um)
        if refuse_wide:
            refuse_blobs(widths, px)
        return cells, widths, None, instances
    if masks is None and labels is None:
        start = otsu_cells(
            image,
            microscope,
            geometry=geometry,
            depth_um=depth_um,
            max_cell_length_um=max_cell_length_um,
            polarity=polarity,
            trench=trench,
            valid=valid,
        )
        if refuse_wide and too_wide(start[1]) and geometry == "open" and polarity == "dark":
            refuse_trenches_in_a_field(image, px)
        if refuse_wide:
            refuse_blobs(start[1], px)
        return start
    found = trench
    if geometry == "trench" and trench is None:
        if polarity == "bright":
            raise ValueError(
                "a fluorescence image shows no trench walls to find: pass "
                "trench=TrenchPlacement(...) or geometry='open'"
            )
        found = otsu_cells(image, microscope, geometry="trench", depth_um=depth_um)[2]
    if geometry == "open":
        found = None
    if masks is not None:
        masks = np.asarray(masks)
        if masks.shape != image.shape:
            raise ValueError(f"masks of shape {masks.shape} do not match the image {image.shape}")
        instances = as_instance_ids(masks)[0].astype(np.int64)
        # an instance mask keeps its cells as they are: no rods split off long regions
        cells, widths = cells_from_instances(instances, px, max_cell_length_um=math.inf)
        if refuse_wide:
            refuse_wide_cells(widths, "the masks' cells", f"pixel size {px:g} um")
        return cells, widths, found, instances
    # Painted classes are rough strokes, not outlines: they give the polarity (above)
    # and say where no cell is; the cells themselves come from the image.
    labels = np.asarray(labels)
    cells, widths, _, instances = otsu_cells(
        image,
        microscope,
        geometry=geometry,
        depth_um=depth_um,
        max_cell_length_um=max_cell_length_um,
        polarity=polarity,
        trench=found,
        valid=valid,
        background=labels == 2,
        painted_cells=labels == 1,
    )
    kept = _off_painted_empty(instances, labels)
    if kept is not instances:
        instances = kept
        cells, widths = cells_from_instances(instances, px, max_cell_length_um)
    if refuse_wide:
        refuse_blobs(widths, px)
    return cells, widths, found, instances


def brightfield_instances(
    image: np.ndarray,
    pixel_size_um: float,
    media: np.ndarray | None = None,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Instance labels of the cells of a bright-field field, for the start.

    A cell out of focus is a bright centre in a dark rim (or the reverse), and where the
    two cancel its centre line can sit at the background's level, so neither a dark nor
    a bright threshold finds it whole. Its departure from the background, ``|I - b|``
    of the image smoothed by 1 px and smoothed again by 1 px, is thresholded (Otsu)
    and its holes filled: one region per cell, split where touching cells meet by the
    watershed :func:`otsu_cells` uses. ``b`` is the median of the painted ``media``
    when given, else of the (``valid``) image (cells cover a small part of a field).
    The region reaches past the cell by its rim: :func:`~napari_symbac.fit.scene_fit.
    fit_scene` tries narrower starts.
    """
    from skimage.filters import threshold_otsu
    from skimage.morphology import remove_small_objects
    from skimage.segmentation import watershed

    px = pixel_size_um
    frame = ndimage.gaussian_filter(np.asarray(image, np.float64), 1.0)
    usable = np.ones(frame.shape, bool) if valid is None else np.asarray(valid, bool)
    source = media & usable if media is not None and (media & usable).any() else usable
    departure = ndimage.gaussian_filter(np.abs(frame - float(np.median(frame[source]))), 1.0)
    if not np.ptp(departure[usable]) > 0:
        return np.zeros(frame.shape, np.int64)
    mask = (departure > threshold_otsu(departure[usable])) & usable
    mask = ndimage.binary_opening(ndimage.binary_fill_holes(mask))
    mask = remove_small_objects(mask, max_size=max(int(0.4 / px**2), 4))
    erode_px = max(round(0.1 / px), 1)
    markers, _ = ndimage.label(ndimage.binary_erosion(mask, iterations=erode_px))
    distance = ndimage.distance_transform_edt(mask)
    return np.asarray(watershed(-distance, markers, mask=mask), np.int64)


def _off_painted_empty(instances: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``instances`` without the regions lying over half on painted media or device (2, 3:
    rough strokes say where no cell is), renumbered; ``instances`` itself when none
    does."""
    empty = (labels == 2) | (labels == 3)
    on_empty = ndimage.mean(empty, instances, np.arange(1, int(instances.max()) + 1))
    dropped = np.flatnonzero(np.asarray(on_empty) > 0.5) + 1
    if not dropped.size:
        return instances
    return _renumber(np.where(np.isin(instances, dropped), 0, instances))


def _renumber(instances: np.ndarray) -> np.ndarray:
    """Instance labels ``1..n`` in order of their old values (0 stays background)."""
    values = np.unique(instances)
    values = values[values > 0]
    lookup = np.zeros(int(instances.max()) + 1, instances.dtype)
    lookup[values] = np.arange(1, values.size + 1, dtype=instances.dtype)
    return lookup[instances]
