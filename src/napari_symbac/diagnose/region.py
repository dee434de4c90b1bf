"""The part of a large frame that a diagnosis looks at.

A diagnosis fits the base model and every candidate effect many times (cross-fitted
held-out checks, a parametric bootstrap), with a dense Jacobian over the pixels for
effects that have a parameter per column or per mode. Its time and memory grow faster
than the pixel count: on the 2-core development machine a 256 x 256 ColiCoords field
took 3 min and 1.6 GB, while the whole 512 x 512 field ran out of 24 GB in the GUI.
Large frames are therefore diagnosed on a window of at most
:data:`MAX_DIAGNOSIS_PIXELS`, the centre one unless the user picks another; most effects
of the catalogue are properties of the microscope, not of where in the field one looks.
"""

from __future__ import annotations

import math

__all__ = [
    "MAX_DIAGNOSIS_PIXELS",
    "Region",
    "default_region",
    "names_centre",
    "parse_region",
    "simulated_shape",
]

#: The most pixels per frame a diagnosis looks at unless told otherwise (256 x 256).
MAX_DIAGNOSIS_PIXELS = 256 * 256

#: The smallest side of a window, in pixels (the fit's smallest image).
MIN_REGION_PX = 8

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


def names_centre(text: str) -> bool:
    """Whether ``text`` asks for the centre window (``"centre"`` or ``"center"``, case
    and spaces aside), as :func:`parse_region` reads it."""
    return text.strip().lower() in ("centre", "center")


def parse_region(
    text: str,
    shape: tuple[int, int],
    *,
    max_pixels: int = MAX_DIAGNOSIS_PIXELS,
    name: str = "--region",
) -> Region:
    """``"centre"``, ``"full"`` or ``"Y0:Y1,X0:X1"`` (pixels, half-open) as a region of
    ``shape``.

    The one parser of a window to diagnose, for the CLI's ``--region`` and the Diagnose
    dock's *window* field. ``"centre"`` (or ``"center"``) is :func:`default_region` of
    ``shape`` with ``max_pixels``; ``"full"`` is the whole frame, however large (a
    diagnosis of it may take long and much memory, but it is the user's choice).

    Parameters
    ----------
    text
        What the user gave; case and spaces around the parts are ignored.
    shape
        Rows and columns of the frame.
    max_pixels
        The most pixels of the centre window.
    name
        What the user gave it as (``"--region"``, ``"window"``), to name in errors.

    Raises
    ------
    ValueError
        Naming ``name``, what is wrong and the forms accepted, when ``text`` is not one
        of those forms or the window is empty or reaches outside the frame.
    """
    rows, cols = (int(n) for n in shape)
    if text.strip().lower() == "full":
        return (0, rows, 0, cols)
    if names_centre(text):
        return default_region((rows, cols), max_pixels)
    side = math.isqrt(max_pixels)
    forms = (
        "give Y0:Y1,X0:X1 (rows and columns in pixels, e.g. 0:128,64:192), full (the whole "
        f"frame) or centre (its centre window of at most {side} x {side} px)"
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
