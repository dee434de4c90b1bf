"""Checks of a fit's inputs before any work: refuse what cannot be fitted, say what to pass.

Each check raises :class:`ValueError` with a message naming the problem and the fix, so
that the ``napari-symbac fit`` command can print it and exit non-zero before it writes
anything.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np
from scipy import ndimage

from napari_symbac.settings import Camera, Microscope

__all__ = [
    "API_CAMERA_HINT",
    "BELOW_OFFSET_FRACTION",
    "BRIGHT_FIELD_NOTE",
    "CAMERA_PIXEL_UM",
    "MAX_FIT_PIXELS",
    "MAX_ROD_FILL",
    "MODALITY_ADVICE",
    "PHASE_NOTE",
    "PLAUSIBLE_PIXEL_UM",
    "TRENCH_MAX_WIDTH_PX",
    "TRENCH_MIN_ASPECT",
    "ModalityAdvice",
    "as_instance_ids",
    "camera_pixel_problem",
    "camera_recording_problem",
    "check_class_labels",
    "check_fit_image",
    "check_instance_masks",
    "check_modality",
    "check_pixel_size",
    "default_geometry",
    "image_polarity",
    "looks_like_masks",
    "modality_doubt",
    "refuse_constant",
    "refuse_image_as_masks",
    "refuse_merged_cells",
    "refuse_non_finite",
    "resolve_pixel_size",
]

Polarity = Literal["bright cells", "dark cells", "unclear"]

#: Tails of the histogram, in noise SDs from the median, that decide the polarity: the
#: cells' side reaches past ``_FAR``, the other side stays within ``_NEAR`` (noise only).
_NEAR, _FAR = 5.0, 10.0
_HIGH_PASS = np.outer([1.0, -2.0, 1.0], [1.0, -2.0, 1.0]) / 6.0
#: Pixels of the ring around cells used to compare cells with their surroundings.
_RING_PX = 3


#: Where the Python functions' message on a shifted image sends the camera baseline.
API_CAMERA_HINT = "in camera=Camera(baseline_adu=...)"


def refuse_non_finite(image: np.ndarray, name: str) -> None:
    """Refuse an image with NaN or infinite pixels, naming how many and the fix."""
    bad = int(np.size(image) - np.count_nonzero(np.isfinite(image)))
    if bad:
        raise ValueError(
            f"{name} contains {bad} NaN or infinite pixels; replace them (e.g. "
            "numpy.nan_to_num) or crop them away"
        )


#: The most pixels per frame a fit takes (4096 x 4096; :func:`check_fit_image`).
MAX_FIT_PIXELS = 4096 * 4096


def check_fit_image(
    image: np.ndarray, name: str = "image", *, camera_hint: str = "with --camera"
) -> None:
    """Refuse images the forward model cannot produce, or a fit cannot hold.

    Parameters
    ----------
    image
        The frame to fit.
    name
        How the message names it.
    camera_hint
        Where the command takes the camera's ``baseline_adu`` (``fit``: ``--camera``;
        ``diagnose``: its microscope file), ending the message's advice.

    Raises
    ------
    ValueError
        For negative values (the model renders camera counts, baseline included), for
        an image whose values all lie within 0..1 (normalised, or a mask), and for
        other normalised values (:func:`~napari_symbac.io.as_counts` would map them):
        no camera counts, no noise to measure, and a dataset drawn from its fit holds
        only a few grey levels; for values beyond 16 bits (``as_counts`` divides
        them); for NaN or infinite pixels; and for a frame of more
        than :data:`MAX_FIT_PIXELS` or fewer than 8 pixels a side.
    """
    shape = np.shape(image)
    if len(shape) >= 2 and shape[-2] * shape[-1] > MAX_FIT_PIXELS:
        # found as a user: a 12000 x 12000 frame ran out of memory with a traceback in
        # the start's segmentation, a 6000 x 6000 one held 3.7 GB after a minute
        rows, cols = shape[-2:]
        raise ValueError(
            f"{name} is {rows} x {cols} px ({rows * cols / 1e6:.0f} Mpx), more than a fit "
            f"takes ({MAX_FIT_PIXELS / 1e6:.1f} Mpx, 4096 x 4096): fit a crop of it (time "
            "and memory grow with the pixels: a 512 x 512 field of 100 cells took 142 s "
            "on a 2-core machine, docs/fitting.md)"
        )
    if len(shape) >= 2 and min(shape[-2:]) < 8:  # what fit_scene and the camera take
        raise ValueError(
            f"{name} of shape {tuple(shape[-2:])} is too small to fit: it needs at least "
            "8 x 8 px (a whole cell and some background around it)"
        )
    if np.issubdtype(np.asarray(image).dtype, np.floating):
        # found as a user: an all-NaN TIFF opened in the docks as a recording
        refuse_non_finite(image, name)
    low = float(np.min(image))
    if low < 0:
        fractional = np.issubdtype(np.asarray(image).dtype, np.floating) and not np.all(
            np.mod(image, 1) == 0
        )
        counts_fix = (
            "add a constant so that all values are >= 0 and give that constant as "
            f"baseline_adu {camera_hint}"
        )
        normalised_fix = (
            "a normalised image opened by napari-symbac (the commands, or the Real image "
            "dock's 'or open') is read as counts, in Python by napari_symbac.io.as_counts"
        )
        # found as an API user: a normalised float image was told to add a constant first,
        # and only the second refusal named as_counts
        fixes = (
            f"{normalised_fix}; counts with their offset subtracted: {counts_fix}"
            if fractional
            else f"{counts_fix}; {normalised_fix}"
        )
        raise ValueError(
            f"{name} has negative values (minimum {low:.4g}): the fit needs camera counts "
            f"(ADU, camera baseline included). Pass the raw recording, or: {fixes}"
        )
    high = float(np.max(image))
    if low < high <= 1:  # (a constant image is refused as such: refuse_constant)
        raise ValueError(
            f"{name} holds values within 0..1 only (maximum {high:.4g}): a normalised image "
            "or a mask, not camera counts (ADU). Pass the raw recording as the camera wrote "
            "it; a normalised image opened by napari-symbac (the commands, or the Real "
            "image dock's 'or open') is read as counts, in Python by "
            "napari_symbac.io.as_counts"
        )
    from napari_symbac.io import as_counts

    mapping = as_counts(image)[1]
    if mapping is not None and mapping.divides:
        # found as a user: a sum projection (maximum 150140) fitted with a 16-bit
        # camera, its dataset clipped at 65535 over a fifth of its pixels, unsaid
        raise ValueError(
            f"{name} has values up to {high:.6g}, beyond the 16 bits (65535) of the "
            "synthetic camera the fit matches to it: read it with napari_symbac.io."
            "as_counts, which divides it into 16 bits (the commands and the Real image "
            "dock's 'or open' do)"
        )
    if mapping is not None:
        # found as a user: ColiCoords' flattened bright field (0.89..1.12, float) given to
        # calibrate() as it was: cells and media fitted at 0 ADU, a dataset of 1s
        raise ValueError(
            f"{name} holds normalised values ({low:.4g}..{high:.4g}, fractional floating "
            "point): not camera counts (ADU). Pass the raw recording, or read it as counts "
            "with napari_symbac.io.as_counts (the commands and the Real image dock's 'or "
            "open' do)"
        )


def _noise_sd(image: np.ndarray) -> float:
    z = ndimage.correlate(np.asarray(image, np.float64), _HIGH_PASS)[1:-1, 1:-1]
    return 1.4826 * float(np.median(np.abs(z - np.median(z))))


def image_polarity(image: np.ndarray) -> Polarity:
    """Whether the objects in a 2D image are brighter or darker than its background.

    The median is taken as the background. Fluorescence has bright objects and nothing
    darker than the background beyond noise; bright field has dark objects and nothing
    brighter. Phase contrast has both (dark cells with bright halos) and gives
    ``"unclear"``, as does any image whose cells cover most of it.

    On the real data: ColiCoords fluorescence fields reach 1.1-2.4 noise SDs below the
    median and 13-300 above; their bright-field fields 16-29 below and 2 above; phase
    contrast (SyMBac trench, Omnipose colonies) 13-73 below and 24-94 above.
    """
    below, above = _tails(np.asarray(image, np.float64))
    if not (math.isfinite(below) and math.isfinite(above)):
        return "unclear"
    if below < _NEAR and above > _FAR:
        return "bright cells"
    if above < _NEAR and below > _FAR:
        return "dark cells"
    return "unclear"


def _tails(frame: np.ndarray) -> tuple[float, float]:
    """How far the image's 0.5th and 99.5th percentiles lie below and above its median,
    in noise SDs (:func:`image_polarity`); ``nan`` for an image without noise."""
    sd = _noise_sd(frame)
    if not sd > 0:
        return math.nan, math.nan
    low, median, high = np.percentile(frame, [0.5, 50.0, 99.5])
    return (median - low) / sd, (high - median) / sd


def _class_polarity(image: np.ndarray, cells: np.ndarray, background: np.ndarray) -> Polarity:
    if not cells.any() or not background.any():
        return "unclear"
    difference = float(np.median(image[cells]) - np.median(image[background]))
    sd = max(_noise_sd(image), 1e-12)
    if abs(difference) < 3 * sd:
        return "unclear"
    return "bright cells" if difference > 0 else "dark cells"


@dataclasses.dataclass(frozen=True)
class ModalityAdvice:
    """What :func:`check_modality` advises, in an interface's words.

    Attributes
    ----------
    switch
        How to give the modality the image looks like (a format string of ``other``).
    paint
        How to paint the cell and media classes.
    """

    switch: str
    paint: str


#: The commands' words.
MODALITY_ADVICE = ModalityAdvice(switch="Pass --modality {other}", paint="paint --labels")


def check_modality(
    image: np.ndarray,
    modality: str,
    *,
    labels: np.ndarray | None = None,
    masks: np.ndarray | None = None,
    advice: ModalityAdvice = MODALITY_ADVICE,
) -> Polarity:
    """Refuse a modality that contradicts the image (e.g. a fluorescence field as phase).

    Phase contrast and bright field show cells darker than the media right around them,
    fluorescence brighter (:func:`bright_field_as_phase` tells the two dark kinds apart
    only as a note). With painted ``labels`` the cells (1) are compared with the
    media (2); with instance ``masks`` with a ring of 3 pixels around the cells; with
    neither, the histogram's tails decide (:func:`image_polarity`) and an unclear image
    passes.

    Returns
    -------
    str
        The polarity found.

    ``advice``: what to do, in the interface's words (:data:`MODALITY_ADVICE`, the
    commands').

    Raises
    ------
    ValueError
        When the polarity contradicts ``modality``, naming the modality to pass.
    """
    frame = np.asarray(image, np.float64)
    if modality == "brightfield":
        # a cell out of focus is a bright centre in a dark rim: brighter or darker than
        # its surroundings by the side of focus, so only a field with nothing darker than
        # its background, fluorescence's look, contradicts it
        polarity = image_polarity(frame)
        if polarity == "bright cells":
            raise ValueError(
                "the image does not look like bright field: it shows bright objects on its "
                "background and nothing darker, as fluorescence does. "
                + advice.switch.format(other="fluorescence")
            )
        return polarity
    if labels is not None:
        polarity = _class_polarity(frame, labels == 1, labels == 2)
        evidence = "the painted cells (1) are {} than the media (2)"
    elif masks is not None:
        cells = masks > 0
        ring = ndimage.binary_dilation(cells, iterations=_RING_PX) & ~cells
        polarity = _class_polarity(frame, cells, ring)
        evidence = "the masked cells are {} than the pixels around them"
    else:
        polarity = image_polarity(frame)
        evidence = (
            "the image shows {} objects on its background and no "
            "objects of the other sign"
        )
    expected = "bright cells" if modality == "fluorescence" else "dark cells"
    if polarity not in ("unclear", expected):
        switch = advice.switch.format(other="fluorescence")
        if modality == "fluorescence":  # dark cells: phase contrast or bright field
            switch = advice.switch.format(other="phase") + ", or brightfield for bright field"
        word = "brighter" if polarity == "bright cells" else "darker"
        if labels is None and masks is None:
            word = "bright" if polarity == "bright cells" else "dark"
        raise ValueError(
            f"the image does not look like {modality}: {evidence.format(word)}. "
            f"{switch} (or, if it really is {modality}, {advice.paint} so the cells and "
            "media settle it)"
        )
    return polarity


def refuse_constant(frame: np.ndarray, name: str, *, what: str = "IMAGE ") -> None:
    """Refuse a frame whose pixels all hold one value (a blank image: nothing to
    fit); ``name`` is the image file's, after ``what`` (the CLI's argument; the docks
    give ``""``)."""
    if frame.size and np.min(frame) == np.max(frame):
        raise ValueError(
            f"{what}{name} is constant (every pixel is {float(frame.flat[0]):g}): nothing to "
            "fit; give the recording with the cells in it"
        )


def _refuse_frames_of_another_count(array: np.ndarray, shape: tuple[int, ...], name: str) -> None:
    """Frames of the image's size, but not one per frame fitted: said so (found as a
    user: masks of 3 frames with ``--frames 0-3`` were "shape (3, 512, 512) but the image
    frame has shape (512, 512)")."""
    if array.ndim == 3 and tuple(array.shape[1:]) == tuple(shape):
        raise ValueError(
            f"{name} holds {array.shape[0]} frames of the image's size, but not one for "
            "each frame of the image: give one per frame of the image (its frame k for "
            "the image's frame k), or one 2D frame for all"
        )


