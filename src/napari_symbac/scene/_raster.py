"""Rasterising cells into a scene's images, each cell only where it can reach.

:func:`rasterise_cells` turns the cells of one frame into the ``cells`` fraction
and the instance labels of :class:`~napari_symbac.scene.Scene` (eq. OPL2: the
chord ``2 sqrt(r^2 - d^2)`` of a 3-D spherocylinder at mid-depth);
:func:`media_fraction` gives the media (eq. OPL3) from them. The work is
proportional to the cells' area, not the frame's: a compiled pass (numba) goes row
by row, drawing each cell whose bounding box covers the row over the columns it can
reach. Where cells overlap, the thickest wins the pixel (the first in the input
order of equal chords), and the fraction is ``min(thickness / depth, 1, open)`` of
that thickest chord, computed once per pixel when its row is drawn.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

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
    """float32 chord ``2 sqrt(r^2 - d^2)`` (eq. OPL2; 0 beyond ``r``) over the grid ``yc x xc``.

    ``d`` is the distance to the axis segment of
    :func:`~napari_symbac.scene.spherocylinder_distance` (bent by eq. 1 with
    ``curvature = (a_um, b, c)``), in the same float64 arithmetic value for value:
    the rows of :func:`rasterise_cells`, over every pixel of the grid.
    """
    xc = np.ascontiguousarray(xc, np.float64)
    yc = np.ascontiguousarray(yc, np.float64)
    bent = curvature is not None
    a_um, b, c = curvature if bent else (0.0, 1.0, 0.0)
    out = np.empty((yc.size, xc.size), np.float32)
    _chord_grid(
        out, xc, yc, float(centre_um[0]), float(centre_um[1]), float(angle_rad),
        float(length_um), float(width_um), bent, float(a_um), float(b), float(c),
    )
    return out


#: Relative margin on ``r + |a|`` beyond which a bent cell's chord is 0 whatever its
#: bend (orders of magnitude above float64 rounding).
_NEAR = 1.0 + 2.0**-20


@njit(cache=True, nogil=True)
def _chord_row(
    out: np.ndarray,
    xc: np.ndarray,
    lo: int,
    hi: int,
    cx: float,
    dy_cos: float,
    dy_sin: float,
    sin_a: float,
    cos_a: float,
    half: float,
    r: float,
    length: float,
    bent: bool,
    a: float,
    b: float,
    c: float,
) -> None:
    """The chord at columns ``lo..hi-1`` of one row into ``out[lo:hi]`` (float32).

    The arithmetic of :func:`~napari_symbac.scene.spherocylinder_distance` then
    ``2 sqrt(max(r^2 - d^2, 0))``, operation for operation: offsets ``s = dy cos +
    dx sin`` along and ``t = dx cos - dy sin`` across the axis (``dy cos``, ``dy sin``
    given for the row), ``q = (s - clip(s, -half, half))^2 + t^2``, ``d = sqrt(q)``.
    A straight cell's row has no branch (it compiles to vector instructions). A bent
    cell moves ``t`` by ``a sin(pi l / b + c)``, ``l = clip((s + length / 2) /
    length, 0, 1)`` (eq. 1); beyond ``r + |a|`` of its straight axis line or beyond a
    pole (``|s| > half + r``) its chord is 0 with or without the bend (the margin
    :data:`_NEAR` is far above rounding), so the sine, a libm call, runs only on the
    pixels left.
    """
    r2 = r * r
    if not bent:
        for j in range(lo, hi):
            dx = xc[j] - cx
            s = dy_cos + dx * sin_a
            t = dx * cos_a - dy_sin
            d = s - min(max(s, -half), half)
            q = math.sqrt(d * d + t * t)
            q = r2 - q * q
            out[j] = np.float32(2.0 * math.sqrt(q if q >= 0.0 else 0.0))
        return
    s_near, t_near = (half + r) * _NEAR, (r + abs(a)) * _NEAR
    for j in range(lo, hi):
        dx = xc[j] - cx
        s = dy_cos + dx * sin_a
        t = dx * cos_a - dy_sin
        if not (abs(t) <= t_near and abs(s) <= s_near):
            out[j] = 0.0
            continue
        ell = min(max((s + length / 2) / length, 0.0), 1.0)
        t = t - a * math.sin(ell * math.pi / b + c)
        d = s - min(max(s, -half), half)
        q = math.sqrt(d * d + t * t)
        q = r2 - q * q
        out[j] = np.float32(2.0 * math.sqrt(q if q >= 0.0 else 0.0))


@njit(cache=True, nogil=True)
def _chord_grid(
    out: np.ndarray,
    xc: np.ndarray,
    yc: np.ndarray,
    cx: float,
    cy: float,
    angle: float,
    length: float,
    width: float,
    bent: bool,
    a: float,
    b: float,
    c: float,
) -> None:
    """:func:`chord` into ``out`` (``yc.size x xc.size`` float32), every pixel."""
    r = width / 2
    half = max(length / 2 - r, 0.0)
    sin_a, cos_a = math.sin(angle), math.cos(angle)
    for i in range(yc.size):
        dy = yc[i] - cy
        _chord_row(
            out[i], xc, 0, xc.size, cx, dy * cos_a, dy * sin_a, sin_a, cos_a, half, r,
            length, bent, a, b, c,
        )


@njit(cache=True, nogil=True)
def _row_span(
    dy: float,
    sin_a: float,
    cos_a: float,
    s_reach: float,
    t_reach: float,
    cx: float,
    x0: float,
    px: float,
    j0: int,
    j1: int,
) -> tuple[int, int]:
    """Columns ``[lo, hi)`` of a row ``dy`` below the centre that may hold a chord.

    The chord is 0 outside the rectangle ``|s| <= s_reach``, ``|t| <= t_reach`` about
    the axis (``s = dy cos + dx sin``, ``t = dx cos - dy sin``): each bound is an
    interval of ``dx``, and their intersection, grown by two pixels on each side (far
    above the rounding of the bounds), is clipped to the box's columns ``[j0, j1)``.
    Where a coefficient of ``dx`` is within ``1e-9`` of 0 (the axis along or across
    the rows), its bound holds for all of the row or none of it (``|dx| 1e-9`` is far
    below a pixel): none beyond ``2 px`` of margin. ``x0`` is the x of column 0,
    ``px`` the pixel size. Empty: ``lo == hi``.
    """
    lo, hi = -np.inf, np.inf
    if abs(cos_a) > 1e-9:
        u, v = (dy * sin_a - t_reach) / cos_a, (dy * sin_a + t_reach) / cos_a
        lo, hi = max(lo, min(u, v)), min(hi, max(u, v))
    elif abs(dy * sin_a) > t_reach + 2 * px:
        return j0, j0
    if abs(sin_a) > 1e-9:
        u, v = (-s_reach - dy * cos_a) / sin_a, (s_reach - dy * cos_a) / sin_a
        lo, hi = max(lo, min(u, v)), min(hi, max(u, v))
    elif abs(dy * cos_a) > s_reach + 2 * px:
        return j0, j0
    if lo > hi:
        return j0, j0
    first = math.floor(max((cx + lo - x0) / px - 2.0, float(j0)))
    last = math.ceil(min((cx + hi - x0) / px + 3.0, float(j1)))
    return int(first), max(int(last), int(first))


@njit(cache=True, nogil=True)
def _rows_of_cells(boxes: np.ndarray, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """For every image row, the cells whose boxes cover it, in input order.

    ``(start, members)``: the cells of row ``i`` are ``members[start[i]:start[i + 1]]``.
    """
    start = np.zeros(rows + 1, np.int64)
    for k in range(boxes.shape[0]):
        for i in range(boxes[k, 0], boxes[k, 1]):
            start[i + 1] += 1
    for i in range(rows):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    members = np.empty(start[rows], np.int64)
    for k in range(boxes.shape[0]):
        for i in range(boxes[k, 0], boxes[k, 1]):
            members[fill[i]] = k
            fill[i] += 1
    return start, members


@njit(cache=True, nogil=True)
def _rasterise(
    cells: np.ndarray,
    labels: np.ndarray,
    open_frac: np.ndarray,
    xc: np.ndarray,
    yc: np.ndarray,
    px: float,
    boxes: np.ndarray,
    ids: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
    angle: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    bent: np.ndarray,
    bend_a: np.ndarray,
    bend_b: np.ndarray,
    bend_c: np.ndarray,
    depth: np.float32,
    capped: bool,
    closed: bool,
) -> None:
    """Draw the cells into ``cells`` (float32 zeros) and ``labels`` (zeros) as fractions:
    :func:`rasterise_cells` below its checks.

    Row by row, so that each row is finished while it is in the cache: every cell
    whose box covers the row, in input order, is drawn over the span of columns it
    can reach (:func:`_row_span`; ``r`` across the axis, ``half + r`` along it, ``r
    + |a|`` across for a bent cell): its chords into a row buffer
    (:func:`_chord_row`), then it takes the pixels where its chord is strictly above
    the thickest so far (the first of equal chords keeps one). Every pixel with a
    chord then holds its thickest cell's label, so a second sweep over the same
    spans turns each cell's own pixels (``labels == id``) into fractions once:
    ``min(chord / depth, open)`` in float32 (the minimum only when ``capped``), the
    label dropped where that is 0 and the scene is ``closed``.
    """
    n = ids.size
    half = np.empty(n)
    sin_a = np.empty(n)
    cos_a = np.empty(n)
    s_reach = np.empty(n)
    t_reach = np.empty(n)
    for k in range(n):
        r = width[k] / 2
        half[k] = max(length[k] / 2 - r, 0.0)
        sin_a[k], cos_a[k] = math.sin(angle[k]), math.cos(angle[k])
        s_reach[k] = (half[k] + r) * _NEAR
        t_reach[k] = (r + abs(bend_a[k])) * _NEAR
    start, members = _rows_of_cells(boxes, cells.shape[0])
    x0 = xc[0]
    row = np.empty(xc.size, np.float32)
    spans = np.empty((n, 2), np.int64)
    for i in range(cells.shape[0]):
        if start[i] == start[i + 1]:
            continue
        drawn, taken, room = cells[i], labels[i], open_frac[i]
        for m in range(start[i], start[i + 1]):
            k = members[m]
            dy = yc[i] - cy[k]
            lo, hi = _row_span(
                dy, sin_a[k], cos_a[k], s_reach[k], t_reach[k], cx[k], x0, px, boxes[k, 2],
                boxes[k, 3],
            )
            spans[m - start[i], 0], spans[m - start[i], 1] = lo, hi
            _chord_row(
                row, xc, lo, hi, cx[k], dy * cos_a[k], dy * sin_a[k], sin_a[k], cos_a[k],
                half[k], width[k] / 2, length[k], bent[k], bend_a[k], bend_b[k], bend_c[k],
            )
            cid = ids[k]
            for j in range(lo, hi):
                if row[j] > drawn[j]:
                    drawn[j] = row[j]
                    taken[j] = cid
        for m in range(start[i], start[i + 1]):
            cid = ids[members[m]]
            for j in range(spans[m - start[i], 0], spans[m - start[i], 1]):
                if taken[j] == cid:
                    v = np.float32(drawn[j] / depth)
                    if capped and not v <= room[j]:
                        v = room[j]
                    drawn[j] = v
                    if closed and v <= 0:
                        taken[j] = 0


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
    These are the only two frame-sized images made. One compiled pass
    (:func:`_rasterise`) goes row by row: it draws the cells whose boxes cover the
    row, each over the span of columns it can reach (:func:`_row_span`), keeping the
    thickest chord so far in the cells image, then turns each cell's own pixels of
    the row into fractions.
    """
    shape = open_frac.shape
    cells = np.zeros(shape, np.float32)
    narrow = ids.size == 0 or int(ids.max()) <= np.iinfo(np.uint16).max
    label_type = np.uint16 if narrow else np.uint32
    labels = np.zeros(shape, label_type)
    cx, cy = centres_um
    bend = np.array([curvature.get(i, (0.0, 1.0, 0.0)) for i in ids.tolist()], np.float64)
    bend = bend.reshape(ids.size, 3)
    reach = np.abs(bend[:, 0])
    boxes = cell_boxes(cx, cy, angle_rad, length_um, width_um, reach, px, border, shape)
    drawn = np.flatnonzero((boxes[:, 0] < boxes[:, 1]) & (boxes[:, 2] < boxes[:, 3]))
    if drawn.size == 0:
        return cells, labels
    # min(thickness / depth, 1, open) = min(thickness / depth, open): open <= 1. With
    # open = 1 and no chord above the (float32) depth, the quotient is at most 1
    # already: a chord is at most the width (times 1 + 4 ulp of rounding).
    depth = np.float32(depth_um)
    capped = closed or width_um[drawn].max() * (1 + 2.0**-40) > float(depth)
    bend = np.ascontiguousarray(bend[drawn].T)  # a, b, c of eq. 1: rows of 0, 1, 0 if straight

    def column(values: np.ndarray, dtype: type = np.float64) -> np.ndarray:
        return np.asarray(values, dtype)[drawn]  # a new contiguous array

    _rasterise(
        cells,
        labels,
        np.ascontiguousarray(open_frac, np.float32),
        np.ascontiguousarray(xc, np.float64),
        np.ascontiguousarray(yc, np.float64),
        float(px),
        boxes[drawn],
        column(ids, np.int64),
        column(cx),
        column(cy),
        column(angle_rad),
        column(length_um),
        column(width_um),
        bend[0] != 0,
        bend[0],
        bend[1],
        bend[2],
        depth,
        bool(capped),
        bool(closed),
    )
    return cells, labels


def media_fraction(open_frac: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Media fraction ``open - cells`` (eq. OPL3: what the cells leave of the open depth).

    ``cells <= open`` everywhere, so the difference is never negative.
    """
    return np.subtract(open_frac, cells)
