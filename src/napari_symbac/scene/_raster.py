"""Rasterising cells into a scene's images, each cell only in its own box.

:func:`rasterise_cells` turns the cells of one frame into the ``cells`` fraction
and the instance labels of :class:`~napari_symbac.scene.Scene` (eq. OPL2: the
chord ``2 sqrt(r^2 - d^2)`` of a 3-D spherocylinder at mid-depth);
:func:`media_fraction` gives the media (eq. OPL3) from them. The work is
proportional to the cells' area, not the frame's: each cell is drawn in its
bounding box. Where cells overlap, the thickest wins the pixel (the first in the
input order of equal chords), and the fraction is ``min(thickness / depth, 1,
open)`` of that thickest chord, computed once per pixel at the end.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["cell_boxes", "chord", "media_fraction", "rasterise_cells"]


def cell_boxes(
    cx: np.ndarray,
    cy: np.ndarray,
    angle_rad: np.ndarray,
    length_um: np.ndarray,
    width_um: np.ndarray,
    bend_um: np.ndarray,
    px: float,
    border: int,
    shape: tuple[int, int],
) -> np.ndarray:
    """``(n, 4)`` int64 boxes ``(i0, i1, j0, j1)`` of every cell, clipped to ``shape``.

    A pixel has a non-zero chord only within ``r + |a|`` of the cell's axis segment
    (``r`` the radius, ``a`` the bend of eq. 1, the segment ``length - width``
    long): with ``e`` the distance beyond the segment's end and ``t'`` the bent
    offset across it, ``e^2 + t'^2 < r^2`` and ``|t - t'| <= |a|`` give a distance
    to the segment of at most ``sqrt(r^2 + a^2 + 2 |a| r) = r + |a|``. The box is
    that region's bounding box grown by one pixel (the rounding of the box and of
    the distances is orders of magnitude smaller). ``cx, cy`` are the cell centres
    in um from the field of view's top-left corner, inside a border of ``border``
    pixels of ``px`` um. Empty boxes have ``i0 >= i1`` or ``j0 >= j1``.
    """
    half_segment = np.maximum(length_um / 2 - width_um / 2, 0.0)
    reach = width_um / 2 + bend_um + px
    reach_x = half_segment * np.abs(np.sin(angle_rad)) + reach
    reach_y = half_segment * np.abs(np.cos(angle_rad)) + reach
    boxes = np.empty((cx.size, 4), np.int64)
    boxes[:, 0] = np.maximum(np.floor((cy - reach_y) / px) + border, 0)
    boxes[:, 1] = np.minimum(np.ceil((cy + reach_y) / px) + border + 1, shape[0])
    boxes[:, 2] = np.maximum(np.floor((cx - reach_x) / px) + border, 0)
    boxes[:, 3] = np.minimum(np.ceil((cx + reach_x) / px) + border + 1, shape[1])
    return boxes


def chord(
    xc: np.ndarray,
    yc: np.ndarray,
    centre_um: tuple[float, float],
    angle_rad: float,
    length_um: float,
    width_um: float,
    curvature: tuple[float, float, float] | None,
) -> np.ndarray:
    """float32 chord ``2 sqrt(r^2 - d^2)`` (0 beyond ``r``) over the grid ``yc x xc``.

    ``d`` is the distance to the axis segment of
    :func:`~napari_symbac.scene.spherocylinder_distance`, in the same float64
    arithmetic value for value, with the temporaries reused in place.
    """
    return _chord_in_box(xc, yc, centre_um, angle_rad, length_um, width_um, curvature, 0.0)


#: A squared distance this far (relatively) beyond ``r^2`` gives a zero chord in
#: float64 whatever the rounding of the square root and its square (8 ulp suffice).
_OUTSIDE = 1.0 + 2.0**-40
#: Relative margin on ``r + |a|`` beyond which a bent cell's chord is 0 whatever its
#: bend (orders of magnitude above float64 rounding).
_NEAR = 1.0 + 2.0**-20


def _chord_in_box(
    xc: np.ndarray,
    yc: np.ndarray,
    centre_um: tuple[float, float],
    angle_rad: float,
    length_um: float,
    width_um: float,
    curvature: tuple[float, float, float] | None,
    pixel_area_um2: float,
) -> np.ndarray:
    """:func:`chord` over ``yc x xc``, its square roots taken only inside the cell.

    The squared distance ``q`` is computed everywhere in the box (a bent cell's, see
    :func:`_bent_chord`, only near its axis); where ``q >= r^2
    (1 + 2^-40)`` the chord is 0 exactly (``sqrt(q)^2 >= r^2`` after rounding), so
    the rest of the arithmetic, two square roots included, runs on the pixels
    inside only, unless the cell (at most ``width x length``, against pixels of
    ``pixel_area_um2``) covers most of the box. Either way the values are those of
    the whole formula, bit for bit.
    """
    r = width_um / 2
    half = max(length_um / 2 - r, 0.0)
    dx = xc - centre_um[0]
    dy = yc - centre_um[1]
    sin_a, cos_a = math.sin(angle_rad), math.cos(angle_rad)
    s = np.add((dy * cos_a)[:, None], (dx * sin_a)[None, :])
    t = np.subtract((dx * cos_a)[None, :], (dy * sin_a)[:, None])
    if curvature is not None:
        return _bent_chord(s, t, half, r, length_um, curvature)
    q = _squared_distance(s, t, half)
    if width_um * length_um > 0.6 * q.size * pixel_area_um2:
        # The cell fills most of its box (e.g. upright in a trench): finishing every
        # pixel costs less than picking out the inside ones.
        return _chord_from_squared(q, r)
    out = np.zeros(q.shape, np.float32)
    # ravel().nonzero() and the ndarray methods skip numpy's Python-level wrappers (a
    # few us per call, per cell).
    inside = np.less(q, (r * r) * _OUTSIDE).ravel().nonzero()[0]
    if inside.size:
        out.ravel()[inside] = _chord_from_squared(q.ravel()[inside], r)
    return out


def _squared_distance(s: np.ndarray, t: np.ndarray, half: float) -> np.ndarray:
    """Squared distance ``(s - clip(s, -half, half))^2 + t^2`` to the axis segment, from
    the offsets along (``s``) and across (``t``, overwritten) the axis."""
    d = s.clip(-half, half)  # = minimum(maximum(s, -half), half)
    np.subtract(s, d, out=d)
    np.square(d, out=d)
    np.square(t, out=t)
    return np.add(d, t, out=d)


def _chord_from_squared(q: np.ndarray, r: float) -> np.ndarray:
    """float32 chord ``2 sqrt(r^2 - d^2)`` (0 beyond ``r``) from ``q = d^2`` (float64,
    overwritten), as ``spherocylinder_distance`` then the chord compute it."""
    np.sqrt(q, out=q)
    np.multiply(q, q, out=q)
    np.subtract(r * r, q, out=q)
    np.maximum(q, 0.0, out=q)
    np.sqrt(q, out=q)
    return np.multiply(2, q, out=np.empty(q.shape, np.float32), casting="same_kind")


def _row_bands(boxes: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Disjoint rectangles ``(i0, i1, j0, j1)`` that together cover every box.

    The boxes' row intervals are merged where they overlap; each merged band of rows
    spans the columns of the boxes in it. A colony gives one rectangle (its bounding
    box), scattered cells a band per group of rows that hold cells, so that a pass
    over the bands never covers the empty rows of a pad.
    """
    order = np.argsort(boxes[:, 0], kind="stable")
    bands: list[list[int]] = []
    for i0, i1, j0, j1 in boxes[order].tolist():
        if bands and i0 < bands[-1][1]:
            band = bands[-1]
            band[1] = max(band[1], i1)
            band[2] = min(band[2], j0)
            band[3] = max(band[3], j1)
        else:
            bands.append([i0, i1, j0, j1])
    return [(b[0], b[1], b[2], b[3]) for b in bands]