def check_class_labels(labels: np.ndarray, shape: tuple[int, ...], name: str = "labels") -> None:
    """Painted class labels: the image's shape, classes 0-3, with cells and media painted."""
    if labels.shape != shape:
        _refuse_frames_of_another_count(labels, shape, name)
        raise ValueError(
            f"{name} has shape {labels.shape} but the image frame has shape {shape}: paint "
            "the labels on the same image (or crop both alike)"
        )
    if not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"{name} must hold integer classes 0-3, got dtype {labels.dtype}")
    present = set(np.unique(labels).tolist())
    if not present <= {0, 1, 2, 3}:
        others = sorted(present - {0, 1, 2, 3})
        said = (
            str(others)
            if len(others) <= 6
            else f"[{', '.join(map(str, others[:5]))}, ..., {others[-1]}] ({len(others)} values)"
        )
        raise ValueError(
            f"{name} holds classes {said}; classes are 0 unpainted, "
            "1 cell, 2 media, 3 device (an instance mask goes to --masks instead)"
        )
    if 2 not in present:
        raise ValueError(
            f"{name} has no media class (2): paint some of the background between or around "
            "the cells as media (2), or pass --masks with instance masks instead"
        )
    if 1 not in present:
        raise ValueError(f"{name} has no cell class (1): paint at least one cell as 1")


