"""Penalty on cells where no cell can be: inside another cell, or through a trench wall.

The scene takes the thickest chord per pixel, so a second rod inside a first costs
nothing in the image: the fit could hide duplicates. Cells are solid and lie in
one layer (a trench, a pad), so two spherocylinders of radius ``r`` whose axis
segments come closer than ``OVERLAP_TOLERANCE * 2 r`` overlap; each overlapping
pair adds a residual ``(OVERLAP_TOLERANCE * 2 r - d) / sd`` to the cost
(``d`` the shortest distance between the axis segments).

In a trench the walls confine the cells (the simulation's, section 1.1), yet a rod
lying across the trench can cost little in the image where the walls are as dark as
cells (found on a series fit: near-horizontal rods longer than the trench is wide).
A cell whose outline reaches more than ``WALL_TOLERANCE`` of its width past a wall
adds ``(reach past the wall - WALL_TOLERANCE w) / sd``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from napari_symbac.fit.engine import Layout

__all__ = [
    "OVERLAP_SD_UM",
    "OVERLAP_TOLERANCE",
    "WALL_TOLERANCE",
    "overlap_terms",
    "segment_distance",
]

#: Fraction of the width two touching cells may overlap without penalty (septa and
#: neighbours on a pad press into each other a little).
OVERLAP_TOLERANCE = 0.9
#: Scale of the penalty (um): 20 nm of overlap costs as much as one s.d. of a pixel.
OVERLAP_SD_UM = 0.02
#: Fraction of its width a cell may reach past a trench wall without penalty: the
#: fitted walls are where the image darkens, and tilted cells press into them (on the
#: SyMBac sample trench the fitted cells, tilted by 0.12-0.15 rad, reach 0.01-0.10 um,
#: up to a tenth of their width, past the fitted walls).
WALL_TOLERANCE = 0.25


Point = tuple[float, float]


def _segment(block: np.ndarray, width: float) -> tuple[Point, Point]:
    cx, cy, angle, length = (float(v) for v in block[:4])
    half = max(max(length, width) / 2 - width / 2, 0.0)
    dx, dy = math.sin(angle) * half, math.cos(angle) * half
    return (cx - dx, cy - dy), (cx + dx, cy + dy)


def _to_point(c: Point) -> Point:
    return float(c[0]), float(c[1])


def _point_distance(c: Point, a: Point, b: Point) -> float:
    """Distance from point ``c`` to the segment ``a b``."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    ex, ey = c[0] - a[0], c[1] - a[1]
    t = min(max((ex * dx + ey * dy) / max(dx * dx + dy * dy, 1e-12), 0.0), 1.0)
    return math.hypot(ex - t * dx, ey - t * dy)


def _side(u: Point, v: Point, w: Point) -> float:
    return (v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0])


def segment_distance(p: tuple[Point, Point], q: tuple[Point, Point]) -> float:
    """Shortest distance between the segments ``p`` and ``q`` (2-D, end points)."""
    a, b = _to_point(p[0]), _to_point(p[1])
    c, e = _to_point(q[0]), _to_point(q[1])
    # Crossing segments: distance 0.
    if _side(a, b, c) * _side(a, b, e) < 0 and _side(c, e, a) * _side(c, e, b) < 0:
        return 0.0
    return min(
        _point_distance(a, c, e),
        _point_distance(b, c, e),
        _point_distance(c, a, b),
        _point_distance(e, a, b),
    )


def _widths(blocks: np.ndarray, shared_width: float, layout: Layout) -> np.ndarray:
    widths = shared_width + (blocks[:, layout.i_dwidth] if layout.per_cell_width else 0.0)
    return np.maximum(np.broadcast_to(widths, (len(blocks),)), 0.2)


def _width(x: np.ndarray, layout: Layout, i: int) -> float:
    """Cell ``i``'s width (as :func:`_widths`), from the parameter vector."""
    pc = layout.per_cell
    width = float(x[layout.n * pc])
    if layout.per_cell_width:
        width += float(x[i * pc + layout.i_dwidth])
    return max(width, 0.2)


def _pair(x: np.ndarray, layout: Layout, i: int, j: int) -> float:
    """How deep cells ``i`` and ``j`` overlap beyond the tolerance, in s.d."""
    pc = layout.per_cell
    wi, wj = _width(x, layout, i), _width(x, layout, j)
    limit = OVERLAP_TOLERANCE * (wi + wj) / 2
    d = segment_distance(
        _segment(x[i * pc : i * pc + 4], wi), _segment(x[j * pc : j * pc + 4], wj)
    )
    return max(limit - d, 0.0) / OVERLAP_SD_UM


def _wall(x: np.ndarray, layout: Layout, i: int) -> float:
    """Cell ``i``'s reach past the nearer trench wall beyond the tolerance, in s.d."""
    n, pc = layout.n, layout.per_cell
    width = _width(x, layout, i)
    cx, _, angle, length = (float(v) for v in x[i * pc : i * pc + 4])
    half_extent = abs(math.sin(angle)) * max(max(length, width) - width, 0.0) / 2 + width / 2
    left, trench_width = float(x[n * pc + 1]), float(x[n * pc + 2])
    past = max(left - (cx - half_extent), (cx + half_extent) - (left + trench_width))
    return max(past - WALL_TOLERANCE * width, 0.0) / OVERLAP_SD_UM


def overlap_terms(
    x: np.ndarray, layout: Layout, scales: np.ndarray | None = None, step: float = 1e-3
) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals of the overlapping pairs and of the cells through a trench wall and,
    with ``scales``, their Jacobian.

    Returns the residuals (none when no cell is where no cell can be) and ``d r / d z``
    (``z = x / scales``, central differences of ``step`` scaled units on the cells'
    parameters, the shared width and the trench's walls), one row per term.
    """
    n, pc = layout.n, layout.per_cell
    blocks = x[: n * pc].reshape(n, pc)
    widths = _widths(blocks, x[n * pc], layout)
    reach = np.maximum(blocks[:, 3], widths) / 2
    gap = np.hypot(blocks[:, None, 0] - blocks[None, :, 0], blocks[:, None, 1] - blocks[None, :, 1])
    near = np.argwhere(np.triu(gap < reach[:, None] + reach[None, :], 1))

    terms = [
        (functools.partial(_pair, layout=layout, i=int(i), j=int(j)), [int(i), int(j)], [n * pc])
        for i, j in near
    ]
    if layout.trench:
        walls = [n * pc, n * pc + 1, n * pc + 2]
        terms += [
            (functools.partial(_wall, layout=layout, i=i), [i], walls) for i in range(n)
        ]
    terms = [term for term in terms if term[0](x) > 0]
    res = np.array([term[0](x) for term in terms])
    if scales is None:
        return res, None
    jac = np.zeros((len(terms), x.size))
    for row, (term, cells, shared) in enumerate(terms):
        for k in [*(c * pc + q for c in cells for q in range(pc)), *shared]:
            h = step * scales[k]
            values = []
            for sign in (1.0, -1.0):
                xk = x.copy()
                xk[k] += sign * h
                values.append(term(xk))
            jac[row, k] = (values[0] - values[1]) / (2 * step)
    return res, jac