def _bent_chord(
    s: np.ndarray,
    t: np.ndarray,
    half: float,
    r: float,
    length_um: float,
    curvature: tuple[float, float, float],
) -> np.ndarray:
    """Chord of a cell bent by eq. 1 (``t -= a sin(pi l / b + c)``), from the straight
    offsets ``s, t`` over a box.

    The bend moves a pixel's offset ``t`` by at most ``|a|``: beyond ``r + |a|`` of
    the axis line, or beyond a pole (``|s| > half + r``), the chord is 0 with or
    without it (the margin :data:`_NEAR` is far above rounding), so the sine and the
    rest of the formula run on the pixels left only, value for value as on all.
    """
    a_um, b, c = curvature
    near = np.abs(t) <= (r + abs(a_um)) * _NEAR
    near &= np.abs(s) <= (half + r) * _NEAR
    near = near.ravel().nonzero()[0]
    out = np.zeros(s.shape, np.float32)
    s_near = s.ravel()[near]
    ell = np.add(s_near, length_um / 2)
    np.divide(ell, length_um, out=ell)
    ell.clip(0.0, 1.0, out=ell)
    np.multiply(ell, math.pi, out=ell)
    np.divide(ell, b, out=ell)
    np.add(ell, c, out=ell)
    np.sin(ell, out=ell)
    np.multiply(a_um, ell, out=ell)
    t_near = t.ravel()[near]
    np.subtract(t_near, ell, out=t_near)
    out.ravel()[near] = _chord_from_squared(_squared_distance(s_near, t_near, half), r)
    return out