def modality_doubt(frame: np.ndarray, modality: str) -> str | None:
    """A note when the image looks like another transmitted-light modality than the one
    given, else ``None``: :data:`BRIGHT_FIELD_NOTE` or :data:`PHASE_NOTE`.

    Phase contrast shows bright halos beside its dark cells, bright field dark objects
    and nothing brighter than its background (:func:`image_polarity`: ColiCoords' bright
    field fields reach 2 noise SDs above their median at most, the real phase images here
    24-737). Found as a user: ColiCoords' bright field calibrated as phase failed after
    its fit with a saturated dataset, and SyMBac's phase trench fitted as bright field
    ended with exit 0 and no word. Only a note, not a refusal: a phase image of a few
    cells with faint halos (the project's own sparse renders with the linear kernel)
    reads as bright field, and a bright-field crop around a cell out of focus (ColiCoords'
    ``01``: 35 SDs above) shows a bright centre as phase shows a halo.
    """
    if modality == "phase" and image_polarity(frame) == "dark cells":
        return BRIGHT_FIELD_NOTE
    if modality == "brightfield":  # both tails far: neither polarity, image_polarity's
        below, above = _tails(np.asarray(frame, np.float64))  # "unclear" (nan: no noise)
        if below > _FAR and above > _FAR:
            return PHASE_NOTE
    return None


