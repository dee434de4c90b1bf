"""The part of a large frame that a diagnosis looks at.

A diagnosis fits the base model and every candidate effect many times (cross-fitted
held-out checks, a parametric bootstrap), with a dense Jacobian over the pixels for
effects that have a parameter per column or per mode. Its time and memory grow faster
than the pixel count: on the 2-core development machine a 256 x 256 ColiCoords field
took 3 min and 1.6 GB, while the whole 512 x 512 field ran out of 24 GB in the GUI.
Large frames are therefore diagnosed on a window of at most
:data:`MAX_DIAGNOSIS_PIXELS`: by default the one that holds the most whole cells
(:func:`cells_region`), else the centre one or the window the user picks; most effects
of the catalogue are properties of the microscope, not of where in the field one looks,
but the fit under them needs cells.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = [
    "CELLS",
    "MAX_DIAGNOSIS_PIXELS",
    "SMALL_WINDOW_PX",
    "Region",
    "cells_region",
    "default_region",
    "names_centre",
    "parse_region",
    "placement",
    "simulated_shape",
]

#: The most pixels per frame a diagnosis looks at unless told otherwise (256 x 256).
MAX_DIAGNOSIS_PIXELS = 256 * 256

#: The smallest side of a window, in pixels (the fit's smallest image).
MIN_REGION_PX = 8

#: The side of a window under which "no cells" may mean too little background around
#: them for the start (found as a user: a 40 x 40 px window around one cell was "no
#: cells", a 64 x 64 one worked).
SMALL_WINDOW_PX = 64

#: Rows ``y0:y1`` and columns ``x0:x1`` of a frame, half-open, in pixels.
Region = tuple[int, int, int, int]


def default_region(shape: tuple[int, int], max_pixels: int = MAX_DIAGNOSIS_PIXELS) -> Region:
    """The whole frame when it has at most ``max_pixels``, else its centre window.

    The window holds at most ``max_pixels``: a frame narrower than the square of that
    many pixels (a trench) keeps its full width, a wider one its aspect ratio.
    """
    rows, cols = (int(n) for n in shape)
    if rows * cols <= max_pixels:
        return (0, rows, 0, cols)
    side = math.isqrt(max_pixels)
    if cols <= side:  # a trench: its full width, as many rows as allowed
        height, width = max_pixels // cols, cols
    elif rows <= side:
        height, width = rows, max_pixels // rows
    else:
        scale = math.sqrt(max_pixels / (rows * cols))
        height, width = int(rows * scale), int(cols * scale)
    y0, x0 = (rows - height) // 2, (cols - width) // 2
    return (y0, y0 + height, x0, x0 + width)


#: The window's name for :func:`cells_region`, the default of the CLI and the dock.
CELLS = "cells"
#: The departure from the frame's median, in s.d. of the smoothed noise
#: (:func:`~napari_symbac.fit.start.departure_z`), that makes a pixel part of something
#: in the frame (a cell, its halo) without masks, where the background is noise alone;
#: a textured background raises it (:data:`NOISE_MEDIAN_Z`).
STRUCTURE_MIN_Z = 5.0
#: The median departure of a frame of noise alone: the median of ``|N(0, 1)|``. A frame
#: whose median departure is ``m`` times this (a pad's texture, out-of-focus debris)
#: counts as structure only what departs ``m`` times :data:`STRUCTURE_MIN_Z`.
NOISE_MEDIAN_Z = 0.6745
#: The fewest pixels of such a region that count as a cell (noise specks do not).
STRUCTURE_MIN_PX = 30


def cells_region(
    frames: np.ndarray,
    masks: np.ndarray | None = None,
    max_pixels: int = MAX_DIAGNOSIS_PIXELS,
) -> Region:
    """The window of :func:`default_region`'s size that holds the most whole cells in
    every frame; the centre one where no window holds one.

    Found as a user: the centre 256 x 256 px of a ColiCoords 512 x 512 field held none of
    its three cells whole, and the diagnosis, said to be of "1 cell", was of its
    background. A cell is an instance of ``masks`` when given, else a connected region
    of at least :data:`STRUCTURE_MIN_PX` pixels that departs from the frame's median by
    more than :data:`STRUCTURE_MIN_Z` s.d. of its noise (both smoothed:
    :func:`~napari_symbac.fit.start.departure_z`), times the background's own median
    departure over that of noise alone where it is larger (:data:`NOISE_MEDIAN_Z`: a
    textured pad): a cell with its halo, whatever the modality. A window
    counts the cells wholly inside it; of a series, its frame with the fewest. Ties go
    to the window nearest the centre.

    Parameters
    ----------
    frames
        One ``(Y, X)`` frame or a ``(T, Y, X)`` series.
    masks
        Instance masks of the frames' shape (one frame for all, or one per frame), or
        ``None``.
    max_pixels
        The most pixels of the window.
    """
    frames = np.asarray(frames, float)
    frames = frames[None] if frames.ndim == 2 else frames
    rows, cols = frames.shape[-2:]
    centre = default_region((rows, cols), max_pixels)
    y0, y1, x0, x1 = centre
    height, width = y1 - y0, x1 - x0
    if (height, width) == (rows, cols):
        return centre
    given = None if masks is None else np.asarray(masks)
    counts = None
    for k, frame in enumerate(frames):
        if given is None:
            cells = _structure(frame)
        else:
            cells = given[min(k, len(given) - 1)] if given.ndim == 3 else given
        per_frame = _whole_cells_per_window(cells, height, width)
        counts = per_frame if counts is None else np.minimum(counts, per_frame)
    if counts.max() == 0:
        return centre
    best = np.argwhere(counts == counts.max())
    nearest = best[np.argmin(np.hypot(best[:, 0] - y0, best[:, 1] - x0))]
    top, left = (int(v) for v in nearest)
    return (top, top + height, left, left + width)


def _structure(frame: np.ndarray) -> np.ndarray:
    """Labelled regions of ``frame`` that stand out of its noise (:func:`cells_region`)."""
    from napari_symbac.fit.start import departure_z

    departures = departure_z(frame)
    if not np.isfinite(departures).all():  # no measurable noise: nothing is judged
        return np.zeros(frame.shape, np.int32)
    # the background's own departures set the bar (found as a user: ColiCoords' bright
    # field, its pad's texture at a median 3 s.d., gave windows of texture: 3 of the
    # masks' cells whole over its 10 fields, none in 7; so raised, 18, where the masks'
    # own windows hold 30)
    texture = max(1.0, float(np.median(departures)) / NOISE_MEDIAN_Z)
    labelled, _ = ndimage.label(departures > STRUCTURE_MIN_Z * texture)
    sizes = np.bincount(labelled.ravel())
    small = sizes < STRUCTURE_MIN_PX
    small[0] = True
    labelled[small[labelled]] = 0
    return labelled


def _whole_cells_per_window(cells: np.ndarray, height: int, width: int) -> np.ndarray:
    """How many of the labelled ``cells`` lie wholly inside the ``height`` x ``width``
    window at each top-left corner, an array of the corners' shape."""
    rows, cols = cells.shape
    marks = np.zeros((rows - height + 2, cols - width + 2), np.int64)
    for box in ndimage.find_objects(np.asarray(cells, np.int64)):
        if box is None:
            continue
        (b0, b1), (c0, c1) = (box[0].start, box[0].stop), (box[1].start, box[1].stop)
        top, bottom = max(0, b1 - height), min(b0, rows - height)
        left, right = max(0, c1 - width), min(c0, cols - width)
        if top > bottom or left > right:  # larger than the window
            continue
        marks[top, left] += 1
        marks[bottom + 1, left] -= 1
        marks[top, right + 1] -= 1
        marks[bottom + 1, right + 1] += 1
    return marks.cumsum(0).cumsum(1)[:-1, :-1]


