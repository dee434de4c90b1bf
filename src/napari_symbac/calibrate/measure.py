"""What a real image with instance masks says about its cells, model-free.

Sizes (pole-to-pole length, width) of every mask region, the per-cell brightness
above the background, the layout of the field (clusters of touching cells, their
sizes and the cell density) and the pixel noise of the background. These are the
numbers a user would otherwise read off the image by hand to match a simulation to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from napari_symbac.export.outline import border_ids
from napari_symbac.export.visibility import pixel_noise
from napari_symbac.fit.masks import cell_widths_px

__all__ = [
    "ColonyPacking",
    "DebrisMeasurements",
    "FieldMeasurements",
    "TextureMeasurements",
    "cell_curvatures_px",
    "instance_masks",
    "lengths_px",
    "measure_debris",
    "measure_field",
    "measure_packing",
    "measure_texture",
]


def instance_masks(masks: np.ndarray) -> np.ndarray:
    """Instance ids of ``masks``: a binary mask (0/1, boolean, 0/255) is split into its
    connected regions, an instance mask is kept (ids need not be consecutive;
    :func:`~napari_symbac.fit.preflight.as_instance_ids`).
    """
    from napari_symbac.fit.preflight import as_instance_ids

    return as_instance_ids(masks)[0].astype(np.int32)


def lengths_px(labels: np.ndarray) -> np.ndarray:
    """Pole-to-pole length of every region: its largest Feret diameter plus one pixel
    (the diameter joins pixel centres; the outline lies half a pixel beyond each).
    """
    from skimage.measure import regionprops

    return np.array([r.feret_diameter_max + 1.0 for r in regionprops(labels)])


@dataclass(frozen=True)
class FieldMeasurements:
    """Model-free measurements of a real field and its instance masks.

    Attributes
    ----------
    shape
        Image shape (rows, columns).
    lengths_px, widths_px
        Pole-to-pole length and width of every cell region, pixels.
    brightness_adu
        Median of each cell region minus the background median (ADU; negative for
        dark cells in phase contrast).
    cells_median_adu, background_median_adu
        Medians over all cell pixels and over background pixels (at least
        ``far_px`` from every cell).
    noise_adu
        Robust pixel noise of the background (:func:`~napari_symbac.export.visibility.pixel_noise`).
    cluster_sizes
        Cells in each cluster (cells closer than ``touch_px`` belong to one cluster).
    cell_area_fraction
        Fraction of the image that is cell.
    whole
        Per cell: ``True`` unless the image's border cuts it. A cut cell counts in the
        layout, but its length, width and brightness are a sliver's, so sizes and the
        brightness spread are read from the whole cells (:meth:`of_whole_cells`).
    """

    shape: tuple[int, int]
    lengths_px: np.ndarray = field(repr=False)
    widths_px: np.ndarray = field(repr=False)
    brightness_adu: np.ndarray = field(repr=False)
    cells_median_adu: float
    background_median_adu: float
    noise_adu: float
    cluster_sizes: np.ndarray = field(repr=False)
    cell_area_fraction: float
    whole: np.ndarray = field(repr=False)

    @property
    def n_cells(self) -> int:
        """Number of cell regions."""
        return int(self.lengths_px.size)

    def of_whole_cells(self, values: np.ndarray) -> np.ndarray:
        """The entries of a per-cell array (``lengths_px``, ``widths_px``,
        ``brightness_adu``) that belong to cells the border does not cut; all of them
        when the border cuts every cell."""
        return values[self.whole] if self.whole.any() else values

    @property
    def brightness_cv(self) -> float:
        """Coefficient of variation of the whole cells' brightness above the background."""
        b = np.abs(self.of_whole_cells(self.brightness_adu))
        if b.size < 2 or b.mean() <= 0:
            return 0.0
        return float(b.std(ddof=1) / b.mean())

    def summary(self, pixel_size_um: float, modality: str = "fluorescence") -> str:
        """One line: cell count, sizes in um, brightness (fluorescence: a phase-contrast
        cell's level above the background is no brightness of its own, and its spread
        near 0 made a meaningless CV, 1.09 on an Omnipose colony), layout."""
        px = pixel_size_um
        brightness = (
            f"brightness CV {self.brightness_cv:.2f}; " if modality == "fluorescence" else ""
        )
        lengths, widths = self.of_whole_cells(self.lengths_px), self.of_whole_cells(self.widths_px)
        return (
            f"{self.n_cells} cells; length {np.median(lengths) * px:.2f} um "
            f"(IQR {np.percentile(lengths, 25) * px:.2f}-"
            f"{np.percentile(lengths, 75) * px:.2f}), width "
            f"{np.median(widths) * px:.2f} um; {brightness}"
            f"{self.cluster_sizes.size} cluster(s), median {np.median(self.cluster_sizes):.0f} "
            f"cell(s), largest {int(self.cluster_sizes.max())}; cells cover "
            f"{100 * self.cell_area_fraction:.1f} % of the image"
        )