#: What :func:`modality_doubt` says of phase contrast that looks like bright field (a
#: constant: the fit says it first, before a fit that may take minutes, and finds it
#: among its notes by it).
BRIGHT_FIELD_NOTE = (
    "the image shows dark objects and nothing brighter than its background, no phase "
    "halo: if it is bright field, pass --modality brightfield (phase contrast fitted to "
    "a bright-field image saturates its synthetic images)"
)
#: What :func:`modality_doubt` says of bright field that looks like phase contrast.
PHASE_NOTE = (
    "the image shows bright objects beside its dark ones, as phase contrast's halos are "
    "(or bright-field cells out of focus): if it is phase contrast, pass --modality phase"
)


def not_integer_masks(name: str, dtype: object) -> str:
    """What is wrong with masks of a non-integer ``dtype``, and the fix. Found as a user:
    a float mask (a probability or binary map saved as float32) got "--masks must hold
    integer cell ids, got float32", with no word of what to do."""
    return (
        f"{name} must hold integer cell ids (0 background, 1..N one id per cell), got "
        f"{dtype}: save the masks as integer labels; a probability or 0/1 map is not "
        "instance masks, label its cells first (e.g. skimage.measure.label(mask > 0.5))"
    )


def check_instance_masks(masks: np.ndarray, shape: tuple[int, ...], name: str = "masks") -> None:
    """Instance masks: the image's shape, integer ids, background 0 and some cells; a
    0/1 mask's regions each one cell (:func:`refuse_merged_cells`)."""
    if masks.shape != shape:
        _refuse_frames_of_another_count(masks, shape, name)
        raise ValueError(
            f"{name} has shape {masks.shape} but the image frame has shape {shape}: give the "
            "masks of this image (or crop both alike)"
        )
    if not (np.issubdtype(masks.dtype, np.integer) or masks.dtype == bool):
        raise ValueError(not_integer_masks(name, masks.dtype))
    if masks.min() < 0:
        raise ValueError(f"{name} has negative ids: cell ids must be >= 1, background 0")
    if not (masks > 0).any():
        raise ValueError(f"{name} holds no cell (all 0): pass masks with cells in them")
    refuse_image_as_masks(masks, name)  # before "no background": what an image lacks too
    if (masks > 0).all():
        raise ValueError(f"{name} has no background (0) pixel: the fit needs some background")
    refuse_merged_cells(masks, name)


