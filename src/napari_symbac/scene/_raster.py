"""Rasterising cells into a scene's images, each cell only in its own box.

:func:`rasterise_cells` turns the cells of one frame into the ``cells`` and
``media`` fractions and the instance labels of :class:`~napari_symbac.scene.Scene`
(eq. OPL2: the chord ``2 sqrt(r^2 - d^2)`` of a 3-D spherocylinder at mid-depth).
The work is proportional to the cells' area, not the frame's: each cell is drawn
in its bounding box. When the boxes about fill their bounding rectangle (a trench)
the thickness and labels are drawn into that rectangle and converted to fractions
once; scattered cells (a pad) convert their own boxes as they are drawn, so that no
pass covers the empty frame. Where cells overlap, the thickest wins the pixel (the
first in the input order of equal chords), and the fraction is ``min(thickness /
depth, 1, open)``; since that is a non-decreasing function of the thickness, the
maximum of the cells' fractions is the fraction of the maximum thickness, so each
cell can write its own.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["cell_boxes", "chord", "rasterise_cells"]


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

    The squared distance ``q`` is computed everywhere in the box; where ``q >= r^2
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
        a_um, b, c = curvature
        ell = np.clip((s + length_um / 2) / length_um, 0.0, 1.0)
        t -= a_um * np.sin(ell * math.pi / b + c)
    d = np.clip(s, -half, half)  # = minimum(maximum(s, -half), half)
    np.subtract(s, d, out=d)
    np.square(d, out=d)
    np.square(t, out=t)
    np.add(d, t, out=d)
    if width_um * length_um > 0.6 * d.size * pixel_area_um2:
        # The cell fills most of its box (e.g. upright in a trench): finishing every
        # pixel costs less than picking out the inside ones.
        np.sqrt(d, out=d)
        np.multiply(d, d, out=d)
        np.subtract(r * r, d, out=d)
        np.maximum(d, 0.0, out=d)
        np.sqrt(d, out=d)
        return np.multiply(2, d, out=np.empty(d.shape, np.float32), casting="same_kind")
    out = np.zeros(d.shape, np.float32)
    inside = np.flatnonzero(d < (r * r) * _OUTSIDE)
    if inside.size:
        q = d.ravel()[inside]
        np.sqrt(q, out=q)
        np.multiply(q, q, out=q)
        np.subtract(r * r, q, out=q)
        np.maximum(q, 0.0, out=q)
        np.sqrt(q, out=q)
        chord_in = np.multiply(2, q, out=np.empty(q.shape, np.float32), casting="same_kind")
        out.ravel()[inside] = chord_in
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
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells and media fractions and instance labels of one frame (eq. OPL2-3).

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
        Whether ``open_frac`` may be 0 somewhere (device): a cell pixel there keeps
        no label. ``False`` (an agar pad) skips that test.

    Returns
    -------
    cells, media, labels
        float32, float32 and uint32 images of ``open_frac``'s shape: ``cells =
        min(thickness / depth, 1, open)`` of the thickest cell, ``media = max(open -
        cells, 0)``, ``labels`` the id of the thickest cell (the first of equal
        chords) where ``cells > 0``, else 0.
    """
    shape = open_frac.shape
    cells = np.zeros(shape, np.float32)
    labels = np.zeros(shape, np.uint32)
    cx, cy = centres_um
    bend = np.array([abs(curvature[int(i)][0]) if int(i) in curvature else 0.0 for i in ids])
    boxes = cell_boxes(cx, cy, angle_rad, length_um, width_um, bend, px, border, shape)
    drawn = np.flatnonzero((boxes[:, 0] < boxes[:, 1]) & (boxes[:, 2] < boxes[:, 3]))
    if drawn.size == 0:
        return cells, open_frac.copy(), labels
    depth = np.float32(depth_um)
    top, left = boxes[drawn, 0].min(), boxes[drawn, 2].min()
    bottom, right = boxes[drawn, 1].max(), boxes[drawn, 3].max()
    covered = ((boxes[drawn, 1] - boxes[drawn, 0]) * (boxes[drawn, 3] - boxes[drawn, 2])).sum()
    # Dense (the boxes about fill their bounding rectangle, a trench): the thickness
    # and labels are drawn into that rectangle, which is converted to fractions in one
    # pass. Scattered (a pad): each cell converts its own box as it is drawn, so no
    # pass covers the empty frame; the thickness lives in the media image meanwhile.
    dense = (bottom - top) * (right - left) <= 2 * covered
    if dense:
        rect = (slice(top, bottom), slice(left, right))
        thickness = np.zeros((bottom - top, right - left), np.float32)
        work_labels = np.zeros(thickness.shape, np.uint32)
    else:
        top = left = 0
        media = np.zeros(shape, np.float32)
        thickness, work_labels = media, labels
    pixel_area = px * px
    for k in drawn.tolist():
        i0, i1, j0, j1 = boxes[k].tolist()
        cell_id = int(ids[k])
        thick = _chord_in_box(
            xc[j0:j1],
            yc[i0:i1],
            (float(cx[k]), float(cy[k])),
            float(angle_rad[k]),
            float(length_um[k]),
            float(width_um[k]),
            curvature.get(cell_id),
            pixel_area,
        )
        local = (slice(i0 - top, i1 - top), slice(j0 - left, j1 - left))
        box_t = thickness[local]
        take = thick > box_t
        np.maximum(box_t, thick, out=box_t)
        box_l = work_labels[local]
        np.putmask(box_l, take, np.uint32(cell_id))
        if dense:
            continue
        # min(thickness / depth, 1, open) = min(thickness / depth, open): open <= 1;
        # the maximum over cells of this non-decreasing map of the chord is the map
        # of the maximum chord.
        box = (slice(i0, i1), slice(j0, j1))
        frac = np.divide(thick, depth, out=thick)
        open_box = open_frac[box]
        np.minimum(frac, open_box, out=frac)
        box_c = cells[box]
        np.maximum(box_c, frac, out=box_c)
        if closed:
            # A pixel inside the PDMS (open = 0) keeps no label, whichever cell is there.
            np.logical_and(take, frac <= 0, out=take)
            np.putmask(box_l, take, np.uint32(0))
    if dense:
        frac = np.divide(thickness, depth, out=thickness)
        open_rect = open_frac[rect]
        np.minimum(frac, open_rect, out=frac)
        cells[rect] = frac
        if closed:
            np.putmask(work_labels, frac <= 0, np.uint32(0))
        labels[rect] = work_labels
        media = open_frac.copy()
        np.subtract(open_rect, frac, out=media[rect])
    else:
        np.subtract(open_frac, cells, out=media)
    return cells, media, labels