def _checked(
    image: np.ndarray, masks: np.ndarray, valid: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``image`` as float64, the instance labels of ``masks`` and the usable pixels.

    Raises
    ------
    ValueError
        Shapes differ or the masks hold no cell.
    """
    image = np.asarray(image, np.float64)
    labels = instance_masks(masks)
    if image.ndim != 2 or labels.shape != image.shape:
        raise ValueError(
            f"image {image.shape} and masks {labels.shape} must be 2D of one shape"
        )
    if not (labels > 0).any():
        raise ValueError("the masks hold no cell (all 0): give the masks of this image")
    ok = np.ones(image.shape, bool) if valid is None else np.asarray(valid, bool)
    return image, labels, ok


def cluster_sizes(labels: np.ndarray, touch_px: int = 2) -> np.ndarray:
    """Cells in each cluster of ``labels`` (instance labels, 0 background): cells whose
    regions come within ``touch_px`` pixels of each other form one cluster."""
    cells = labels > 0
    grown = ndimage.binary_dilation(cells, iterations=max(1, math.ceil(touch_px / 2)))
    clusters, n_clusters = ndimage.label(grown)
    return np.array(
        [np.unique(labels[(clusters == c) & cells]).size for c in range(1, n_clusters + 1)],
        dtype=np.int64,
    )


def measure_field(
    image: np.ndarray,
    masks: np.ndarray,
    *,
    far_px: float = 6.0,
    touch_px: int = 2,
    valid: np.ndarray | None = None,
) -> FieldMeasurements:
    """Measure a real field against its instance masks (module notes).

    Parameters
    ----------
    image
        The real 2D image (ADU).
    masks
        Its instance masks (0 background; a 0/1 mask is split into connected regions).
    far_px
        Background pixels are at least this far from every cell.
    touch_px
        Cells whose regions come within this many pixels of each other form a cluster.
    valid
        Pixels to use in the intensity measurements (False: censored, e.g. clipped or
        zeroed by a background subtraction); default all.

    Raises
    ------
    ValueError
        Shapes differ, no cell, or no background pixel far from the cells.
    """
    image, labels, ok = _checked(image, masks, valid)
    cells = labels > 0
    distance = ndimage.distance_transform_edt(~cells)
    far = (distance >= far_px) & ok
    while far.sum() < 10 and far_px > 1:  # a dense colony: its gaps are the background
        far_px = max(1.0, far_px / 2)
        far = (distance >= far_px) & ok
    if far.sum() < 10:
        raise ValueError(
            "fewer than 10 pixels lie outside every cell: the masks "
            "cover the image; give a field with some background"
        )
    background = float(np.median(image[far]))
    ids = [i for i in np.unique(labels) if i > 0]
    relabelled = np.zeros_like(labels)
    for new, old in enumerate(ids, start=1):
        relabelled[labels == old] = new
    brightness = np.array(
        [
            float(np.median(image[(relabelled == k) & ok] if ((relabelled == k) & ok).any()
                            else image[relabelled == k])) - background
            for k in range(1, len(ids) + 1)
        ]
    )
    sizes = cluster_sizes(relabelled, touch_px)
    inside = ok & cells
    return FieldMeasurements(
        shape=(int(image.shape[0]), int(image.shape[1])),
        lengths_px=lengths_px(relabelled),
        widths_px=cell_widths_px(relabelled),
        brightness_adu=brightness,
        cells_median_adu=float(np.median(image[inside] if inside.any() else image[cells])),
        background_median_adu=background,
        noise_adu=pixel_noise(image, far),
        cluster_sizes=sizes,
        cell_area_fraction=float(cells.mean()),
        whole=~np.isin(np.arange(1, len(ids) + 1), border_ids(relabelled)),
    )


@dataclass(frozen=True)
class DebrisMeasurements:
    """Unlabelled bright blobs of a fluorescence field (:func:`measure_debris`).

    Attributes
    ----------
    n_blobs
        Blobs found outside the dilated masks.
    free_area_um2
        Area searched (outside the dilated masks, valid pixels), um^2.
    diameters_um
        Diameter of each blob: that of a disk of its area above half its peak.
    peaks_adu
        Peak of each blob above the background (smoothed image), ADU.
    blur_sigma_um
        Gaussian blur of each blob beyond that of a disk of its diameter: the square
        root of its intensity-weighted variance per axis minus ``r^2 / 4`` (0 when
        negative), before the image's own PSF and defocus are taken off.
    """

    n_blobs: int
    free_area_um2: float
    diameters_um: np.ndarray = field(repr=False)
    peaks_adu: np.ndarray = field(repr=False)
    blur_sigma_um: np.ndarray = field(repr=False)

    @property
    def density_per_100um2(self) -> float:
        """Blobs per 100 um^2 of the area searched."""
        return 100.0 * self.n_blobs / self.free_area_um2 if self.free_area_um2 > 0 else 0.0


def measure_debris(
    image: np.ndarray,
    masks: np.ndarray,
    pixel_size_um: float,
    *,
    valid: np.ndarray | None = None,
    gap_px: int = 4,
    smooth_px: float = 1.0,
    min_area_px: int = 4,
) -> DebrisMeasurements:
    """Find the bright blobs a fluorescence field shows outside its masks.

    The image is smoothed (Gaussian ``smooth_px``); a blob is a connected region above
    ``background + max(5 noise, 0.1 median cell brightness)`` (background median and
    noise of the smoothed image over pixels far from the cells, robust) that lies
    entirely more than ``gap_px`` from every mask, covers at least ``min_area_px``
    pixels and at most half the median cell's area (a larger one is an unannotated
    cell, not debris).

    Parameters
    ----------
    image, masks
        The field (ADU) and its instance masks (or the fit's cells).
    pixel_size_um
        Camera pixel size.
    valid
        Pixels that may be used (False: censored); default all.

    Raises
    ------
    ValueError
        Shapes differ or the masks hold no cell.
    """
    image, labels, ok = _checked(image, masks, valid)
    cells = labels > 0
    smooth = ndimage.gaussian_filter(image, smooth_px)
    free = (ndimage.distance_transform_edt(~cells) > gap_px) & ok
    background = float(np.median(smooth[free]))
    noise = float(1.4826 * np.median(np.abs(smooth[free] - background)))
    cell_level = float(np.median(smooth[cells & ok] if (cells & ok).any() else smooth[cells]))
    threshold = background + max(5.0 * noise, 0.1 * (cell_level - background))
    regions, n = ndimage.label(smooth > threshold)
    cell_area = float(np.median(np.bincount(labels[cells])[np.unique(labels[cells])]))
    sizes = np.bincount(regions.ravel(), minlength=n + 1)
    touching = np.unique(regions[~free & (regions > 0)])
    keep = np.ones(n + 1, bool)
    keep[0] = False
    keep[touching] = False
    keep &= (sizes >= min_area_px) & (sizes <= 0.5 * cell_area)
    diameters, peaks, blurs = [], [], []
    above = smooth - background
    for index in np.flatnonzero(keep):
        region = regions == index
        values = above[region]
        peak = float(values.max())
        half = region & (above >= 0.5 * peak)
        radius_px = math.sqrt(half.sum() / math.pi)
        rows, cols = np.nonzero(region)
        w = np.clip(values, 0, None)
        r0, c0 = np.average(rows, weights=w), np.average(cols, weights=w)
        var = 0.5 * np.average((rows - r0) ** 2 + (cols - c0) ** 2, weights=w)
        blur2 = var - radius_px**2 / 4 - smooth_px**2
        diameters.append(2 * radius_px * pixel_size_um)
        peaks.append(peak)
        blurs.append(math.sqrt(max(blur2, 0.0)) * pixel_size_um)
    return DebrisMeasurements(
        n_blobs=len(peaks),
        free_area_um2=float(free.sum()) * pixel_size_um**2,
        diameters_um=np.array(diameters),
        peaks_adu=np.array(peaks),
        blur_sigma_um=np.array(blurs),
    )


@dataclass(frozen=True)
class ColonyPacking:
    """How tightly the cells of a field's colonies are packed (:func:`measure_packing`).

    Attributes
    ----------
    cell_fraction
        Cell area over colony area, pooled over the colonies of at least ``min_cells``
        cells; a colony is the cells closed by a disk of half the median cell width,
        holes filled (so the thin seams and small gaps inside count as colony, the pad
        around it does not). NaN without such a colony.
    gaps_px
        For every pair of neighbouring cells (another cell less than half the median
        cell width from a cell's outline), the background between them where they
        come closest, pixels: the distance from the outline to the nearest pixel of
        the other cell minus one (0: the labels touch). Each pair counts twice.
    width_px
        Median cell width (:func:`~napari_symbac.fit.masks.cell_widths_px`).
    n_colonies
        Colonies of at least ``min_cells`` cells.
    """

    cell_fraction: float
    gaps_px: np.ndarray = field(repr=False)
    width_px: float
    n_colonies: int

    @property
    def mean_gap_px(self) -> float:
        """Mean seam width between neighbouring cells, pixels (NaN without any)."""
        return float(self.gaps_px.mean()) if self.gaps_px.size else math.nan

    @property
    def touching_fraction(self) -> float:
        """Fraction of the neighbouring pairs whose labels touch (no background seam)."""
        return float((self.gaps_px == 0).mean()) if self.gaps_px.size else 0.0


@dataclass(frozen=True)
class TextureMeasurements:
    """The background's texture (:func:`measure_texture`).

    Attributes
    ----------
    rms_adu
        Standard deviation of the texture (ADU): the background's autocovariance at a
        lag of one pixel, blind to white pixel noise.
    correlation_px
        Lag (camera px) at which the autocovariance falls to ``1/e`` of that.
    noise_adu
        The white pixel noise beside it (ADU; lag 0 less lag 1).
    """

    rms_adu: float
    correlation_px: float
    noise_adu: float


def measure_texture(
    image: np.ndarray,
    masks: np.ndarray,
    pixel_size_um: float,
    *,
    valid: np.ndarray | None = None,
    gap_um: float = 1.2,
    trend_um: float = 3.0,
) -> TextureMeasurements | None:
    """The texture of a field's background: the pad's mottling between the cells.

    Over the valid pixels more than ``gap_um`` from every mask, with the background's
    trend (a plane fitted by least squares, then a Gaussian of ``trend_um``, normalised
    to those pixels) taken off, the autocovariance is computed by FFT and normalised by
    the number of pixel pairs at each lag. White pixel noise adds to lag 0 only, so the
    texture's variance is the mean of the lags (0, 1) and (1, 0), and its correlation
    length the lag along rows and columns where that mean first falls to ``1/e`` of it
    (linear between lags).
    Found calibrating ColiCoords' bright field: networks trained on a clean synthetic
    pad called the real pad's 0.3-1 um patches cells (docs/proof.md). ``None`` when the
    texture's variance is under 5 % of the pixel noise's, or fewer than 1000 background
    pixels remain.
    """
    image, labels, ok = _checked(image, masks, valid)
    gap_px = max(1, round(gap_um / pixel_size_um))
    background = ok & ~ndimage.binary_dilation(labels > 0, iterations=gap_px)
    if background.sum() < 1000:
        return None
    weight = background.astype(np.float64)
    rows_i, cols_i = np.nonzero(background)
    plane = np.column_stack([np.ones(rows_i.size), rows_i, cols_i])
    coef = np.linalg.lstsq(plane, image[background], rcond=None)[0]
    yy, xx = np.indices(image.shape)
    image = image - (coef[0] + coef[1] * yy + coef[2] * xx)  # a lamp's gradient
    sigma = trend_um / pixel_size_um
    trend = ndimage.gaussian_filter(image * weight, sigma) / np.maximum(
        ndimage.gaussian_filter(weight, sigma), 1e-12
    )
    residual = (image - trend) * weight
    residual[background] -= residual[background].mean()
    rows, cols = image.shape
    shape = (2 * rows, 2 * cols)  # zero-padded: no wrap-around
    f = np.fft.rfft2(residual, shape)
    w = np.fft.rfft2(weight, shape)
    pairs = np.fft.irfft2(w * np.conj(w), shape)
    cov = np.fft.irfft2(f * np.conj(f), shape) / np.maximum(pairs, 1.0)
    max_lag = min(rows, cols) // 4
    lags = np.array([(cov[0, k] + cov[k, 0]) / 2 for k in range(max_lag)])
    texture_var = float(lags[1])
    noise_var = float(lags[0] - lags[1])
    if not (texture_var > 0.05 * max(noise_var, 1e-12)):
        return None
    below = np.flatnonzero(lags[1:] <= texture_var / math.e)
    if below.size:
        k = int(below[0]) + 1  # lags[k] <= var / e < lags[k - 1]
        high, low = lags[k - 1], lags[k]
        correlation = (k - 1) + (high - texture_var / math.e) / max(high - low, 1e-12)
    else:
        correlation = float(max_lag)
    return TextureMeasurements(
        rms_adu=math.sqrt(texture_var),
        correlation_px=float(max(correlation, 1.0)),
        noise_adu=math.sqrt(max(noise_var, 0.0)),
    )


def _disk(radius: int) -> np.ndarray:
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    return yy**2 + xx**2 <= radius**2


def measure_packing(masks: np.ndarray, *, min_cells: int = 5) -> ColonyPacking:
    """Cell-area fraction of the colonies and the seams between touching cells.

    Parameters
    ----------
    masks
        Instance masks (0 background; a 0/1 mask is split into connected regions:
        touching cells then count as one).
    min_cells
        Smallest cluster counted as a colony in ``cell_fraction``.

    Raises
    ------
    ValueError
        The masks hold no cell.
    """
    labels = instance_masks(masks)
    cells = labels > 0
    if not cells.any():
        raise ValueError("the masks hold no cell (all 0): give the masks of this image")
    width = float(np.median(cell_widths_px(labels)))
    radius = max(1, round(width / 2))
    padded = np.pad(cells, radius + 1)
    closed = ndimage.binary_closing(padded, _disk(radius))[
        radius + 1 : -radius - 1, radius + 1 : -radius - 1
    ]
    colonies, _ = ndimage.label(ndimage.binary_fill_holes(closed | cells))
    cell_area = colony_area = 0
    n_colonies = 0
    for index, box in enumerate(ndimage.find_objects(colonies), start=1):
        region = colonies[box] == index
        ids = np.unique(labels[box][region])
        if np.count_nonzero(ids) >= min_cells:
            n_colonies += 1
            cell_area += int((region & cells[box]).sum())
            colony_area += int(region.sum())
    reach = math.ceil(width)
    gaps = []
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        grown = tuple(
            slice(max(0, s.start - reach), min(size, s.stop + reach))
            for s, size in zip(box, labels.shape, strict=True)
        )
        window = labels[grown]
        own = window == index
        others = (window > 0) & ~own
        if not others.any():
            continue
        edge = own & ~ndimage.binary_erosion(own)
        distance, (rows, cols) = ndimage.distance_transform_edt(~others, return_indices=True)
        gap = distance[edge] - 1.0
        near = gap < width / 2
        neighbour = window[rows[edge][near], cols[edge][near]]
        for other in np.unique(neighbour):
            gaps.append(float(gap[near][neighbour == other].min()))
    return ColonyPacking(
        cell_fraction=cell_area / colony_area if colony_area else math.nan,
        gaps_px=np.array(gaps),
        width_px=width,
        n_colonies=n_colonies,
    )


def cell_curvatures_px(masks: np.ndarray) -> np.ndarray:
    """Curvature (1 / radius, per pixel) of every cell's centre line.

    The region's pixels are rotated onto their principal axis and a parabola
    ``v = a u^2 + b u + c`` is fitted to the middle of the region across it at each
    ``u`` (the mean ``v`` of the column of pixels); the curvature at the vertex is
    ``2 |a|``. A straight rod gives 0 (to within the pixel grid); eq. 1 bends a cell
    of length ``L`` into an arc of radius ``R``: ``2 |a| = 1 / R``.
    """
    labels = instance_masks(masks)
    out = []
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        rows, cols = np.nonzero(labels[box] == index)
        if rows.size < 6:
            out.append(0.0)
            continue
        points = np.stack([rows, cols], 1).astype(np.float64)
        points -= points.mean(0)
        _, vectors = np.linalg.eigh(points.T @ points)
        u, v = points @ vectors[:, 1], points @ vectors[:, 0]
        bins = np.round(u).astype(int)
        keys, inverse = np.unique(bins, return_inverse=True)
        if keys.size < 3:
            out.append(0.0)
            continue
        middle = np.bincount(inverse, weights=v) / np.bincount(inverse)
        a = np.polyfit(keys.astype(np.float64), middle, 2)[0]
        out.append(2.0 * abs(float(a)))
    return np.array(out)