#: Patches of one value per id above which "masks" are taken for an image: a segmenter's
#: masks hold one patch per cell (the real ones here: exactly one), an intensity image's
#: values are scattered (ColiCoords' fluorescence crop: 30 patches per value, the SyMBac
#: trench 3.2).
MAX_PATCHES_PER_ID = 2.0


#: The most area a binary mask's region may cover per pixel of its width x length box:
#: a rod lies inside that box (the real cells here fill 0.84-0.90 of it, ColiCoords'
#: binary masks; a curved filament of Omnipose's 1.02), the touching cells of a
#: colony merged into one region branch beyond it (the Omnipose colonies as 0/1
#: masks: 2.32, 4.47 and 2.47).
MAX_ROD_FILL = 1.5
#: Regions narrower than this (pixels) are specks whose width the pixel grid cannot
#: measure (a 2 x 2 block reads 1 px wide), not checked by :func:`refuse_merged_cells`.
_MIN_CHECKED_WIDTH_PX = 3.0


def refuse_merged_cells(masks: np.ndarray, name: str = "masks") -> None:
    """Refuse a binary mask whose touching cells are merged into one region.

    A binary mask (one non-zero value) is split into its connected regions, one cell
    each (:func:`as_instance_ids`); a semantic cell/background mask of a colony then
    gives one region of many cells (found as a user: Omnipose's colony as 0/1 was
    calibrated as one cell 8.9 um long, the pixel size 0.02 um from its width). Such
    a region is no rod: its area exceeds :data:`MAX_ROD_FILL` times its width (twice
    its largest inscribed radius, less a pixel) times its length (largest Feret
    diameter, plus a pixel). Instance masks are taken as they are.

    Raises
    ------
    ValueError
        When a region at least 3 px wide of a binary mask is no rod, naming the fix:
        instance masks.
    """
    from skimage.measure import regionprops

    from napari_symbac.fit.masks import cell_widths_px

    regions, n_regions = as_instance_ids(masks)
    if n_regions is None:
        return
    widths = cell_widths_px(regions)
    for region, width in zip(regionprops(regions), widths, strict=True):
        length = region.feret_diameter_max + 1.0
        fill = region.area / (width * length)
        if width >= _MIN_CHECKED_WIDTH_PX and fill > MAX_ROD_FILL:
            raise ValueError(
                f"{name} holds one value, a cell/background mask, and a connected region "
                f"of it ({int(region.area)} px) is no rod: it covers {fill:.1f} times its "
                f"width x length ({width:.0f} x {length:.0f} px), as touching cells merged "
                "into one region do. Give instance masks, each cell its own number (e.g. "
                "Omnipose or Cellpose output)"
            )


def as_instance_ids(masks: np.ndarray) -> tuple[np.ndarray, int | None]:
    """Instance ids of ``masks``: a binary mask (one non-zero value: 0/1, boolean, or
    0/255 as ImageJ saves one) split into its connected regions, with their count;
    instance masks as they are, and ``None``. Found as a user: a 0/255 mask was taken
    for one cell of id 255 spanning 8 separate regions."""
    masks = np.asarray(masks)
    if np.count_nonzero(np.unique(masks)) <= 1:
        labels, n_regions = ndimage.label(masks != 0)
        return labels, int(n_regions)
    return masks, None


