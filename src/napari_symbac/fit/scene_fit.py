"""Scene fitting by analysis by synthesis (issue 5, item 4).

Place and size spherocylinder cells (centre, angle, length, curvature, one shared or
hierarchical width) and the trench (left wall, width, closed end) so that the
rendered image overlays the real recording pixel for pixel, jointly with the
optical parameters. Starts from a plain segmentation of the real image (Otsu
threshold, watershed, region moments). For every geometry and kernel the
intensities are solved exactly by non-negative least squares (eq. 3 is linear in
them); the noise weights follow the camera model (eq. 17) by iteratively
reweighted least squares.

Coordinates of fitted cells are in micrometres from the top-left corner of the
image (x along columns, y down the rows), angle as in
:class:`~napari_symbac.sim.FrameCells` (0 = vertical).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import ndimage

from napari_symbac.fit.inputs import as_label_stack, as_single_image
from napari_symbac.fit.objectives import objective_terms
from napari_symbac.fit.parameters import (
    _SCALE,
    _Budget,
    _nnls,
    _variance,
    parameter_bounds,
)
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import Field, Scene, draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

__all__ = [
    "SceneFit",
    "TrenchPlacement",
    "fit_scene",
    "otsu_cells",
]

_INTENSITIES = ("cell_intensity", "media_intensity", "device_intensity")
#: Finite-difference step in scaled units (0.3 x 0.05 um = 15 nm, ~ 2/3 of a render
#: pixel): the chord ``2 sqrt(r^2 - d^2)`` has a square-root cusp at a cell's edge, so
#: steps much smaller than a render pixel give a Jacobian that only sees the cusp.
DIFF_STEP = 0.3
#: ``b`` and ``c`` of eq. 1 for fitted curvature: ``roll(l) = a sin(pi l / b + c)`` with
#: ``l`` the fraction of the cell length from its top pole, so ``b = 1, c = 0`` is one
#: symmetric bend (a crescent, the middle displaced by ``a`` from the poles' line).
#: Only the amplitude ``a`` is fitted: at 65 nm pixels a sub-pixel bend of a ~2.5 um
#: cell does not tell ``b`` and ``c`` apart from ``a``, the centre and the angle.
CURVATURE_B = 1.0
CURVATURE_C = 0.0


@dataclass(frozen=True)
class TrenchPlacement:
    """Where the trench lies in the image (um from the image's top-left corner).

    Attributes
    ----------
    left_um
        Position of the left wall.
    width_um
        Trench width.
    top_um
        Position of the closed end (negative: above the image).
    depth_um
        Optical depth of the trench (``s_media``; not fitted).
    closed_end
        ``"square"`` or ``"round"`` (a semicircle of diameter ``width_um``), as
        :attr:`TrenchGeometry.closed_end`; not fitted.
    """

    left_um: float
    width_um: float
    top_um: float
    depth_um: float = 1.2
    closed_end: Literal["square", "round"] = "square"

    def __post_init__(self) -> None:
        for name in ("left_um", "width_um", "top_um", "depth_um"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"TrenchPlacement.{name} must be finite")
            object.__setattr__(self, name, value)
        if self.width_um <= 0 or self.depth_um <= 0:
            raise ValueError("TrenchPlacement.width_um and depth_um must be positive")
        if self.closed_end not in ("square", "round"):
            raise ValueError(
                f"TrenchPlacement.closed_end must be 'square' or 'round', got {self.closed_end!r}"
            )


def _draw(
    cells: FrameCells,
    trench: TrenchPlacement | None,
    camera_shape: tuple[int, int],
    microscope: Microscope,
    render: RenderSettings,
    depth_um: float = 1.2,
    curvature: dict[int, tuple[float, float, float]] | None = None,
) -> Scene:
    """Draw fitted cells (image coordinates) with :func:`draw_scene`.

    The trench is placed by ``trench_origin_um`` in a field of view of the image's
    shape; ``trench=None`` is an open field (agar pad: media everywhere, no device).
    """
    rows, cols = camera_shape
    if trench is None:
        px = microscope.pixel_size_um
        field = Field(cols * px, rows * px, depth_um=depth_um)
        return draw_scene(cells, TrenchGeometry(), microscope, render, curvature, field=field)
    relative = FrameCells(
        ids=cells.ids,
        x_um=cells.x_um - trench.left_um,
        y_um=cells.y_um - trench.top_um,
        angle_rad=cells.angle_rad,
        length_um=cells.length_um,
        width_um=cells.width_um,
    )
    # Length and margin do not matter: camera_shape sets the field of view.
    geometry = TrenchGeometry(
        width_um=trench.width_um,
        depth_um=trench.depth_um,
        margin_um=0.0,
        closed_end=trench.closed_end,
    )
    return draw_scene(
        relative,
        geometry,
        microscope,
        render,
        curvature,
        trench_origin_um=(trench.left_um, trench.top_um),
        camera_shape=(rows, cols),
    )


def _spherocylinder_width(area_um2: float, length_um: float) -> float:
    """Width of the spherocylinder of given area and length: ``A = w L - (1 - pi/4) w^2``."""
    k = 1 - math.pi / 4
    disc = max(length_um**2 - 4 * k * area_um2, 0.0)
    return (length_um - math.sqrt(disc)) / (2 * k)


def _longest_run(mask: np.ndarray) -> tuple[int, int] | None:
    labels, n = ndimage.label(mask)
    if n == 0:
        return None
    sizes = ndimage.sum(mask, labels, range(1, n + 1))
    idx = np.flatnonzero(labels == int(np.argmax(sizes)) + 1)
    return int(idx[0]), int(idx[-1])


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


def _septum_cuts(
    profile: np.ndarray, noise: np.ndarray, min_prominence: float, min_length: int
) -> list[int]:
    """Positions of septa in a 1-D intensity profile along a region's axis.

    Local maxima (bright septa between dark cell bodies) whose topographic prominence
    is above ``min_prominence`` and above :data:`SEPTUM_NOISE_SD` times the profile's
    noise there, accepted greedily by decreasing prominence as long as every piece
    they cut the region into stays at least ``min_length`` bins long.
    """
    from scipy.signal import find_peaks

    peaks, props = find_peaks(profile, prominence=min_prominence)
    keep = props["prominences"] >= SEPTUM_NOISE_SD * noise[peaks]
    peaks, prominences = peaks[keep], props["prominences"][keep]
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
) -> tuple[FrameCells, np.ndarray, TrenchPlacement | None, np.ndarray]:
    """Plain segmentation: Otsu threshold, watershed, region moments.

    Phase contrast is assumed (cells darker than the media around them). In a trench
    the trench is found first from the column profile (90th percentile of each
    column, longest run above 30 % of its range) and its closed end from the row
    profile (Otsu threshold). Touching cells that the threshold and watershed leave
    in one region are split at their bright septa (septum profile split,
    :func:`_split_at_septa`). A region still longer than ``max_cell_length_um`` is
    taken as several touching cells and starts as equal rods along its axis.

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
    smooth = ndimage.gaussian_filter(image, 1.0)
    region = np.ones(image.shape, bool)
    trench = None
    if geometry == "trench":
        # Device columns are dark all along; trench columns hold bright media or halo
        # somewhere: the 90th percentile of each column separates them.
        columns = np.percentile(smooth, 90, axis=0)
        low, high = np.percentile(columns, 10), columns.max()
        above = columns > low + 0.3 * (high - low)
        above = ndimage.binary_closing(above, np.ones(7, bool)) | above  # dips between halos
        run = _longest_run(above)
        if run is None:
            raise ValueError("no trench found in the image: is it a mother-machine trench?")
        c0, c1 = run
        inside = smooth[:, c0 : c1 + 1].mean(axis=1)
        above = inside > threshold_otsu(inside)
        first = int(np.argmax(np.convolve(above, np.ones(3), "same") >= 2))
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
    rows_list = []
    for index in range(1, int(instances.max()) + 1):
        rr, cc = np.nonzero(instances == index)
        if rr.size < 6:
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
                (cx + offset * vx, cy + offset * vy, angle, max(length / k, width), width)
            )
    if not rows_list:
        raise ValueError("the Otsu segmentation found no cells in the image")
    rows_list.sort(key=lambda row: (row[1], row[0]))
    table = np.array(rows_list)
    cells = FrameCells(
        ids=np.arange(1, len(table) + 1),
        x_um=table[:, 0],
        y_um=table[:, 1],
        angle_rad=table[:, 2],
        length_um=table[:, 3],
        width_um=table[:, 4],
    )
    return cells, table[:, 4].copy(), trench, instances