def rasterise_cells(
    xc: np.ndarray,
    yc: np.ndarray,
    px: float,
    border: int,
    open_frac: np.ndarray,
    depth_um: float,
    ids: np.ndarray,
    centres_um: tuple[np.ndarray, np.ndarray],
    angle_rad: np.ndarray,
    length_um: np.ndarray,
    width_um: np.ndarray,
    curvature: dict[int, tuple[float, float, float]],
    *,
    closed: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Cells fraction and instance labels of one frame (eq. OPL2-3).

    Parameters
    ----------
    xc, yc
        Physical coordinates (um) of the render-pixel centres along columns and
        rows, from the field of view's top-left corner: ``(index - border + 0.5) px``.
    px
        Render pixel size (um).
    border
        Pixels outside the field of view on each side.
    open_frac
        Fraction of each pixel open to cells and media (``1 - device``, in [0, 1]).
    depth_um
        Optical depth: a chord as thick as it fills the pixel (``cells = 1``).
    ids
        Cell ids (>= 1, unique), int64.
    centres_um
        Cell centres ``(x, y)`` in the coordinates of ``xc, yc``.
    angle_rad, length_um, width_um
        Axis angle (0 = along the rows' axis, y), pole-to-pole length and width.
    curvature
        ``id -> (a_um, b, c)`` of eq. 1 for the bent cells.
    closed
        Whether there is device: ``open_frac`` may be below 1 and a cell pixel where
        it is 0 keeps no label. ``False`` (an agar pad) says that ``open_frac`` is 1
        everywhere, so the fraction is ``min(thickness / depth, 1)``, and just
        ``thickness / depth`` when no cell is wider than the depth.

    Returns
    -------
    cells, labels
        Images of ``open_frac``'s shape: ``cells = min(thickness / depth, 1, open)``
        (float32) of the thickest cell, ``labels`` the id of the thickest cell (the
        first of equal chords) where ``cells > 0``, else 0, uint16 when every id
        fits (half the memory traffic of uint32, here and in the masks made from
        them), else uint32. The media fraction is ``open - cells``
        (:func:`media_fraction`).

    Notes
    -----
    These are the only two frame-sized images made: the cells image holds the
    thickest chord so far while the cells are drawn (each cell compares its chord
    with it and takes the label where it is strictly thicker, so the first of equal
    chords keeps the pixel) and is turned into fractions in place at the end, over
    the rows that hold cells.
    """
    shape = open_frac.shape
    cells = np.zeros(shape, np.float32)
    narrow = ids.size == 0 or int(ids.max()) <= np.iinfo(np.uint16).max
    label_type = np.uint16 if narrow else np.uint32
    labels = np.zeros(shape, label_type)
    cx, cy = centres_um
    bend = np.array([abs(curvature[i][0]) if i in curvature else 0.0 for i in ids.tolist()])
    boxes = cell_boxes(cx, cy, angle_rad, length_um, width_um, bend, px, border, shape)
    drawn = np.flatnonzero((boxes[:, 0] < boxes[:, 1]) & (boxes[:, 2] < boxes[:, 3]))
    if drawn.size == 0:
        return cells, labels
    pixel_area = px * px
    columns = (ids, cx, cy, angle_rad, length_um, width_um)
    for box, (cell_id, x, y, angle, length, width) in zip(
        boxes[drawn].tolist(), zip(*(c[drawn].tolist() for c in columns)), strict=True
    ):
        i0, i1, j0, j1 = box
        thick = _chord_in_box(
            xc[j0:j1], yc[i0:i1], (x, y), angle, length, width, curvature.get(cell_id), pixel_area
        )
        box_t = cells[i0:i1, j0:j1]
        take = thick > box_t
        np.maximum(box_t, thick, out=box_t)
        np.putmask(labels[i0:i1, j0:j1], take, cell_id)
    # min(thickness / depth, 1, open) = min(thickness / depth, open): open <= 1. With
    # open = 1 and no chord above the (float32) depth, the quotient is at most 1
    # already: a chord is at most the width (times 1 + 4 ulp of rounding).
    depth = np.float32(depth_um)
    capped = closed or width_um[drawn].max() * (1 + 2.0**-40) > float(depth)
    for i0, i1, j0, j1 in _row_bands(boxes[drawn]):
        frac = cells[i0:i1, j0:j1]
        np.divide(frac, depth, out=frac)
        if capped:
            np.minimum(frac, open_frac[i0:i1, j0:j1], out=frac)
        if closed:
            # A pixel inside the PDMS (open = 0) keeps no label, whichever cell is there.
            np.putmask(labels[i0:i1, j0:j1], frac <= 0, label_type(0))
    return cells, labels


def media_fraction(open_frac: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Media fraction ``open - cells`` (eq. OPL3: what the cells leave of the open depth).

    ``cells <= open`` everywhere, so the difference is never negative.
    """
    return np.subtract(open_frac, cells)