def refuse_image_as_masks(masks: np.ndarray, name: str = "masks") -> None:
    """Refuse an intensity image given as instance masks (found as a user: a
    fluorescence crop passed to ``fit --masks`` was fitted as 929 cells for over 5 min;
    ``calibrate`` said after 100 s that "the masks cover the image").

    A binary mask (ids 0 and 1, its connected regions the cells) is taken as it is.

    Raises
    ------
    ValueError
        When the ids form more than :data:`MAX_PATCHES_PER_ID` separate patches each (and
        more than 10 patches in all).
    """
    n_ids, n_patches = _ids_and_patches(masks)
    if n_ids <= 1:
        return
    if n_patches > max(MAX_PATCHES_PER_ID * n_ids, 10):
        raise ValueError(
            f"{name} does not look like instance masks: its {n_ids} values lie in "
            f"{n_patches} separate patches (a cell's id fills one patch), as an image's grey "
            "levels do. Give the masks file (0 background, each cell its own id 1..N, e.g. "
            "a segmenter's label image), not the recording"
        )


def _ids_and_patches(masks: np.ndarray) -> tuple[int, int]:
    """The non-zero values of ``masks`` and the connected patches of one value they form."""
    from skimage import measure

    n_ids = int(np.count_nonzero(np.unique(masks)))
    return n_ids, int(measure.label(masks, background=0, connectivity=2).max())


def looks_like_masks(image: np.ndarray) -> bool:
    """Whether an image (its first frame) holds instance masks or a binary mask rather
    than a recording: integer values, a background of 0 (5 % of it or more) and each
    value one patch (:data:`MAX_PATCHES_PER_ID` at most), or one value only. A
    recording's grey levels are scattered over the frame (the 8-bit Omnipose colonies:
    thousands of patches for their 19-256 levels). Found as a user: a masks TIFF opened
    with napari's own reader became an image, and Calibrate took it for the recording."""
    frame = np.asarray(image[(0,) * (image.ndim - 2)] if image.ndim > 2 else image)
    if frame.ndim != 2 or not np.issubdtype(frame.dtype, np.integer):
        return False
    background = np.count_nonzero(frame == 0)
    if not 0.05 * frame.size <= background < frame.size:
        return False
    values = np.unique(frame)
    if values.size - 1 > frame.size // 20:  # more levels than a frame holds cells
        return False
    n_ids, n_patches = _ids_and_patches(frame)
    return n_ids == 1 or n_patches <= MAX_PATCHES_PER_ID * n_ids


#: Frames at most this wide (pixels) are taken for a mother-machine trench...
TRENCH_MAX_WIDTH_PX = 100
#: ... when they are also at least this many times as tall as wide: a trench image runs
#: along the trench (the real ones here: 256 x 46 and 256 x 32 px). Found as a user: a
#: 57 x 61 px crop around one cell on an agar pad was fitted as a trench, walls and all.
TRENCH_MIN_ASPECT = 2.0


def default_geometry(
    shape_px: tuple[int, ...], modality: str, configured: str | None = None
) -> str:
    """The fit's geometry, ``trench`` or ``field``, when the user names none.

    ``field`` when the configured simulation is an agar pad, when it is fluorescence (no
    walls to find), or when the frame (the last two axes of ``shape_px``) is wider than
    :data:`TRENCH_MAX_WIDTH_PX` or less than :data:`TRENCH_MIN_ASPECT` times as tall as
    wide; else ``trench``. A configured trench or chamber keeps ``trench`` for phase.
    Used alike by ``napari-symbac fit``, ``diagnose``, ``calibrate`` and the Simulate and
    Diagnose docks.
    """
    if configured == "agar_pad" or modality == "fluorescence":
        return "field"
    if configured in ("trench", "chamber"):
        return "trench"
    height_px, width_px = shape_px[-2:]
    narrow = width_px <= TRENCH_MAX_WIDTH_PX and height_px >= TRENCH_MIN_ASPECT * width_px
    return "trench" if narrow else "field"