@dataclass(frozen=True)
class SceneFit:
    """Outcome of :func:`fit_scene`.

    Attributes
    ----------
    cells
        Fitted cells (image coordinates, um), model-based lengths and widths.
    initial_cells
        The Otsu / watershed / moments start.
    otsu_width_um
        Otsu width of each initial cell (area and length of its region).
    trench
        Fitted trench placement (``None`` for an open field).
    render
        Fitted render settings (intensities and kernel parameters).
    scene
        The fitted scene at render resolution.
    synthetic
        Noise-free rendered image, baseline included (ADU, float32).
    residual
        ``real - synthetic`` (ADU, float32): the pixelwise residual for diagnosis.
    synthetic_before
        The rendered start (Otsu geometry, starting optics, intensities solved).
    terms
        ``{term: (before, after)}``; ``pixel`` is the reduced chi-square with the
        camera's variance (1 = fitted to the noise).
    objective_before, objective_after
        The pixel term at the start (Otsu geometry, starting optics, intensities
        solved) and at the end.
    n_evaluations
        Renders used.
    curvature_um
        Fitted curvature amplitude ``a`` (um) of eq. 1 per cell, with ``b, c`` =
        :data:`CURVATURE_B`, :data:`CURVATURE_C` (zeros when not fitted); see
        :meth:`curvature`.
    """

    cells: FrameCells
    initial_cells: FrameCells
    otsu_width_um: np.ndarray
    trench: TrenchPlacement | None
    render: RenderSettings
    scene: Scene = field(repr=False)
    synthetic: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    synthetic_before: np.ndarray | None = field(default=None, repr=False)
    terms: dict[str, tuple[float, float]] = field(default_factory=dict)
    objective_before: float = math.nan
    objective_after: float = math.nan
    n_evaluations: int = 0
    curvature_um: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def curvature(self) -> dict[int, tuple[float, float, float]]:
        """The fitted curvature as ``draw_scene``'s mapping ``cell id -> (a_um, b, c)``."""
        return {
            int(i): (float(a), CURVATURE_B, CURVATURE_C)
            for i, a in zip(self.cells.ids, self.curvature_um)
            if a != 0
        }

    def trench_geometry(self, image_rows: int, pixel_size_um: float) -> TrenchGeometry:
        """An approximate :class:`TrenchGeometry` for re-rendering with the pipeline.

        The pipeline centres the trench with equal margins; the margin is taken from
        the fitted left wall.
        """
        if self.trench is None:
            raise ValueError("an open-field fit has no trench")
        margin = max(self.trench.left_um, 0.0)
        length = max(image_rows * pixel_size_um - margin, self.trench.width_um)
        return TrenchGeometry(
            length_um=length,
            width_um=self.trench.width_um,
            depth_um=self.trench.depth_um,
            margin_um=margin,
            closed_end=self.trench.closed_end,
        )

    def cells_table(self) -> dict[str, list]:
        """The fitted cells and their Otsu widths as plain lists (for JSON)."""
        table: dict[str, list] = {
            name: np.asarray(getattr(self.cells, name)).tolist()
            for name in ("ids", "x_um", "y_um", "angle_rad", "length_um", "width_um")
        }
        table["curvature_um"] = np.asarray(self.curvature_um).tolist()
        table["otsu_width_um"] = np.asarray(self.otsu_width_um).tolist()
        table["otsu_length_um"] = np.asarray(self.initial_cells.length_um).tolist()
        return table


