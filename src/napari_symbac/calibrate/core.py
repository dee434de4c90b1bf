"""Calibrate the pipeline to a real recording: fit it, then turn the fit into settings.

:func:`calibrate` runs the existing engine on a crop of the recording and measures the
whole field model-free (:mod:`~napari_symbac.calibrate.measure`):

* fluorescence (and phase contrast of sparse cells): the scene fit
  (:func:`~napari_symbac.fit.fit_scene`, open field) started from the masks, or from
  painted labels, or from its own segmentation; it gives the intensities (eq. 3),
  defocus (eq. 14) and, in phase, the kernel (eq. 7-15), and the camera (eq. 17)
  measured from the image;
* phase contrast of dense colonies (the crop's masks hold a colony,
  :func:`~napari_symbac.fit.colony.is_dense_colony`, as for ``fit --masks``): the
  scene drawn from the masks (:func:`~napari_symbac.scene.scene_from_masks`) and the
  partially coherent phase model fitted to it pixel by pixel
  (:func:`~napari_symbac.fit.colony.colony_optics`), which reaches the halo and the bright
  gaps that the linear kernel cannot (docs/rendering.md), then each cell's own optical
  path, whose spread the dataset draws.

The settings (:func:`settings_from_fit`) then hold what a user would otherwise set by
hand: pixel size, cell length and width distributions, intensities and their polarity
from the modality, per-cell brightness variation, the camera, and an agar pad with as
many colonies of as many cells as the recording shows. Given masks with a colony of
five cells or more, the colonies are packed as tightly as the recording's and their
cells are as long (:mod:`~napari_symbac.calibrate.compaction`: gravity towards each
colony's centre chosen by simulating a few, the division length corrected).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from napari_symbac.arguments import require_argument
from napari_symbac.calibrate.compaction import CompactionTrial, compacted
from napari_symbac.calibrate.measure import (
    ColonyPacking,
    FieldMeasurements,
    instance_masks,
    measure_debris,
    measure_field,
    measure_packing,
    measure_texture,
)
from napari_symbac.settings import (
    AgarPadGeometry,
    Camera,
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
)

if TYPE_CHECKING:
    from napari_symbac.calibrate.compare import AdviceWords, Comparison
    from napari_symbac.export import ExportSettings
    from napari_symbac.export.item import ExportItem
    from napari_symbac.fit.scene_fit import SceneFit

__all__ = [
    "COMPARED_ITEMS",
    "Calibration",
    "best_crop",
    "calibrate",
    "compare_with_dataset",
    "division_length_um",
    "export_settings",
    "items_words",
    "rough_pad_layout",
    "settings_from_fit",
]

#: Side of the crop fitted without masks: the fit's cells are then the only measurement of
#: sizes and layout, so as much of the field as a fit takes in a minute or two (a sparse
#: 512 x 512 ColiCoords field holds 3-10 cells; a 160 px crop of it often one).
NO_MASKS_CROP_PX = 512

#: Doubling time and frame interval of the simulated colonies (minutes).
_DOUBLING_MIN = 25.0
_FRAME_MIN = 3.0


@dataclass(frozen=True)
class Calibration:
    """Outcome of :func:`calibrate`.

    Attributes
    ----------
    settings
        Pipeline settings matched to the recording (render them, export them).
    measurements
        Model-free measurements of the whole field against its masks.
    reference
        The real image the measurements and the layout are of: the whole image with
        masks, the fitted crop without (only there are the fit's cells known).
    masks
        Instance masks of ``reference`` (given, or the fit's cells).
    crop
        ``(row slice, column slice)`` of the crop the optics were fitted on.
    method
        ``"scene fit"`` or ``"masks + partially coherent fit"``.
    fit_chi2
        Reduced chi-square (pixel term) of the fit at its start and end.
    packing
        Packing of the field's colonies (:func:`measure_packing`), ``None`` without
        masks.
    compaction
        The simulated gravities :func:`choose_gravity` tried (empty when the field
        has no colony of at least 5 cells: gravity stays 0).
    notes
        Plain sentences: where each setting came from, what could not be measured.
    mask_offset_um
        Fluorescence or bright field with masks: how far beyond the fitted model cells
        the masks' outlines lie, the annotation convention :func:`export_settings` gives
        the dataset's masks. Fluorescence: the growth that puts the model cells'
        outline at the same fraction of their light as the masks' outline in the
        recording (:func:`~napari_symbac.export.outline.level_matched_growth_px`);
        bright field: by area (median over the crop's matched cells,
        :func:`~napari_symbac.export.outline.outline_offset_px`). ``None`` otherwise.
    mask_faintest_cnr
        Fluorescence or bright field with masks: the contrast-to-noise ratio of the
        faintest cell the masks mark in the recording
        (:func:`~napari_symbac.export.visibility.contrast_to_noise`, as the export
        measures its synthetic cells), the annotation's visibility convention: the masks
        mark every cell (sizes and layout are read from them), so a cell fainter than
        any of them is one the annotator did not mark. :func:`export_settings` drops
        synthetic cells fainter than it (at most :data:`VISIBILITY_MAX_CNR`) from the
        dataset's masks. ``None`` otherwise, and when the masks hold fewer than
        :data:`VISIBILITY_MIN_CELLS` whole cells.
    cautions
        What to check before training on the dataset, in plain sentences (cells of a
        width no bacterium has: the pixel size); empty when nothing is doubtful.
    """

    settings: PipelineSettings
    measurements: FieldMeasurements
    reference: np.ndarray = field(repr=False)
    masks: np.ndarray = field(repr=False)
    crop: tuple[slice, slice]
    method: str
    fit_chi2: tuple[float, float]
    packing: ColonyPacking | None = None
    compaction: tuple[CompactionTrial, ...] = ()
    notes: tuple[str, ...] = ()
    mask_offset_um: float | None = None
    mask_faintest_cnr: float | None = None
    cautions: tuple[str, ...] = ()

    def report_lines(self, pixel_note: str, notes: list[str] | None = None) -> list[str]:
        """The report's account of the calibration (``napari-symbac calibrate``'s
        report.txt and the Calibrate dock): modality, pixel size (``pixel_note``: where
        it came from), method and chi-square, the real field, and where each setting
        came from (``notes``, default :attr:`notes`)."""
        microscope = self.settings.microscope
        px = microscope.pixel_size_um
        # a note that says the size itself is the line (found as a user: "pixel size
        # 0.8 um (pixel size 0.8 um from --microscope ...)")
        said = pixel_note.startswith("pixel size ")
        return [
            f"modality: {microscope.modality}",
            pixel_note if said else f"pixel size {px:.4g} um ({pixel_note})",
            f"method: {self.method}; pixel chi2 {self.fit_chi2[0]:.3g} -> "
            f"{self.fit_chi2[1]:.3g}",
            f"real field: {self.measurements.summary(px, microscope.modality)}",
            *(["", "WARNINGS", *(f"- {c}" for c in self.cautions)] if self.cautions else []),
            "",
            "WHERE THE SETTINGS CAME FROM",
            *(f"- {n}" for n in (self.notes if notes is None else notes)),
        ]


def _stain_model(
    modality: str, envelope_stain: bool, depth_layers: int
) -> tuple[tuple[str, ...] | None, RenderSettings]:
    """The optics the scene fit fits and the render it starts from, for a stain in the
    envelope and / or a depth-resolved image (both fluorescence only, as ``fit``'s
    ``--envelope-stain`` and ``--depth-layers``)."""
    from napari_symbac.fit.scene_fit import (
        ENVELOPE_FIT_OPTICS,
        depth_fit_optics,
        depth_start,
        envelope_stain_start,
    )
    from napari_symbac.settings import MAX_DEPTH_LAYERS

    start = RenderSettings(cell_brightness_cv=0.0)
    asked = [
        words
        for words, on in (("a stain in the envelope", envelope_stain), ("depth", depth_layers))
        if on
    ]
    if asked and modality != "fluorescence":
        raise ValueError(
            f"{' and '.join(asked)} is fitted in fluorescence; this recording is {modality}: "
            "calibrate it without"
        )
    if not 0 <= depth_layers <= MAX_DEPTH_LAYERS:
        raise ValueError(
            f"depth_layers={depth_layers} is not a number of slabs: pass 1-{MAX_DEPTH_LAYERS} "
            "(5 fit ColiCoords ds2 as well as 15), or 0 for the 2-D projection"
        )
    fit_optics = None
    if envelope_stain:
        fit_optics, start = ENVELOPE_FIT_OPTICS, envelope_stain_start(start)
    if depth_layers:
        fit_optics, start = depth_fit_optics(fit_optics), depth_start(start, depth_layers)
    return fit_optics, start


def _stain_words(render: RenderSettings, envelope_stain: bool) -> str:
    """The fitted stain model, for the scene fit's note ('' when neither was asked)."""
    words = ""
    if envelope_stain:
        words += f"; stain in the envelope {render.envelope_stain_fraction:.2f} of it"
    if render.depth_layers:
        words += (
            f"; imaged in {render.depth_layers} slabs, focal plane "
            f"{render.focus_offset_um:+.2f} um from the cells' mid-plane"
        )
    return words


def best_crop(masks: np.ndarray, size_px: int) -> tuple[slice, slice]:
    """The ``size_px`` square window holding the most whole cells (fewest cut by its edge).

    Windows are tried on a grid of a quarter of ``size_px``; the score is whole cells
    minus cut cells, ties go to the first window (row-major), so the choice is
    deterministic.
    """
    labels = instance_masks(masks)
    rows, cols = labels.shape
    h, w = min(size_px, rows), min(size_px, cols)
    step = max(1, min(h, w) // 4)
    best, best_score = (slice(0, h), slice(0, w)), -math.inf
    starts_r = sorted({*range(0, rows - h + 1, step), rows - h})
    starts_c = sorted({*range(0, cols - w + 1, step), cols - w})
    for r in starts_r:
        for c in starts_c:
            window = labels[r : r + h, c : c + w]
            inside = set(np.unique(window).tolist()) - {0}
            edge = np.concatenate([window[0], window[-1], window[:, 0], window[:, -1]])
            cut = set(np.unique(edge).tolist()) - {0}
            score = len(inside - cut) - len(cut)
            if score > best_score:
                best, best_score = (slice(r, r + h), slice(c, c + w)), score
    return best


def _rough_cells(image: np.ndarray, modality: str, pixel_size_um: float) -> np.ndarray:
    """Regions beyond an Otsu threshold of the smoothed image (cells' polarity from the
    modality; bright field: the departure from the background either way,
    :func:`~napari_symbac.fit.start.brightfield_instances`): where to crop when no masks
    are given."""
    from scipy import ndimage
    from skimage.filters import threshold_otsu

    if modality == "brightfield":
        from napari_symbac.fit.start import brightfield_instances

        return brightfield_instances(image, pixel_size_um)
    smooth = ndimage.gaussian_filter(image, 1.0)
    threshold = threshold_otsu(smooth)
    cells = smooth > threshold if modality == "fluorescence" else smooth < threshold
    labels, _ = ndimage.label(ndimage.binary_opening(cells, iterations=2))
    return labels


#: Distance (um) within which a field's rough cell regions are one cluster, a colony:
#: the bright seams between a phase colony's touching cells are thinner.
_CLUSTER_REACH_UM = 0.5


def _phase_classes(image: np.ndarray) -> tuple[np.ndarray, float, float]:
    """A phase-contrast field smoothed, and the two thresholds of its three Otsu
    classes: the darkest the cells' interiors, the brightest the halo and the seams
    between cells, the middle the background far from the cells (one threshold took the
    background for cells: one colony of thousands of cells on the Omnipose images)."""
    from scipy import ndimage
    from skimage.filters import threshold_multiotsu

    smooth = ndimage.gaussian_filter(image, 1.0)
    dark, bright = threshold_multiotsu(smooth, 3)
    return smooth, float(dark), float(bright)


def _rough_phase_interiors(smooth: np.ndarray, dark: float) -> np.ndarray:
    """Regions of a phase-contrast field's cell interiors: its darkest class
    (:func:`_phase_classes`)."""
    from scipy import ndimage

    labels, _ = ndimage.label(ndimage.binary_opening(smooth <= dark, iterations=2))
    return labels


def _phase_colonies_px(
    smooth: np.ndarray, dark: float, bright: float, seeds: np.ndarray, reach_px: int
) -> np.ndarray:
    """Areas (px) of a phase field's colonies that hold a seed (cell interiors of a
    cluster of at least a cell): the cells' dark class and the bright class of the
    halo and the seams between them, joined within ``reach_px`` and filled, less the
    halo around them (the bright regions that reach the colony's edge). Found as a
    user: Omnipose's Sample000033, whose cells are lighter inside the colony than at its
    rim, was laid out as three colonies of 16 cells (its darkest class is the rim) for
    one of 116; its masks' area is 171.5 cells, this region's 171.7 (Sample000193:
    205 against 204, Sample000252: 150 against 145). ``smooth``, ``dark`` and
    ``bright``: :func:`_phase_classes`."""
    from scipy import ndimage

    marked = ndimage.binary_opening((smooth <= dark) | (smooth > bright), iterations=2)
    joined = ndimage.binary_dilation(marked, iterations=reach_px)
    region = ndimage.binary_erosion(
        ndimage.binary_fill_holes(joined), iterations=reach_px, border_value=1
    )
    lights, _ = ndimage.label(ndimage.binary_opening(smooth > bright, iterations=1) & region)
    rim = region & ~ndimage.binary_erosion(region)
    halo = np.isin(lights, np.unique(lights[rim & (lights > 0)]))
    colonies, _ = ndimage.label(ndimage.binary_opening(region & ~halo, iterations=2))
    seeded = np.unique(colonies[seeds & (colonies > 0)])
    return np.bincount(colonies.ravel())[seeded]


#: The least area, in cells, of a phase field's region of cell interiors that counts:
#: interiors are about 40 % of the cells' area (Omnipose's Sample000252 and 193: the
#: darkest class holds 41 % and 40 % of their masks' pixels).
_PHASE_INTERIOR_MIN_CELLS = 0.25
#: Distance (um) within which a phase field's cell interiors are one colony: those of
#: touching cells lie a cell's edges and the seam between them apart (at 0.5 um,
#: Sample000193's one colony was three).
_PHASE_CLUSTER_REACH_UM = 1.0


def rough_pad_layout(
    image: np.ndarray,
    pixel_size_um: float,
    cell_width_um: float,
    division_length_um: float,
    modality: str = "fluorescence",
) -> tuple[dict, str] | None:
    """A field's agar pad laid out before any fit (Simulate's start): :func:`pad_layout`
    with one colony per cluster of the image's cell regions (joined within
    :data:`_CLUSTER_REACH_UM`, in phase contrast :data:`_PHASE_CLUSTER_REACH_UM`), each
    of the clusters' mean area in cells (``cell_width_um`` times 0.75
    ``division_length_um``, a sizer cell's median size). Found as a user: a
    ColiCoords field of eight scattered cells was simulated as one founder on an empty
    41 um pad until Auto-fit laid it out (and, in bright field, until this took bright
    field too), and so was a phase colony of 77 cells (Omnipose's Sample000252).

    The cell regions are, in fluorescence and bright field, :func:`_rough_cells` of at
    least half a cell, a cluster's area that of its regions; in phase contrast the cell
    interiors (:func:`_rough_phase_interiors`) of at least
    :data:`_PHASE_INTERIOR_MIN_CELLS` cell, clusters whose outline (closed and filled)
    holds at least a cell (smaller ones are debris), each cluster's colony that of
    :func:`_phase_colonies_px` (one colony however many clusters of interiors it
    holds). ``None`` for an image without such a region.
    """
    from scipy import ndimage

    if modality not in ("fluorescence", "brightfield", "phase"):
        raise ValueError(
            f"rough_pad_layout takes fluorescence, bright field or phase, not {modality}"
        )
    image = np.asarray(image, np.float64)
    if not np.ptp(image) > 0:
        return None
    cell_area_um2 = cell_width_um * 0.75 * division_length_um
    phase = modality == "phase"
    if phase:
        classes = _phase_classes(image)
        regions, least = _rough_phase_interiors(*classes[:2]), _PHASE_INTERIOR_MIN_CELLS
    else:
        regions, least = _rough_cells(image, modality, pixel_size_um), 0.5
    area_px = np.bincount(regions.ravel())[1:]
    kept = np.flatnonzero(area_px * pixel_size_um**2 >= least * cell_area_um2) + 1
    cells = np.isin(regions, kept)
    reach_um = _PHASE_CLUSTER_REACH_UM if phase else _CLUSTER_REACH_UM
    reach = max(1, round(reach_um / pixel_size_um))
    clusters, n_clusters = ndimage.label(ndimage.binary_dilation(cells, iterations=reach))
    if n_clusters == 0:
        return None
    if phase:  # each cluster's outline, its dilation taken back; a colony holds a cell
        outline = ndimage.binary_erosion(ndimage.binary_fill_holes(clusters > 0), iterations=reach)
        in_cells = np.bincount(clusters[outline], minlength=n_clusters + 1)[1:]
        seeds = np.isin(clusters, np.flatnonzero(in_cells * pixel_size_um**2 >= cell_area_um2) + 1)
        in_cells = _phase_colonies_px(*classes, seeds & cells, reach)
    else:
        in_cells = np.bincount(clusters[cells], minlength=n_clusters + 1)[1:]
    if in_cells.size == 0:
        return None
    per_colony = float(in_cells.mean()) * pixel_size_um**2 / cell_area_um2
    return pad_layout(
        image.shape[-2:],
        pixel_size_um,
        in_cells.size,
        max(per_colony, 1.0),
        division_length_um=division_length_um,
        width_um=cell_width_um,
    )


def _clusters_outside(
    rough: np.ndarray, crop: tuple[slice, slice], fitted_cells: np.ndarray
) -> int:
    """Clusters of cells of the whole image outside the fitted crop, for a calibration
    without masks (the crop's own clusters are the fit's cells).

    A cluster is a region of ``rough`` (:func:`_rough_cells` of the whole image, as the
    crop was chosen on) covering at least half the median area of the fit's cells
    (``fitted_cells``, labels of the crop; smaller regions are specks) whose centroid
    lies outside ``crop``. 0 when the crop is the whole image.
    """
    from scipy import ndimage

    areas = np.bincount(np.asarray(fitted_cells).ravel())[1:]
    cell_area = float(np.median(areas[areas > 0]))
    rough = np.asarray(rough)
    sizes = np.bincount(rough.ravel())[1:]
    big = np.flatnonzero(sizes >= cell_area / 2) + 1
    if big.size == 0:
        return 0
    centres = np.asarray(ndimage.center_of_mass(rough > 0, rough, big)).reshape(-1, 2)
    inside = np.ones(len(big), bool)
    for axis, window in enumerate(crop):
        inside &= (centres[:, axis] >= window.start) & (centres[:, axis] < window.stop)
    return int(np.count_nonzero(~inside))


def division_length_um(lengths_um: np.ndarray) -> tuple[float, float]:
    """Sizer division length and its variance from a population's lengths.

    An asynchronous population of cells born at ``L_d / 2`` that grow exponentially to
    ``L_d`` has lengths distributed as ``1 / L^2`` between them: median ``2 L_d / 3``
    (mean ``L_d ln 2``). The median is taken, so that a few filaments do not lengthen
    every cell (found as a user: Omnipose's Sample000252, median 4.19 um, mean 5.30 um,
    gave a dataset of cells dividing at 7.64 um, medians 5.1-5.9 um; on its other two
    colonies the two estimates agree within 4 %). The variance of ``L_d`` between cells
    is what is left of the lengths' variance after the spread that growth itself makes
    (s.d. ~ ``0.2 L_d``).
    """
    division = 1.5 * float(np.median(lengths_um))
    spread = float(np.var(lengths_um)) - (0.2 * division) ** 2
    return division, float(np.clip(spread, 0.01, (0.25 * division) ** 2))


def _frames_for(cluster_cells: float, division_length_um: float, width_um: float) -> int:
    """Frames of growth for one founder to become ``cluster_cells`` cells, on average.

    A cell grows exponentially with doubling time :data:`_DOUBLING_MIN`, but a sizer's
    daughters share the mother's length and a cap's worth more (``L + w / 3``: volume
    kept, Algorithm 1), so a generation takes ``g = log2(2 L / (L + w / 3))`` doublings
    (0.87 for 3.5 x 1 um cells); the founder starts at a uniform fraction of its
    division length (``sim.simulator.FOUNDER_LENGTH_FRACTION``, 0.5-0.9: the median 0.7,
    ``log2(1 / 0.7)`` doublings from its first division); and from then on the mean
    count of a colony grown from one newborn cell is ``2^n / (2 ln 2)`` after ``n``
    generations, not ``2^n`` (the Bellman-Harris branching process with near-equal
    lifetimes: the count is a staircase, its steps spread by the cells' noise). Found
    as a user: colonies laid out as ~123 cells grew to 181-255.
    """
    from napari_symbac.sim.simulator import FOUNDER_LENGTH_FRACTION

    L, w = float(division_length_um), float(width_um)
    generation = _DOUBLING_MIN * math.log2(2.0 * L / (L + w / 3.0))
    founder_median = sum(FOUNDER_LENGTH_FRACTION) / 2  # of a uniform draw
    first = _DOUBLING_MIN * math.log2(1.0 / founder_median)
    cells = max(cluster_cells, 1.0) * 2.0 * math.log(2.0)  # the staircase's mean
    minutes = first + generation * (math.log2(cells) - 1.0)
    return max(0, round(minutes / _FRAME_MIN))


def pad_edge_margin_um(width_um: float, height_um: float, margin_um: float = 3.0) -> float:
    """``margin_um``, or less on a small field, so that the field keeps room inside its
    margins (15 % of its shorter side at most)."""
    return float(min(margin_um, 0.15 * min(width_um, height_um)))


def pad_layout(
    shape_px: tuple[int, int],
    pixel_size_um: float,
    n_colonies: int,
    cells_per_colony: float,
    *,
    division_length_um: float,
    width_um: float,
) -> tuple[dict, str]:
    """The simulation of an agar pad laid out as an image: the image's size, one colony
    per cluster of its cells, each grown from one founder (sizer, doubling
    :data:`_DOUBLING_MIN` min, frames of :data:`_FRAME_MIN` min) to the clusters' mean
    size, on average, for cells that divide at ``division_length_um`` and are
    ``width_um`` wide (:func:`_frames_for`).

    Returns
    -------
    fields, note
        :class:`SimulationSettings` fields (geometry, pad, founders, frames, growth) and
        a sentence saying them.
    """
    height_um, field_um = shape_px[0] * pixel_size_um, shape_px[1] * pixel_size_um
    n_colonies = int(max(1, n_colonies))
    growth = _frames_for(cells_per_colony, division_length_um, width_um)
    separation = float(min(10.0, 0.5 * math.sqrt(height_um * field_um / n_colonies)))
    pad = AgarPadGeometry(
        field_width_um=field_um,
        field_height_um=height_um,
        n_colonies=n_colonies,
        colony_separation_um=separation,
        edge_margin_um=pad_edge_margin_um(field_um, height_um),
    )
    note = (
        f"layout: agar pad {field_um:.1f} x {height_um:.1f} um (the image), {n_colonies} "
        f"{'colony' if n_colonies == 1 else 'colonies'} of one founder each grown {growth} "
        f"frames of {_FRAME_MIN:g} min (doubling {_DOUBLING_MIN:g} min) to "
        f"~{cells_per_colony:.0f} cells, as the image's clusters (on average: a colony "
        "of one founder varies by about a fifth from seed to seed)"
    )
    fields = {
        "n_frames": growth + 1,
        "geometry": "agar_pad",
        "agar_pad": pad,
        "n_founders": n_colonies,
        "frame_interval_min": _FRAME_MIN,
        "growth_model": "sizer",
        "interdivision_time_min": _DOUBLING_MIN,
        "growth_rate_per_min": math.log(2) / _DOUBLING_MIN,
    }
    return fields, note


def settings_from_fit(
    measurements: FieldMeasurements,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera,
    *,
    width_um: float | None = None,
    length_scale: float = 1.0,
    layout: tuple[tuple[int, int], int] | None = None,
) -> tuple[PipelineSettings, list[str]]:
    """Pipeline settings matched to a measured field and its fitted optics.

    Parameters
    ----------
    measurements
        The field's cells and layout.
    microscope, render, camera
        Fitted optics, intensities and camera.
    width_um
        Cell width (the fit's model width); default: the masks' median width.
    length_scale
        Fitted over mask length of the crop's cells (the masks of thresholded
        probability maps run long); the masks' length distribution is scaled by it.
    layout
        ``((rows, columns), n_colonies)`` of the simulated field when it is not the
        measured one (the whole image around a fitted crop, :func:`_clusters_outside`);
        default the measurements' shape and clusters.

    Returns
    -------
    settings, notes
    """
    px = microscope.pixel_size_um
    m = measurements
    notes = []
    lengths = m.of_whole_cells(m.lengths_px) * px * length_scale
    widths = m.of_whole_cells(m.widths_px) * px
    width = float(np.median(widths)) if width_um is None else float(width_um)
    width_var = float(np.clip(np.var(widths), 0.0004, 0.04))
    division, division_var = division_length_um(lengths)
    division = max(division, 1.3 * width)
    notes.append(
        f"cells: width {width:.2f} um ({'fit' if width_um is not None else 'masks'}), "
        f"width variance {width_var:.4f} um^2 (masks); division length {division:.2f} um "
        f"(1.5 x the median length {np.median(lengths):.2f} um; masks x {length_scale:.2f}), "
        f"variance {division_var:.3f} um^2"
        + _cut_cells_words(m)
    )
    shape, n_colonies = layout or (m.shape, m.cluster_sizes.size)
    per_colony = float(np.mean(m.cluster_sizes)) if m.cluster_sizes.size else 1.0
    fields, note = pad_layout(
        shape, px, n_colonies, per_colony, division_length_um=division, width_um=width
    )
    notes.append(note)
    simulation = SimulationSettings(
        **fields,
        cell_max_length_um=division,
        max_length_var_um2=division_var,
        cell_width_um=width,
        width_var_um2=width_var,
    )
    return (
        PipelineSettings(
            simulation=simulation, microscope=microscope, render=render, camera=camera
        ),
        notes,
    )


def _fit_scene_crop(
    crop_image,
    crop_masks,
    microscope,
    render,
    camera,
    labels,
    max_iterations,
    progress,
    cancel,
    fit_optics=None,
):
    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.camera_estimate import censored_pixels

    valid = ~censored_pixels(crop_image, camera)
    result = fit_scene(
        crop_image,
        microscope,
        render,
        camera,
        geometry="open",
        masks=crop_masks,
        labels=labels,
        valid=valid,
        moves=crop_masks is None,
        fit_optics=fit_optics,
        max_iterations=max_iterations,
        progress=progress,
        cancel=cancel,
    )
    return result


def _refuse_a_trench(shape: tuple[int, ...], modality: str) -> None:
    """calibrate lays a field out as an agar pad: a mother-machine trench (the fit's
    rule, :func:`~napari_symbac.fit.preflight.default_geometry`), upright or on its
    side, is refused, as the command line and the Calibrate dock refuse it (found as an
    API user: the SyMBac trench was calibrated into agar-pad settings without a word)."""
    from napari_symbac.fit.preflight import default_geometry, lying_trench_problem

    lying = lying_trench_problem(shape, modality, "the image")
    if lying or default_geometry(shape, modality) == "trench":
        what = lying or (
            f"the image is {shape[-2]} x {shape[-1]} px (rows x columns), narrow and tall: "
            "a mother-machine trench"
        )
        raise ValueError(
            f"{what}; calibrate lays out fields (agar pads and colonies), not a trench: fit "
            "the trench instead (`napari-symbac fit IMAGE --out FIT` writes its settings, "
            "FIT/settings.yaml, for `napari-symbac export --config`)"
        )


def calibrate(
    image: np.ndarray,
    *,
    microscope: Microscope,
    masks: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    modality: Literal["phase", "fluorescence", "brightfield"] | None = None,
    camera: Camera | None = None,
    cell_width_um: float | None = None,
    crop_px: int | None = None,
    max_iterations: int = 8,
    max_evaluations: int = 40,
    envelope_stain: bool = False,
    depth_layers: int = 0,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    stage: Callable[[str], None] | None = None,
    pixel_note: str | None = None,
) -> Calibration:
    """Fit a real recording and turn the fit into matched pipeline settings.

    Parameters
    ----------
    image
        One 2D frame (ADU; an 8-bit image is read as an 8-bit camera's counts).
    microscope
        What the user knows: objective, wavelength, pixel size, modality.
    masks
        Instance masks (or a 0/1 mask) of ``image``: the start of the fit and the cells
        the sizes and layout are measured on.
    labels
        Painted classes (1 cell, 2 media) instead of masks: the fit finds the cells, and
        the sizes and layout are those of its cells on the crop.
    modality
        Overrides ``microscope.modality``.
    camera
        The camera, if known; default: measured from the image (photon transfer).
    cell_width_um
        Known cell width of the species, for a recording whose pixel size is not known:
        the pixel size becomes this over the masks' median width (``fit.masks``).
    crop_px
        Side of the square crop the optics are fitted on (whole cells, most of them); with
        masks at least 16 median cell widths (default 160), without masks by default
        :data:`NO_MASKS_CROP_PX` (its cells are all that sizes and layout are measured on).
    max_iterations, max_evaluations
        Budget of the scene fit (per round) and of the partially coherent fit.
    envelope_stain
        Fluorescence: fit the fraction of the stain in the cell envelope as well (a
        membrane dye; ``napari-symbac fit --envelope-stain``), so that the dataset draws
        it (``render.envelope_stain_fraction``).
    depth_layers
        Fluorescence: image the stain in this many slabs through the cells and fit the
        focal plane (eq. 16; ``fit --depth-layers``); 0: the 2-D projection.
    progress, cancel
        Passed to the fit (``progress(done, total)`` renders); ``cancel()`` is also
        asked before each simulated colony of the compaction, and ``True`` raises
        :class:`~napari_symbac.fit.FitCancelled` (the dock widget's Cancel).
    stage
        Called with a few words when a long stage after the fit begins (the packing
        search of dense colonies, which simulates colonies and renders nothing), so that
        a status line does not keep showing the fit's last render count.
    pixel_note
        A sentence saying the pixel size and where it came from (e.g.
        :func:`~napari_symbac.fit.preflight.resolve_pixel_size`'s), said when the cells
        (the masks', or without them the fit's) are wider than any rod
        (:func:`_refuse_wide_cells`); default: ``microscope``'s.

    Returns
    -------
    Calibration

    Raises
    ------
    ValueError
        Bad image, masks or labels (the ``fit`` command's refusals), a modality the
        image contradicts, cells wider than any rod at the pixel size given.
    """
    from napari_symbac.fit.camera_estimate import censored_pixels, image_bit_depth
    from napari_symbac.fit.fitted_settings import drawn_colony_phase
    from napari_symbac.fit.masks import estimate_pixel_size_um
    from napari_symbac.fit.preflight import (
        camera_recording_problem,
        check_class_labels,
        check_fit_image,
        check_instance_masks,
        check_modality,
        check_pixel_size,
        modality_doubt,
    )

    require_argument(microscope, Microscope, "calibrate(microscope=...)")
    frame = np.asarray(image)
    if frame.ndim != 2:  # found as an API user: a stack was "masks of another shape"
        raise ValueError(
            f"calibrate(image=...) takes one 2D frame, got an array of shape {frame.shape}: "
            "pass one frame of a stack (e.g. stack[0])"
        )
    check_fit_image(frame, "image")
    if masks is not None and labels is not None:
        raise ValueError("pass masks or labels, not both")
    if modality is not None and modality != microscope.modality:
        microscope = dataclasses.replace(microscope, modality=modality)
    _refuse_a_trench(frame.shape, microscope.modality)
    if labels is not None:
        check_class_labels(np.asarray(labels), frame.shape, "labels")
    if masks is not None:
        check_instance_masks(np.asarray(masks), frame.shape, "masks")
        masks = instance_masks(masks)
    check_modality(frame, microscope.modality, labels=labels, masks=masks)
    fit_optics, start = _stain_model(microscope.modality, envelope_stain, depth_layers)
    notes = []
    if (note := modality_doubt(frame, microscope.modality)) is not None:
        notes.append(note)
    if pixel_note is None:
        pixel_note = f"pixel size {microscope.pixel_size_um:.4g} um from microscope"
    if cell_width_um is not None:
        if masks is None:
            raise ValueError(
                "cell_width_um sets the pixel size from the masks' widths: pass masks too"
            )
        px = estimate_pixel_size_um(masks, cell_width_um)
        microscope = dataclasses.replace(microscope, pixel_size_um=px)
        notes.append(
            f"pixel size {px:.4f} um = cell width {cell_width_um} um / median mask width"
        )
    elif masks is not None:
        from napari_symbac.fit.masks import cell_widths_px

        widths_um = cell_widths_px(masks) * microscope.pixel_size_um
        _refuse_wide_cells(widths_um, "the masks' cells", pixel_note)
    check_pixel_size(microscope.pixel_size_um, pixel_note)
    if camera is not None and (problem := camera_recording_problem(camera, frame)):
        raise ValueError(f"calibrate(camera=...): {problem}")
    bit_depth = image_bit_depth(frame)
    mask_offset_um = mask_faintest_cnr = None
    layout = None  # the simulated field: that of the measurements
    valid = ~censored_pixels(frame, camera)
    if not valid.all():
        notes.append(
            f"censored pixels: {int((~valid).sum())} ({100 * (~valid).mean():.2f} %), clipped "
            "at the image's lowest or highest grey level (saturated, or background-subtracted "
            "to 0): left out of every measurement and fit"
        )
    frame = frame.astype(np.float64)
    if masks is not None:  # at least 16 cell widths across, to hold whole cells
        from napari_symbac.fit.masks import cell_widths_px

        crop_px = 160 if crop_px is None else crop_px
        crop_px = max(crop_px, round(16 * float(np.median(cell_widths_px(masks)))))
        crop = best_crop(masks, crop_px)
    else:
        crop_px = NO_MASKS_CROP_PX if crop_px is None else crop_px
        rough = _rough_cells(frame, microscope.modality, microscope.pixel_size_um)
        crop = best_crop(rough, crop_px)
    crop_image = frame[crop]
    crop_masks = None if masks is None else masks[crop]
    crop_labels = None if labels is None else np.asarray(labels)[crop]
    from napari_symbac.fit.colony import colony_cell_gains, colony_optics, is_dense_colony

    dense = is_dense_colony(crop_masks, microscope.modality)
    crop_m = None  # the crop's masks, measured once
    if dense:
        from napari_symbac.export.visibility import pixel_noise

        background = ~(np.asarray(crop_masks) > 0)
        noise = pixel_noise(crop_image, background)
        base_camera = Camera(baseline_adu=0.0, bit_depth=bit_depth) if camera is None else camera
        result, scene, _ = colony_optics(
            crop_image,
            crop_masks,
            microscope,
            base_camera,
            noise,
            max_evaluations,
            progress=progress,
            cancel=cancel,
        )
        # rendered as fitted: the upsampling that samples the image band (1 for pixels
        # finer than lambda / 4 NA); the partially coherent model sums source points, so
        # a 3x finer grid would cost 9x per image
        done = result.n_evaluations  # the cells' renders count on from the optics'
        gains = colony_cell_gains(
            crop_image - base_camera.baseline_adu, scene, microscope, base_camera,
            result.render, max_evaluations, cancel=cancel,
            progress=None if progress is None else lambda k, n: progress(done + k, done + n),
        )  # fmt: skip
        render, note = _with_own_optical_paths(result.render, gains)
        fitted_camera = base_camera
        chi2 = (result.objective_before, result.objective_after)
        method = "masks + partially coherent fit"
        notes.append(
            f"dense phase colony ({100 * (crop_masks > 0).mean():.0f} % of the crop is cell): "
            f"partially coherent phase model fitted to the scene of the masks "
            f"({result.n_evaluations} renders): phase {render.cell_phase_rad:.2f} rad, "
            f"apodisation {render.apodisation_sigma_um:.2f} um, ring width "
            f"{render.phase_ring_width_scale:.2f}"
        )
        notes.append(
            f"noise: Gaussian, {render.gaussian_noise_sd_adu:.2f} ADU (background pixel "
            f"differences, at least 0.5), camera baseline {fitted_camera.baseline_adu:g} ADU, "
            f"{fitted_camera.bit_depth} bit"
        )
        notes.append(note)
        notes.extend(f"fit warning: {w}" for w in result.warnings)
        width_fit, length_scale = None, 1.0
        field_masks = masks
    else:
        result = _fit_scene_crop(
            crop_image,
            crop_masks,
            microscope,
            start,
            camera,
            crop_labels,
            max_iterations,
            progress,
            cancel,
            fit_optics,
        )
        fitted_camera = dataclasses.replace(
            result.camera or camera or Camera(), bit_depth=bit_depth
        )
        render = result.render
        chi2 = (result.objective_before, result.objective_after)
        method = "scene fit"
        notes.append(
            f"scene fit of a {crop_image.shape[0]} x {crop_image.shape[1]} crop (rows "
            f"{crop[0].start}-{crop[0].stop}, columns {crop[1].start}-{crop[1].stop}): "
            f"{len(result.cells)} cells; intensities cell {render.cell_intensity:.0f}, "
            f"media {render.media_intensity:.0f} ADU; defocus {render.defocus_sigma_um:.2f} um"
            + _stain_words(render, envelope_stain)
        )
        notes.extend(f"fit warning: {w}" for w in result.warnings)
        if masks is None:
            _refuse_wide_cells(result.cells.width_um, "the fit's cells", pixel_note)
        width_fit = float(np.median(result.cells.width_um)) if len(result.cells) else None
        length_scale = 1.0
        if masks is not None and len(result.cells):
            crop_m = measure_field(crop_image, crop_masks, valid=valid[crop])
            mask_len = float(np.median(crop_m.of_whole_cells(crop_m.lengths_px)))
            mask_len *= microscope.pixel_size_um
            length_scale = float(np.clip(np.median(result.cells.length_um) / mask_len, 0.7, 1.3))
            field_masks = masks
            if microscope.modality in ("fluorescence", "brightfield"):
                mask_offset_um, note = _outline_offset_um(
                    crop_image,
                    crop_masks,
                    result,
                    microscope,
                    valid[crop],
                )
                notes.append(note)
                mask_faintest_cnr, note = _faintest_masked_cnr(frame, masks)
                notes.append(note)
        else:  # the fit's own cells are the masks: sizes from the crop
            field_masks = np.asarray(result.scene.camera_labels(), np.int32)
            if not (field_masks > 0).any():
                raise ValueError(
                    "the fit found no cell in the crop: give the cells' masks (calibrate "
                    "--masks; in napari, the Calibrate step's cell masks) or paint cell and "
                    "media --labels"
                )
            outside = _clusters_outside(rough, crop, field_masks)
            image_shape = frame.shape
            frame, valid = crop_image, valid[crop]
    measurements = measure_field(frame, field_masks, valid=valid)
    if masks is None:  # the whole image's layout: the crop's clusters and those outside it
        layout = (image_shape, measurements.cluster_sizes.size + outside)
        notes.append(
            "no masks: sizes from the fit's cells on the crop; the simulated field is the "
            f"whole image ({image_shape[0]} x {image_shape[1]} px) with its {layout[1]} "
            f"clusters of cells: the fit's {measurements.cluster_sizes.size} on the crop "
            f"and {outside} outside it (Otsu regions of the smoothed image at least half "
            "the fitted cells' median area), since the crop holds the most cells and its "
            "density would overstate the field's"
        )
    if microscope.modality == "fluorescence":
        if masks is not None:
            if crop_m is None:
                crop_m = measure_field(crop_image, crop_masks, valid=valid[crop])
            render, note = _with_field_brightness(render, measurements, crop_m)
            notes.append(note)
        render, note = _with_brightness_cv(measurements, render)
        notes.append(note)
        if render.cell_intensity <= render.media_intensity:
            raise ValueError(
                "the fitted fluorescent cells are not brighter than the background: check "
                "the modality and the masks"
            )
        render, note = _with_debris(frame, field_masks, valid, microscope, render)
        notes.append(note)
    if microscope.modality == "brightfield":
        render, note = _with_texture(frame, field_masks, valid, microscope, render)
        notes.append(note)
    uncounted_noise = None if dense or camera is not None else _uncounted_noise_adu(
        frame, valid, np.asarray(field_masks) > 0
    )
    if uncounted_noise is not None:
        render = dataclasses.replace(
            render, noise_model="gaussian", gaussian_noise_sd_adu=uncounted_noise
        )
        notes.append(
            "camera: not measurable from the image (its pixel variance does not grow with "
            "the mean: not raw counts, e.g. flattened or rescaled); noise Gaussian, "
            f"{uncounted_noise:.3g} ADU, the image's own pixel noise (differences of "
            "neighbouring background pixels; the fit's residual would count its misfit "
            "as noise); a real camera's file (`napari-symbac calibrate --camera C.yaml`) "
            "replaces it"
        )
    settings, more = settings_from_fit(
        measurements,
        microscope,
        render,
        fitted_camera,
        width_um=width_fit,
        length_scale=length_scale,
        layout=layout,
    )
    if microscope.modality == "fluorescence":
        from napari_symbac.fit.clipped_background import clipped_background, drawn_clipped

        clipped = clipped_background(frame, np.asarray(field_masks) > 0, ~valid)
        if clipped is not None:
            settings, note = drawn_clipped(settings, clipped, noise=camera is None)
            more.append(note)
    if not dense and uncounted_noise is None:  # the camera drawn (a clipped background's)
        notes.append("camera: " + _camera_note(settings.camera, camera))
    packing, trials = None, []
    if masks is not None:
        packing = measure_packing(field_masks)
        if packing.n_colonies:
            if stage is not None:
                stage("choosing the colonies' packing (simulating colonies under gravity)")
            settings, trials, note = compacted(
                settings,
                packing,
                float(np.median(measurements.of_whole_cells(measurements.lengths_px))),
                cancel,
            )
            more.append(note)
    if dense:
        settings, note = drawn_colony_phase(settings)
        more.append(note)
    return Calibration(
        settings=settings,
        measurements=measurements,
        reference=frame,
        masks=field_masks,
        crop=crop,
        method=method,
        fit_chi2=(float(chi2[0]), float(chi2[1])),
        packing=packing,
        compaction=tuple(trials),
        notes=(*notes, *more),
        mask_offset_um=mask_offset_um,
        mask_faintest_cnr=mask_faintest_cnr,
        cautions=_width_cautions(settings.simulation.cell_width_um, pixel_note),
    )


def _width_cautions(width_um: float, pixel_note: str) -> tuple[str, ...]:
    """A warning when the dataset's cells are wider or narrower than bacteria
    (:func:`~napari_symbac.fit.report.unusual_width_words`, the fit's report's rule).

    Found as a user: Omnipose's Sample000193 calibrated at 0.134 um/px (its cells are 1 um
    at 0.0745) exported cells 1.80 um wide without a word, where Auto-fit on the same
    image warned; cells wider than any rod are refused before (:func:`_refuse_wide_cells`).
    """
    from napari_symbac.fit.report import unusual_width_words

    unusual = unusual_width_words(width_um)
    if unusual is None:
        return ()
    return (
        f"the dataset's cells are {width_um:.2f} um wide, {unusual} ({pixel_note}); with "
        "masks, calibrate --cell-width-um (in napari, the Calibrate step's cell width) "
        "sets it from the cells' width",
    )


def _refuse_wide_cells(widths_um: np.ndarray, whose: str, pixel_note: str) -> None:
    """:func:`~napari_symbac.fit.start.refuse_wide_cells` with calibrate's other way:
    the pixel size from the masks' widths."""
    from napari_symbac.fit.start import refuse_wide_cells

    refuse_wide_cells(
        widths_um,
        whose,
        pixel_note,
        ", or set it from the masks with the cells' width (calibrate --cell-width-um; in "
        "napari, the Calibrate step's cell width)",
    )


def _uncounted_noise_adu(
    frame: np.ndarray, valid: np.ndarray, cells: np.ndarray
) -> float | None:
    """The pixel noise (ADU) of an image whose noise is no camera's, for the dataset's
    Gaussian noise; ``None`` when photon transfer measures a camera (raw counts: the
    variance grows with the mean, a slope at least
    :data:`~napari_symbac.fit.camera_estimate.MEASURED_SLOPE_SE` standard errors above
    0, :func:`~napari_symbac.fit.camera_estimate.estimate_camera`; the ColiCoords
    fluorescence fields give 12-22).

    Found calibrating ColiCoords' bright field (flattened: the variance falls with the
    mean, or on a 192 x 256 crop rises by 0.2 standard errors): the fit, finding no
    camera, takes its residual's mean square, misfit included, and the dataset was drawn
    with twice the recording's pixel noise. Here the noise is that of neighbouring valid
    background pixels more than 3 px from a cell
    (:func:`~napari_symbac.export.visibility.pixel_noise`), blind to smooth misfit.
    """
    from scipy import ndimage

    from napari_symbac.export.visibility import pixel_noise
    from napari_symbac.fit.camera_estimate import estimate_camera

    try:
        estimate_camera(frame, valid=valid)
        return None
    except ValueError:
        pass
    background = valid & ~ndimage.binary_dilation(cells, iterations=3)
    noise = pixel_noise(frame, background)
    return float(noise) if math.isfinite(noise) and noise > 0 else None


def _outline_offset_um(
    crop_image: np.ndarray,
    crop_masks: np.ndarray,
    result: SceneFit,
    microscope: Microscope,
    valid: np.ndarray,
) -> tuple[float | None, str]:
    """How far the dataset's masks grow beyond the model cells to follow the masks'
    outline (um, :attr:`Calibration.mask_offset_um`), and a note; ``None`` when no mask
    matches a model cell.

    Fluorescence: read in the light (:func:`~napari_symbac.export.outline.outline_level`):
    the masks' outline lies at some fraction of their cells' core brightness, and the
    model cells are grown until their outline lies at that fraction of the fitted
    model's image (:func:`~napari_symbac.export.outline.level_matched_growth_px`). A
    bright-field outline is no fraction of a cell's light (dark and bright rims): there,
    and when the light gives no level, the geometric offset
    (:func:`~napari_symbac.export.outline.outline_offset_px`), median over the cells.
    """
    from napari_symbac.export.outline import (
        level_matched_growth_px,
        outline_level,
        outline_offset_px,
    )

    px = microscope.pixel_size_um
    model_labels = np.asarray(result.scene.camera_labels())
    offsets = outline_offset_px(crop_masks, model_labels)
    if not offsets.size:
        return None, "mask outline: no mask matches a fitted cell, not measured"
    geometric = float(np.median(offsets)) * px
    spread = (
        f"median of {offsets.size} cells, quartiles {np.percentile(offsets, 25) * px:+.3f} "
        f"to {np.percentile(offsets, 75) * px:+.3f} um"
    )
    if microscope.modality == "fluorescence":
        levels = outline_level(crop_image, crop_masks, valid=valid)
        model_levels = outline_level(result.synthetic, model_labels)
        if levels.size and model_levels.size:
            level = float(np.median(levels))
            growth = level_matched_growth_px(level, result.synthetic, model_labels)
            if growth is not None:
                offset = growth * px
                return offset, (
                    f"mask outline at {level:.2f} of the cells' core brightness above the "
                    f"background (median of {levels.size} cells; the fitted model's outline "
                    f"at {float(np.median(model_levels)):.2f}): the dataset's masks grow by "
                    f"{offset:.3f} um, where the model's light falls to that level "
                    f"(ExportSettings.mask_dilation_um; by area the masks lie {geometric:+.3f} "
                    f"um outside the fitted cells, {spread})"
                )
    return geometric, (
        f"mask outline {geometric:+.3f} um outside the fitted cells ({spread}): the "
        "dataset's masks grow by it (ExportSettings.mask_dilation_um)"
    )


def _cut_cells_words(measurements: FieldMeasurements) -> str:
    """``"; N cells cut by the image's border ..."`` when the border cuts some cells but
    not all (:meth:`FieldMeasurements.of_whole_cells`), else ``""``."""
    cut = int((~measurements.whole).sum())
    if not cut or cut == measurements.n_cells:
        return ""
    return (
        f"; {cut} cell(s) cut by the image's border left out of the sizes and the "
        "brightness spread (counted in the layout)"
    )


#: Whole cells (with background around them) the masks need before their faintest cell
#: sets which synthetic cells the dataset marks (:attr:`Calibration.mask_faintest_cnr`).
VISIBILITY_MIN_CELLS = 5
#: The most the masks' faintest cell raises the dataset's visibility threshold to
#: (contrast-to-noise). The faintest marked cell only bounds the annotator's threshold
#: from above; it says where the threshold lies when it is near the noise (ColiCoords
#: ds1 field 1: 4.8, with unmarked blobs at 0.2-3), not when every cell is bright (ds2
#: field 00066: 116, when synthetic cells of 104-115, plain to any eye, were unmarked).
VISIBILITY_MAX_CNR = 10.0


def _faintest_masked_cnr(frame: np.ndarray, masks: np.ndarray) -> tuple[float | None, str]:
    """Contrast-to-noise of the faintest cell ``masks`` mark in ``frame``
    (:attr:`Calibration.mask_faintest_cnr`), and a note.

    Cells cut by the image's border are left out: a sliver of a cell at the edge is no
    sample of what the annotator marked. The faintest of ``n`` cells bounds the
    annotation's threshold from above, and a few cells, all bright, would set it above
    most cells of the matched dataset: ``None`` with fewer than
    :data:`VISIBILITY_MIN_CELLS` cells.
    """
    from napari_symbac.export.outline import border_ids
    from napari_symbac.export.visibility import contrast_to_noise

    cut = set(border_ids(masks).tolist())
    cnr = np.array(
        [v for c, v in contrast_to_noise(frame, masks).items() if c not in cut and np.isfinite(v)]
    )
    if cnr.size < VISIBILITY_MIN_CELLS:
        return None, (
            f"masks' faintest cell: {cnr.size} whole cell(s) with background around them, "
            f"too few (< {VISIBILITY_MIN_CELLS}) to say which faint cells the annotation "
            "leaves out; the dataset drops only the cells its noise hides (contrast-to-noise "
            "below 1)"
        )
    faintest = float(cnr.min())
    words = (
        f"masks' faintest cell: contrast-to-noise {faintest:.1f} (of {cnr.size} cells, median "
        f"{np.median(cnr):.1f}): "
    )
    if faintest > VISIBILITY_MAX_CNR:
        return faintest, words + (
            f"every marked cell is plain above the noise, which says no more than that no "
            f"fainter cell was there; the dataset's masks leave out synthetic cells below "
            f"{VISIBILITY_MAX_CNR:g} (ExportSettings.visibility)"
        )
    return faintest, words + (
        "the dataset's masks leave out synthetic cells fainter than it, as the annotation "
        "leaves out cells fainter than that (ExportSettings.visibility)"
    )


#: Largest per-cell brightness CV a calibration draws: the gains are gamma
#: (:func:`~napari_symbac.pipeline.cell_brightness_gains`), and one of CV above 1 piles
#: its cells up at zero brightness, while a field's masked cells are visible.
MAX_BRIGHTNESS_CV = 1.0


def _with_field_brightness(render, field, crop) -> tuple[RenderSettings, str]:
    """Render settings whose cell contrast ``I_c - I_m`` is the field's mean cell, and a
    note.

    The per-cell gains have mean 1 (:func:`~napari_symbac.pipeline.cell_brightness_gains`),
    so the fitted contrast, which holds the crop's cells only, is scaled by the mean
    brightness above the background of the field's whole cells over that of the crop's
    (ColiCoords ds3 frame 2: the crop held the two dimmest of four cells, 388 and 418
    ADU against a mean of 1885, and every synthetic cell came out 4-5 times too dim).
    """
    whole, part = field.of_whole_cells(field.brightness_adu), crop.of_whole_cells(
        crop.brightness_adu
    )
    if not (whole.size and part.size and part.mean() > 0 and whole.mean() > 0):
        return render, "cell brightness: the fit's (no whole cell to compare the crop's with)"
    scale = float(whole.mean() / part.mean())
    contrast = render.cell_intensity - render.media_intensity
    render = dataclasses.replace(render, cell_intensity=render.media_intensity + scale * contrast)
    return render, (
        f"cell brightness: the field's {whole.size} whole cells are on average x{scale:.2f} "
        f"as bright above the background as the crop's {part.size} ({whole.mean():.0f} "
        f"against {part.mean():.0f} ADU): cell intensity {render.cell_intensity:.0f} ADU, "
        "the field's mean cell (the gains of the per-cell brightness CV have mean 1)"
    )


def _with_own_optical_paths(render: RenderSettings, gains) -> tuple[RenderSettings, str]:
    """``render`` drawing cells whose optical paths differ as the colony's do, and a note.

    ``gains``: each masked cell's own gain on its phase, fitted on the fitted optics
    (:func:`~napari_symbac.fit.colony.colony_cell_gains`, as ``fit_colony`` does); their
    spread less the errors' becomes ``cell_brightness_cv`` (the Omnipose colonies:
    0.10-0.19). None (fewer cells than a spread needs) or gains that did not lower the
    residual: ``render`` as it is.
    """
    if gains is None:
        return render, "cells' optical paths: alike (fewer than 3 cells in the crop)"
    if not gains.improved:
        return render, "cells' optical paths: alike (no gain per cell lowered the residual)"
    values = np.array(list(gains.gains.values()))
    low, high = np.percentile(values, [5, 95])
    render = gains.render_with_spread(render)
    return render, (
        f"cells' own optical paths ({len(values)} cells of the crop, {gains.n_evaluations} "
        f"renders): gains {low:.2f}-{high:.2f} of the fitted phase (5-95 %), residual rms "
        f"{gains.rms_before_adu:.2f} -> {gains.rms_after_adu:.2f} ADU; drawn with per-cell "
        f"brightness CV {render.cell_brightness_cv:.2f}, at most "
        f"x{render.cell_brightness_max_gain:.2f} the mean cell"
    )


def _with_brightness_cv(measurements, render) -> tuple[RenderSettings, str]:
    """Render settings with the field's per-cell brightness CV and its bound, and a note.

    The CV of the whole cells' medians above the background, at most
    :data:`MAX_BRIGHTNESS_CV`; the note gives the cells it comes from and its standard
    error ``cv sqrt((1 + 2 cv^2) / 2n)`` (ColiCoords ds3 frame 2: 1.21 from 4 cells of
    388-5213 ADU, drawn as a gamma of shape 0.68 most items lost 1-3 of their 4 cells
    as fainter than the noise, and some were darker than the background). The gains
    are bounded by the brightest whole cell over their mean
    (``cell_brightness_max_gain``): ColiCoords ds1 field 5, CV 0.99 from 4 cells,
    exported cells up to 2.4x as bright as its brightest cell without the bound.
    """
    cv = measurements.brightness_cv
    brightness = np.abs(measurements.of_whole_cells(measurements.brightness_adu))
    n = int(brightness.size)
    drawn = float(min(cv, MAX_BRIGHTNESS_CV))
    se = cv * math.sqrt((1 + 2 * cv * cv) / (2 * max(n, 1)))
    note = (
        f"per-cell brightness CV {cv:.2f} +- {se:.2f} (masks' medians above background, "
        f"{n} whole cells)"
    )
    if drawn < cv:
        note += (
            f"; drawn as {drawn:.2f}, the most a gamma of per-cell gains may have without "
            "piling its cells up at zero brightness"
        )
    if drawn == 0:
        return dataclasses.replace(render, cell_brightness_cv=0.0), note
    max_gain = max(float(brightness.max() / brightness.mean()), 1.0)
    note += f"; no cell brighter than x{max_gain:.2f} the mean cell, the field's brightest"
    return dataclasses.replace(
        render, cell_brightness_cv=drawn, cell_brightness_max_gain=max_gain
    ), note


#: Fewest blobs outside the masks for the debris to be rendered.
_MIN_DEBRIS_BLOBS = 3


def _with_debris(frame, masks, valid, microscope, render) -> tuple[RenderSettings, str]:
    """Render settings with the field's debris (:func:`measure_debris`) and a note.

    Density, diameter (log-normal median and CV) and extra blur come from the blobs as
    measured; the brightness ``b`` (of the unblurred particle, a fraction of the
    fitted full-depth cell column ``I_c - I_m``) is the blobs' median peak over the
    peak of one ``b = 1`` particle of the median diameter rendered by the fitted
    forward model (PSF, defocus of eq. 14, resampling; :func:`_particle_peak_adu`),
    both seen through the same 1 px smoothing.
    """
    px = microscope.pixel_size_um
    debris = measure_debris(frame, masks, px, valid=valid)
    if debris.n_blobs < _MIN_DEBRIS_BLOBS:
        return render, (
            f"debris: {debris.n_blobs} blob(s) outside the masks "
            f"({debris.free_area_um2:.0f} um^2 searched): none rendered"
        )
    diameter = float(np.median(debris.diameters_um))
    blur = float(np.median(debris.blur_sigma_um))
    unit = _particle_peak_adu(microscope, render, diameter, blur)
    brightness = float(min(np.median(debris.peaks_adu) / max(unit, 1e-9), 1.0))
    render = dataclasses.replace(
        render,
        debris_density_per_100um2=debris.density_per_100um2,
        debris_diameter_um=diameter,
        debris_diameter_cv=float(min(_cv(debris.diameters_um), 2.0)),
        debris_brightness=brightness,
        debris_brightness_cv=float(min(_cv(debris.peaks_adu), 2.0)),
        debris_defocus_sigma_um=blur,
    )
    return render, (
        f"debris: {debris.n_blobs} blobs outside the masks, "
        f"{debris.density_per_100um2:.2f} per 100 um^2; diameter {diameter:.2f} um "
        f"(CV {render.debris_diameter_cv:.2f}), median peak "
        f"{np.median(debris.peaks_adu):.0f} ADU above the pad = brightness {brightness:.2f} "
        f"of a cell column (CV {render.debris_brightness_cv:.2f}), extra blur {blur:.2f} um"
    )


def _with_texture(frame, masks, valid, microscope, render) -> tuple[RenderSettings, str]:
    """Render settings with the background's texture (:func:`measure_texture`) and a note:
    ``texture_amplitude`` its rms over the media level (eq. 3: the texture multiplies
    the media), ``texture_scale_um`` twice its correlation length (the lattice spacing
    of a Perlin texture whose autocovariance falls to ``1/e`` near half of it).
    Bright field only: there the texture is the pad's own light, while the
    fluorescence and phase calibrations are left as their benchmarks measured them."""
    px = microscope.pixel_size_um
    texture = measure_texture(frame, masks, px, valid=valid)
    if texture is None or render.media_intensity <= 0:
        return render, "background texture: none measurable beside the pixel noise"
    render = dataclasses.replace(
        render,
        texture_amplitude=texture.rms_adu / render.media_intensity,
        texture_scale_um=2.0 * texture.correlation_px * px,
    )
    return render, (
        f"background texture: {texture.rms_adu:.3g} ADU rms beside {texture.noise_adu:.3g} "
        f"ADU of pixel noise, correlation length {texture.correlation_px:.1f} px "
        f"({texture.correlation_px * px:.2f} um; away from the cells, trend removed): "
        f"drawn as a Perlin texture of {render.texture_amplitude:.3g} of the media, "
        f"lattice {render.texture_scale_um:.2f} um"
    )


def _particle_peak_adu(
    microscope: Microscope, render: RenderSettings, diameter_um: float, blur_um: float
) -> float:
    """Peak above the pad (ADU, image smoothed by 1 px) of one debris particle of
    brightness 1, ``diameter_um`` and blur ``blur_um``, rendered without noise."""
    from scipy import ndimage

    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Scene
    from napari_symbac.scene._debris import particle_image

    u, border, side = render.upsample, render.psf_radius_px, 33
    shape = (side * u + 2 * border,) * 2
    fine_um = microscope.pixel_size_um / u
    particle = particle_image(0.5 * diameter_um / fine_um, blur_um / fine_um)
    cells = np.zeros(shape, np.float32)
    h, c = particle.shape[0] // 2, shape[0] // 2 - (u // 2 if u % 2 == 0 else 0)
    cells[c - h : c + h + 1, c - h : c + h + 1] = np.minimum(particle, 1.0)
    scene = Scene(
        cells=cells,
        media=1.0 - cells,
        device=np.zeros(shape, np.float32),
        labels=np.zeros(shape, np.uint32),
        border_px=border,
        upsample=u,
        camera_shape=(side, side),
        pixel_size_um=fine_um,
        depth_um=1.0,
    )
    clean = ForwardModel(microscope, render, Camera()).render_clean(scene, cache=False)
    smooth = ndimage.gaussian_filter(np.asarray(clean, np.float64), 1.0)
    return float(smooth.max() - np.median(smooth))


def _cv(values: np.ndarray) -> float:
    if values.size < 2 or values.mean() <= 0:
        return 0.0
    return float(values.std(ddof=1) / values.mean())


def _camera_note(used: Camera, given: Camera | None) -> str:
    from napari_symbac.fit.report import read_noise_note

    source = "given" if given is not None else "measured from the image"
    said = None if given is not None else read_noise_note(used)
    return (
        f"{source}: baseline {used.baseline_adu:.1f} ADU, sensitivity "
        f"{used.sensitivity_adu_per_e:.3g} ADU/e-, read noise {used.dark_noise_e:.3g} e-"
        + (f" ({said})" if said else "")
        + f", {used.bit_depth} bit"
    )


#: Items of the matched dataset that :func:`compare_with_dataset` pools (the first ones:
#: each from its own simulation). A dataset's items differ in layout and light; one item
#: alone flipped the report between 0 and 3 of 4 comparisons matched (ColiCoords' bright
#: field, docs/proof.md).
COMPARED_ITEMS = 4


def compare_with_dataset(
    calibration: Calibration,
    settings: ExportSettings,
    *,
    masks_given: bool,
    words: AdviceWords | None = None,
    n_items: int = COMPARED_ITEMS,
) -> tuple[Comparison, list[ExportItem]]:
    """The recording against the first ``n_items`` items of the dataset of ``settings``
    (:func:`export_settings`; at most its size), pooled
    (:func:`~napari_symbac.calibrate.compare_images`), and those items: the report's
    comparison and its pictures.

    ``words``: the interface's (:data:`~napari_symbac.calibrate.compare.CLI_WORDS` by
    default). The simulations are cached in the process, so an export that follows does
    not simulate them again.
    """
    from napari_symbac.calibrate.compare import CLI_WORDS, compare_images
    from napari_symbac.export.dataset import PipelineSource

    source = PipelineSource(settings)
    items = [source.make_unit(unit)[0] for unit in range(min(n_items, settings.n_items))]
    render = settings.pipeline.render
    comparison = compare_images(
        calibration.reference,
        calibration.masks,
        [item.image for item in items],
        [item.labels for item in items],
        masks_given=masks_given,
        words=CLI_WORDS if words is None else words,
        sub_level_noise=render.noise_model == "gaussian" and render.gaussian_noise_sd_adu < 1,
    )
    return comparison, items


def items_words(count: int) -> str:
    """The dataset items a comparison pools, in the report's words: ``"item 0"``,
    ``"items 0-3, pooled"``."""
    return "item 0" if count == 1 else f"items 0-{count - 1}, pooled"


def export_settings(
    calibration: Calibration,
    *,
    n_items: int,
    formats: tuple[str, ...] | list[str] = ("tiff",),
    seed: int = 0,
    val_fraction: float = 0.1,
):
    """The :class:`~napari_symbac.export.ExportSettings` of a matched training dataset.

    Images are independent frames drawn near the end of the simulated growth (colonies
    as large as the recording's), from up to 16 simulations (colony places differ), and
    cells the image does not show (contrast-to-noise below 1,
    :mod:`~napari_symbac.export.visibility`) are dropped from the masks: a network must
    not learn to find cells in the noise. With masks (fluorescence, bright field) the
    threshold is the contrast-to-noise of their faintest cell
    (``calibration.mask_faintest_cnr``) when that is higher, up to
    :data:`VISIBILITY_MAX_CNR`: the annotation's convention of what counts as a cell.
    On the ColiCoords transfer benchmark (field 1's masks, faintest cell 4.8) this raised
    the network's mean F1 on fields 2-10 over four seeds from 0.632 to 0.799
    (docs/proof.md): trained with faint cells marked, it had called blobs of noise cells.
    The images are varied as the default export varies them
    (:func:`~napari_symbac.export.dataset.default_randomisation`): the fitted defocus
    kept (eq. 14); in bright field the light as a whole, never past the camera's full
    scale; with the partially coherent phase model (dense phase colonies) the cells'
    bright-field transmission within its physical range
    (:data:`~napari_symbac.export.dataset.PHASE_TRANSMISSION_SCALE`).

    Fluorescence or bright field with masks: the dataset's masks follow their outline
    convention, grown by ``calibration.mask_offset_um`` (``mask_dilation_um``; an offset
    inside the model cell is not applied: masks are never shrunk). In fluorescence the
    light is not varied between images (``Randomisation.exposure_scale`` stays 1): on
    the ColiCoords transfer benchmark every range tried lowered the mean F1 of the
    calibration without masks (docs/proof.md); in bright field it is, as a whole.
    """
    from napari_symbac.export.dataset import ExportSettings, default_randomisation
    from napari_symbac.export.visibility import Visibility

    n_frames = calibration.settings.simulation.n_frames
    first = max(0, n_frames - 1 - (n_frames - 1) // 8)
    return ExportSettings(
        n_items=n_items,
        kind="frames",
        formats=list(formats),
        seed=seed,
        val_fraction=val_fraction,
        n_simulations=min(n_items, 16),
        first_frame=first,
        pipeline=calibration.settings,
        visibility=Visibility(
            min_contrast_to_noise=float(
                np.clip(calibration.mask_faintest_cnr or 1.0, 1.0, VISIBILITY_MAX_CNR)
            ),
            action="drop",
        ),
        randomise=default_randomisation(calibration.settings),
        mask_dilation_um=max(0.0, round(calibration.mask_offset_um or 0.0, 4)),
    )