def lying_trench_problem(shape_px: tuple[int, ...], modality: str, name: str) -> str | None:
    """What to do with a frame shaped like a trench on its side (at most
    :data:`TRENCH_MAX_WIDTH_PX` tall and :data:`TRENCH_MIN_ASPECT` times as wide), in
    phase contrast or bright field; ``None`` for any other frame. Found as a user: a
    46 x 256 px trench (the chip mounted turned by 90 degrees) was fitted as an open
    field of 1.7 um cells, exit 0, and calibrated into a dataset of empty frames."""
    height_px, width_px = shape_px[-2:]
    if modality == "fluorescence" or not (
        height_px <= TRENCH_MAX_WIDTH_PX and width_px >= TRENCH_MIN_ASPECT * height_px
    ):
        return None
    return (
        f"{name} is {height_px} x {width_px} px (rows x columns), wide and short: a "
        "mother-machine trench lying on its side, which is fitted and simulated upright: "
        "rotate it by 90 degrees (numpy.rot90; Fiji: Image > Transform > Rotate 90 Degrees "
        "Left or Right) so that the trench runs from top to bottom, its closed end up"
    )


#: Pixel sizes (um, in the sample plane) of real bacterial micrographs: 20 nm (super-
#: resolution camera pixels at 250x) to 1 um (a 10x objective); beyond, cells are not
#: resolved.
PLAUSIBLE_PIXEL_UM = (0.02, 1.0)


#: Camera pixels, um, binning included (sCMOS 6.5-11, CCD 6.45, EMCCD 13-24; 2 x 2
#: binning doubles them): the pixel size times the magnification falls here when the
#: microscope file describes the objective the image was taken with.
CAMERA_PIXEL_UM = (1.0, 40.0)


#: The most pixels a camera's offset may lie above (:func:`camera_recording_problem`).
BELOW_OFFSET_FRACTION = 0.05