def names_centre(text: str) -> bool:
    """Whether ``text`` asks for the centre window (``"centre"`` or ``"center"``, case
    and spaces aside), as :func:`parse_region` reads it."""
    return text.strip().lower() in ("centre", "center")


def placement(text: str) -> str:
    """How ``text`` places the window, as :func:`parse_region` reads it: ``"cells"``
    (:func:`cells_region`, the default), ``"centre"`` (:func:`default_region`) or
    ``"chosen"`` (rows and columns, or full): the words the CLI's note and the dock's
    status give the window."""
    if names_centre(text):
        return "centre"
    return "cells" if text.strip().lower() == CELLS else "chosen"


def parse_region(
    text: str,
    frames: np.ndarray,
    *,
    masks: np.ndarray | None = None,
    max_pixels: int = MAX_DIAGNOSIS_PIXELS,
    name: str = "--region",
) -> Region:
    """``"cells"``, ``"centre"``, ``"full"`` or ``"Y0:Y1,X0:X1"`` (pixels, half-open) as
    a region of the frames.

    The one parser of a window to diagnose, for the CLI's ``--region`` and the Diagnose
    dock's *window* field. ``"cells"`` is :func:`cells_region` of the frames (and
    ``masks``) with ``max_pixels``; ``"centre"`` (or ``"center"``) is
    :func:`default_region` of their shape; ``"full"`` is the whole frame, however large
    (a diagnosis of it may take long and much memory, but it is the user's choice).

    Parameters
    ----------
    text
        What the user gave; case and spaces around the parts are ignored.
    frames
        One ``(Y, X)`` frame or a ``(T, Y, X)`` series.
    masks
        The cells' instance masks, for ``"cells"``; ``None`` without.
    max_pixels
        The most pixels of the cells' and the centre window.
    name
        What the user gave it as (``"--region"``, ``"window"``), to name in errors.

    Raises
    ------
    ValueError
        Naming ``name``, what is wrong and the forms accepted, when ``text`` is not one
        of those forms or the window is empty or reaches outside the frame.
    """
    rows, cols = (int(n) for n in np.shape(frames)[-2:])
    if text.strip().lower() == "full":
        return (0, rows, 0, cols)
    how = placement(text)
    if how == "centre":
        return default_region((rows, cols), max_pixels)
    if how == "cells":
        return cells_region(frames, masks, max_pixels)
    side = math.isqrt(max_pixels)
    forms = (
        "give Y0:Y1,X0:X1 (rows and columns in pixels, e.g. 0:128,64:192), full (the whole "
        f"frame), cells (the window of at most {side} x {side} px that holds the most "
        "cells) or centre (its centre window of that many)"
    )
    try:
        ys, xs = text.split(",")
        y0, y1 = (int(v) for v in ys.split(":"))
        x0, x1 = (int(v) for v in xs.split(":"))
    except ValueError:
        raise ValueError(
            f"{name} {text!r} is not of the form Y0:Y1,X0:X1: {forms}"
        ) from None
    if not (y0 < y1 and x0 < x1):
        raise ValueError(f"{name} {text!r} is empty (each end after its start): {forms}")
    if not (y0 >= 0 and y1 <= rows and x0 >= 0 and x1 <= cols):  # found as a user:
        # 0:300,0:46 of a 256 x 46 frame was "empty or outside" it, and is neither
        raise ValueError(
            f"{name} {text!r} is not all inside the {rows} x {cols} frame (rows 0:{rows}, "
            f"columns 0:{cols}): {forms}"
        )
    if min(y1 - y0, x1 - x0) < MIN_REGION_PX:  # found as a user: "real_image of shape
        # (4, 4) is too small", named by the fit's inner word
        raise ValueError(
            f"{name} {text!r} is {y1 - y0} x {x1 - x0} px: a window needs at least "
            f"{MIN_REGION_PX} x {MIN_REGION_PX} px (a few cells' worth is best): {forms}"
        )
    return (y0, y1, x0, x1)


def simulated_shape(region: Region, shape: tuple[int, int], trench: bool) -> tuple[int, int]:
    """The frame, in pixels, that the settings of a diagnosis of ``region`` simulate.

    A trench diagnosed on a window of all its columns is simulated as long as the whole
    ``shape``: the window only saves the diagnosis' time, and a trench cut to it can be
    too short for the fitted cells to divide in. Any other window (a field's) is
    simulated as it is, with the cells it holds.
    """
    y0, y1, x0, x1 = region
    if trench and (x0, x1) == (0, int(shape[1])):
        return (int(shape[0]), int(shape[1]))
    return (y1 - y0, x1 - x0)