def fit_scene(
    real_image: np.ndarray,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera | None = None,
    *,
    trench: TrenchPlacement | TrenchGeometry | None = None,
    labels: np.ndarray | None = None,
    geometry: Literal["trench", "open"] = "trench",
    closed_end: Literal["square", "round"] | None = None,
    fit_optics: tuple[str, ...] = ("apodisation_sigma_um", "defocus_sigma_um", "psf_offset"),
    width_sd_um: float = 0.0,
    fit_curvature: bool = True,
    curvature_sd_um: float = 0.1,
    irls_rounds: int = 3,
    max_iterations: int = 25,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> SceneFit:
    """Fit cells, trench and optics so the rendered image overlays the real one.

    Parameters
    ----------
    real_image
        One 2D frame (ADU, camera baseline included), phase contrast.
    microscope, render, camera
        Starting model; ``render`` gives the starting kernel parameters.
    trench
        Starting trench placement (:class:`TrenchPlacement` in image coordinates, or a
        :class:`TrenchGeometry` read as ``left = top = margin_um``); default: found
        from the image.
    labels
        Optional painted class map; only checked for shape here (the segmentation
        needs no labels), and used to report eq. 20 / class statistics terms.
    geometry
        ``"trench"`` (mother machine) or ``"open"`` (agar pad: no device).
    closed_end
        Shape of the trench's closed end drawn in the fit: ``"square"`` or ``"round"``
        (a semicircle of diameter the trench width, PDMS in its corners; the real
        trench's end is rounded, docs/fitting.md). Default: that of ``trench`` if
        given, else ``"square"``.
    fit_optics
        Kernel parameters fitted jointly with the geometry (the intensities always are).
    width_sd_um
        0 (default): one width shared by all cells. > 0: per-cell widths tied to the
        shared width by a Gaussian prior of this s.d. (hierarchical). Free per-cell
        widths would soak up PSF effects (docs/fitting.md).
    fit_curvature
        Fit each cell's curvature amplitude ``a`` of eq. 1 (one bend: ``b, c`` fixed
        to :data:`CURVATURE_B`, :data:`CURVATURE_C`), bounded to +-0.5 um; cells
        start straight.
    curvature_sd_um
        S.d. of a Gaussian prior on ``a`` centred on 0 (ridge), so that straight
        cells and cells too short to show a bend stay straight.
    irls_rounds
        Rounds of iteratively reweighted least squares (variance held fixed within a
        round, eq. 17).
    max_iterations
        Gauss-Newton iterations per round.
    progress, cancel
        As in :func:`~napari_symbac.fit.fit_parameters`.

    Returns
    -------
    SceneFit
    """
    camera = Camera() if camera is None else camera
    real = as_single_image(real_image, name="real_image")
    if labels is not None:
        labels = as_label_stack(labels, (1, *real.shape))[0]
    if not (math.isfinite(width_sd_um) and width_sd_um >= 0):
        raise ValueError(f"width_sd_um must be zero or positive, got {width_sd_um!r}")
    if not (math.isfinite(curvature_sd_um) and curvature_sd_um > 0):
        raise ValueError(f"curvature_sd_um must be positive, got {curvature_sd_um!r}")
    for name in fit_optics:
        parameter_bounds(name, microscope)
    px = microscope.pixel_size_um
    depth = trench.depth_um if trench is not None else 1.2
    init_cells, otsu_w, found, _ = otsu_cells(real, microscope, geometry=geometry, depth_um=depth)
    if isinstance(trench, TrenchGeometry):
        trench = TrenchPlacement(
            trench.margin_um, trench.width_um, trench.margin_um, depth, trench.closed_end
        )
    placement = trench if trench is not None else found
    if placement is not None and closed_end is not None:
        placement = dataclasses.replace(placement, closed_end=closed_end)
    if geometry == "open":
        placement = None
    n = len(init_cells)
    shape = real.shape
    fit_top = placement is not None and placement.top_um > 0
    # ---- parameter vector (scaled units) -------------------------------------------
    scale_geo = 0.05
    width0 = float(np.clip(np.median(otsu_w) + 0.1, 0.4, 2.0))  # Otsu is biased narrow
    p0: list[float] = []
    lo: list[float] = []
    hi: list[float] = []
    for i in range(n):
        vals = (
            init_cells.x_um[i],
            init_cells.y_um[i],
            init_cells.angle_rad[i],
            max(init_cells.length_um[i] + 0.1, width0),
        )
        bounds_i = ((-2, shape[1] * px + 2), (-3, shape[0] * px + 3), (-1.6, 1.6), (0.3, 12.0))
        for v, (a, b) in zip(vals, bounds_i):
            p0.append(v)
            lo.append(a)
            hi.append(b)
    i_curv = len(p0)
    n_curv = n if fit_curvature else 0
    p0.extend([0.0] * n_curv)
    lo.extend([-0.5] * n_curv)
    hi.extend([0.5] * n_curv)
    i_width = len(p0)
    p0.append(width0)
    lo.append(0.3)
    hi.append(2.5)
    i_dw = len(p0)
    if width_sd_um > 0:
        p0.extend([0.0] * n)
        lo.extend([-1.0] * n)
        hi.extend([1.0] * n)
    i_trench = len(p0)
    if placement is not None:
        p0.extend([placement.left_um, placement.width_um])
        lo.extend([-1.0, 0.3])
        hi.extend([shape[1] * px, shape[1] * px + 1])
        if fit_top:
            p0.append(placement.top_um)
            lo.append(-1.0)
            hi.append(shape[0] * px)
    i_optics = len(p0)
    start_optics = {name: float(getattr(render, name)) for name in fit_optics}
    for name in fit_optics:
        a, b = parameter_bounds(name, microscope)
        v = float(np.clip(start_optics[name], a, b))
        p0.append(v)
        lo.append(a)
        hi.append(b)
    scales = np.array([scale_geo] * (i_optics) + [_SCALE[name] for name in fit_optics], dtype=float)
    x0 = np.array(p0)
    lo_a, hi_a = np.array(lo), np.array(hi)
    x0 = np.clip(x0, lo_a + 1e-9, hi_a - 1e-9)

    def bends(x: np.ndarray) -> np.ndarray:
        return x[i_curv : i_curv + n_curv] if n_curv else np.zeros(n)

    def unpack(x: np.ndarray) -> tuple[FrameCells, TrenchPlacement | None, RenderSettings]:
        cell = x[: 4 * n].reshape(n, 4) if n else np.zeros((0, 4))
        width = np.full(n, x[i_width])
        if width_sd_um > 0:
            width = width + x[i_dw : i_dw + n]
        width = np.maximum(width, 0.2)
        frame = FrameCells(
            ids=np.arange(1, n + 1),
            x_um=cell[:, 0],
            y_um=cell[:, 1],
            angle_rad=cell[:, 2],
            length_um=np.maximum(cell[:, 3], width),
            width_um=width,
        )
        place = None
        if placement is not None:
            top = x[i_trench + 2] if fit_top else placement.top_um
            place = TrenchPlacement(
                x[i_trench], x[i_trench + 1], top, placement.depth_um, placement.closed_end
            )
        r = dataclasses.replace(
            render, **{name: float(v) for name, v in zip(fit_optics, x[i_optics:])}
        )
        return frame, place, r

    total = (irls_rounds * (max_iterations + 2) + 2) * (len(x0) + 1)  # an upper bound
    budget = _Budget(total, progress, cancel)
    model = ForwardModel(microscope, render, camera)
    y = (real - camera.baseline_adu).ravel()

    def design(x: np.ndarray) -> tuple[np.ndarray, Scene, RenderSettings]:
        budget.tick()
        frame, place, r = unpack(x)
        curv = {i + 1: (float(a), CURVATURE_B, CURVATURE_C) for i, a in enumerate(bends(x))}
        scene = _draw(frame, place, shape, microscope, r, depth, curv)
        comps = model.with_render(r).components(scene)
        a = np.stack([comps[k].ravel() for k in ("cells", "media", "device")], axis=1)
        return a.astype(np.float64), scene, r

    def solve(a: np.ndarray, sw: np.ndarray) -> np.ndarray:
        return _nnls(a * sw[:, None], y * sw)

    def prior(x: np.ndarray) -> np.ndarray:
        terms = [x[i_curv : i_curv + n_curv] / curvature_sd_um]
        if width_sd_um > 0:
            terms.append(x[i_dw : i_dw + n] / width_sd_um)
        return np.concatenate(terms)

    var = _variance(np.maximum(y, 0.0), render, camera)
    a0, _, _ = design(x0)
    sw0 = 1 / np.sqrt(var)
    i0 = solve(a0, sw0)
    clean0 = a0 @ i0
    var_before = _variance(clean0, render, camera)
    before_pixel = float(np.mean((y - clean0) ** 2 / var_before))
    x = x0.copy()
    bend_index = np.arange(i_curv, i_curv + n_curv)
    straight = np.setdiff1d(np.arange(x0.size), bend_index)
    for round_ in range(irls_rounds):
        sw = 1 / np.sqrt(var)
        # Curvature is held straight in the first round (when there are more): the
        # centres and angles settle first, so that a bend cannot stand in for them
        # (on the real trench, freeing it at once ended in a worse minimum).
        free = straight if (round_ == 0 and irls_rounds > 1 and n_curv) else np.arange(x0.size)
        z_all = (x - x0) / scales

        def residual(
            zf: np.ndarray, sw: np.ndarray = sw, free: np.ndarray = free, base: np.ndarray = z_all
        ) -> np.ndarray:
            zz = base.copy()
            zz[free] = zf
            xx = x0 + zz * scales
            a, _, _ = design(xx)
            return np.concatenate([(y - a @ solve(a, sw)) * sw, prior(xx)])

        z = z_all.copy()
        z[free] = _levenberg_marquardt(
            residual,
            z_all[free],
            ((lo_a - x0) / scales)[free],
            ((hi_a - x0) / scales)[free],
            max_iterations,
        )
        x = x0 + z * scales
        a, _, r = design(x)
        clean = a @ solve(a, sw)
        var = _variance(clean, r, camera)
    a, scene, r = design(x)
    sw = 1 / np.sqrt(var)
    intens = solve(a, sw)
    final_render = dataclasses.replace(r, **{k: float(v) for k, v in zip(_INTENSITIES, intens)})
    frame, place, _ = unpack(x)
    synthetic = ((a @ intens) + camera.baseline_adu).reshape(shape).astype(np.float32)
    after_pixel = float(np.mean((y - a @ intens) ** 2 / _variance(a @ intens, r, camera)))
    terms = {"pixel": (before_pixel, after_pixel)}
    if labels is not None:
        before_img = (clean0 + camera.baseline_adu).reshape(shape)
        tb = objective_terms(before_img, real, labels, terms=("eq20", "class_stats"))
        ta = objective_terms(synthetic, real, labels, terms=("eq20", "class_stats"))
        terms.update({k: (tb[k], ta[k]) for k in ta})
    if progress is not None:
        progress(budget.total, budget.total)
    return SceneFit(
        cells=frame,
        initial_cells=init_cells,
        otsu_width_um=otsu_w,
        trench=place,
        render=final_render,
        scene=scene,
        synthetic=synthetic,
        residual=(real - synthetic).astype(np.float32),
        synthetic_before=(clean0 + camera.baseline_adu).reshape(shape).astype(np.float32),
        terms=terms,
        objective_before=before_pixel,
        objective_after=after_pixel,
        n_evaluations=budget.done,
        curvature_um=np.array(bends(x), dtype=float),
    )


def _levenberg_marquardt(
    residual: Callable[[np.ndarray], np.ndarray],
    z0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    max_iterations: int,
    step: float = DIFF_STEP,
) -> np.ndarray:
    """Projected Levenberg-Marquardt with a forward-difference Jacobian.

    Steps are clipped to the bounds; the damping ``lambda diag(J^T J)`` (Marquardt
    scaling) shrinks after an accepted step and grows after a rejected one. Stops after
    ``max_iterations`` Jacobians or when the cost falls by less than 1e-6 relative.
    (scipy's trust-region solver stalled on these renders: the Coleman-Li scaling near
    the bounds and the cusps at cell edges made it reject every step.)
    """
    z = np.clip(z0, lower, upper)
    r = residual(z)
    cost = float(r @ r)
    lam = 1e-2
    for _ in range(max_iterations):
        jac = np.empty((r.size, z.size))
        for k in range(z.size):
            zk = z.copy()
            h = step if zk[k] + step <= upper[k] else -step
            zk[k] += h
            jac[:, k] = (residual(zk) - r) / h
        jtj = jac.T @ jac
        grad = jac.T @ r
        diag = np.diag(jtj) + 1e-9 * max(float(np.mean(np.diag(jtj))), 1e-12)
        improved = False
        for _attempt in range(6):
            delta = -np.linalg.solve(jtj + lam * np.diag(diag), grad)
            trial = np.clip(z + delta, lower, upper)
            r_trial = residual(trial)
            cost_trial = float(r_trial @ r_trial)
            if cost_trial < cost:
                improved = True
                gain = (cost - cost_trial) / max(cost, 1e-300)
                z, r, cost = trial, r_trial, cost_trial
                lam = max(lam / 3, 1e-6)
                break
            lam *= 4
        if not improved or gain < 1e-6:
            break
    return z


def before_after_montage(real_image: np.ndarray, result: SceneFit) -> np.ndarray:
    """An 8-bit RGB figure: real | start (Otsu) | fitted | residual, side by side.

    The three images share one grey scale (0.5-99.5 percentiles of the real image);
    the residual is shown on a symmetric scale, red positive, blue negative.
    """
    real = as_single_image(real_image, name="real_image")
    low, high = np.percentile(real, [0.5, 99.5])
    panels = []
    before = result.synthetic_before if result.synthetic_before is not None else result.synthetic
    for image in (real, before, result.synthetic):
        grey = np.clip((np.asarray(image, float) - low) / max(high - low, 1e-9), 0, 1)
        panels.append(np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=-1))
    res = np.asarray(result.residual, float)
    limit = max(float(np.percentile(np.abs(res), 99)), 1e-9)
    v = np.clip(res / limit, -1, 1)
    rgb = np.full((*res.shape, 3), 255, np.uint8)
    rgb[..., 0] = (255 * (1 - np.maximum(-v, 0))).astype(np.uint8)
    rgb[..., 1] = (255 * (1 - np.abs(v))).astype(np.uint8)
    rgb[..., 2] = (255 * (1 - np.maximum(v, 0))).astype(np.uint8)
    panels.append(rgb)
    gap = np.zeros((real.shape[0], 3, 3), np.uint8)
    row = [panels[0]]
    for panel in panels[1:]:
        row.extend([gap, panel])
    return np.concatenate(row, axis=1)