def camera_recording_problem(camera: Camera, image: np.ndarray) -> str | None:
    """Why a given ``camera`` cannot have recorded ``image``, or ``None``.

    Found as a user: a camera of 8 bits given for a 16-bit trench (591-7507 ADU) made
    Auto-fit fail with "every pixel of the image is clipped", naming no camera; an
    offset of 3000 ADU (above the trench's median) fitted to a reduced chi-square of
    1e5 without a word. A camera's full scale holds all of its pixels, and its offset
    lies below nearly all of them: only its read noise dips under it, so more than
    :data:`BELOW_OFFSET_FRACTION` of the pixels 3 read-noise SDs (and 3 ADU) under the
    offset is no camera's.
    """
    values = np.asarray(image, np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    high = float(values.max())
    if high > camera.max_adu:
        return (
            f"the recording reaches {high:.6g} ADU, above this camera's full scale "
            f"({camera.max_adu} ADU at bit_depth {camera.bit_depth}): give its bit depth "
            f"(at least {math.ceil(math.log2(high + 1))} bits to hold the recording)"
        )
    margin = 3 * camera.dark_noise_e * camera.sensitivity_adu_per_e + 3
    below = float(np.mean(values < camera.baseline_adu - margin))
    if below > BELOW_OFFSET_FRACTION:
        return (
            f"its offset {camera.baseline_adu:g} ADU lies above {below:.0%} of the "
            f"recording's pixels (whose 1st percentile is {np.percentile(values, 1):.6g} "
            "ADU): a camera's offset lies below nearly all of them; give its dark level "
            "(the mean of a frame taken with the shutter closed)"
        )
    return None


def camera_pixel_problem(microscope: Microscope, where: str = "the microscope file") -> str | None:
    """A sentence when ``pixel_size_um x magnification`` is no camera's pixel, else None;
    ``where`` names where the user sets them (the GUI's form, not a file).

    Found as a user: ``pixel_size_um: 0.65`` (a 10x slip) for a 100x objective was fitted
    with 35 cells at their bounds, exit 0. The product is a 65 um camera pixel: either
    the pixel size is wrong or the microscope file describes another objective (whose NA
    shapes the PSF).
    """
    camera_um = microscope.pixel_size_um * microscope.magnification
    low, high = CAMERA_PIXEL_UM
    if low <= camera_um <= high:
        return None
    return (
        f"pixel size {microscope.pixel_size_um:g} um at {microscope.magnification:g}x "
        f"magnification is a {camera_um:.3g} um camera pixel, outside the {low:g}-{high:g} "
        "um cameras have: check pixel_size_um and magnification (and the NA) in "
        f"{where} (pixel size = camera pixel / magnification: 6.5 um / 100x = 0.065 um)"
    )


def check_pixel_size(pixel_size_um: float, source: str) -> None:
    """Refuse a pixel size (from ``source``) no bacterial micrograph has.

    Raises
    ------
    ValueError
        Outside :data:`PLAUSIBLE_PIXEL_UM`, naming the fix (a pixel size in um, e.g. a
        camera pixel given for the sample's, or nm for um).
    """
    low, high = PLAUSIBLE_PIXEL_UM
    if not low <= pixel_size_um <= high:
        # found as a user: 65 typed for 65 nm
        nm = pixel_size_um / 1000
        said = f" (in nm? {pixel_size_um:g} nm is {nm:g} um)" if low <= nm <= high else ""
        raise ValueError(
            f"pixel size {pixel_size_um:g} um ({source}) is outside {low:g}-{high:g} um, "
            f"implausible for a bacterial micrograph{said}: give it in um in the sample, "
            "i.e. the camera pixel divided by the magnification (6.5 um / 100x = 0.065 um)"
        )


def resolve_pixel_size(
    file_pixel_um: float | None,
    microscope: Microscope,
    *,
    microscope_gives_it: bool = True,
    flag_pixel_um: float | None = None,
    tolerance: float = 0.01,
    other_way: str = "",
) -> tuple[Microscope, str]:
    """The pixel size to fit at: ``--pixel-size-um``, else the TIFF's and the microscope
    file's when they agree, else whichever of them gives one.

    ``microscope_gives_it``: whether the microscope file sets the pixel size
    (:func:`~napari_symbac.settings.microscope_sets_pixel_size`); when neither it nor
    the image does, the pixel size is refused, not taken from :class:`Microscope`'s
    default (found as a user: a PNG and a microscope file without ``pixel_size_um``
    were calibrated at 0.065 um, "from --microscope", cells 0.5 um wide).
    ``flag_pixel_um``: the command line's ``--pixel-size-um``, which wins over both.
    ``other_way``: another way the command has to set it, said in that refusal.

    Returns
    -------
    microscope, note
        The microscope with the pixel size used, and a sentence saying where the pixel
        size came from.

    Raises
    ------
    ValueError
        The pixel size used is implausible (:func:`check_pixel_size`); neither the
        image nor the microscope file gives one; or the two disagree by more than
        ``tolerance`` (found as a user: the TIFF's value was taken over the microscope
        file's, and a wrong one, such as a 1 um scale some software writes when none was
        set, gave a fit of no cells or wrong sizes with exit 0), which
        ``flag_pixel_um`` settles.
    """
    given = microscope.pixel_size_um
    recorded = file_pixel_um is not None and math.isfinite(file_pixel_um) and file_pixel_um > 0
    if flag_pixel_um is not None:
        check_pixel_size(flag_pixel_um, "from --pixel-size-um")
        microscope = _with_pixel_size(microscope, flag_pixel_um, "--pixel-size-um")
        return microscope, f"pixel size {flag_pixel_um:.4g} um from --pixel-size-um"
    if not recorded:
        if not microscope_gives_it:
            raise ValueError(
                "neither the image nor --microscope gives the pixel size: pass "
                "--pixel-size-um P or add pixel_size_um to the microscope file, in um in "
                "the sample (the camera pixel divided by the magnification: 6.5 um / 100x "
                "= 0.065)" + (f"; {other_way}" if other_way else "")
            )
        check_pixel_size(given, "from --microscope; the image file records none")
        return microscope, (
            f"pixel size {given:.4g} um from --microscope (the image file records none)"
        )
    check_pixel_size(file_pixel_um, "recorded in the image file; --pixel-size-um overrides it")
    if microscope_gives_it and abs(file_pixel_um - given) > tolerance * given:
        unset = " (1 um per pixel is often a scale that was never set)" * (
            file_pixel_um == 1.0
        )
        raise ValueError(
            f"the image file records a pixel size of {file_pixel_um:.4g} um{unset} and "
            f"--microscope {given:.4g} um: say which is right with --pixel-size-um "
            f"{given:.4g} (or {file_pixel_um:.4g}), or correct the file that is wrong"
        )
    if microscope_gives_it:
        return microscope, f"pixel size {file_pixel_um:.4g} um (TIFF and --microscope agree)"
    microscope = _with_pixel_size(microscope, file_pixel_um, "the TIFF's metadata")
    return microscope, f"pixel size {file_pixel_um:.4g} um from the TIFF"


def _with_pixel_size(microscope: Microscope, pixel_um: float, source: str) -> Microscope:
    try:
        return dataclasses.replace(microscope, pixel_size_um=float(pixel_um))
    except ValueError as err:
        raise ValueError(
            f"the pixel size {pixel_um:.4g} um does not suit the microscope ({err}); fix "
            f"{source} or the microscope file"
        ) from err
