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


def _segment(block: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    cx, cy, angle, length = block[:4]
    half = max(max(length, width) / 2 - width / 2, 0.0)
    d = np.array([math.sin(angle), math.cos(angle)]) * half
    c = np.array([cx, cy])
    return c - d, c + d


def segment_distance(p: tuple[np.ndarray, np.ndarray], q: tuple[np.ndarray, np.ndarray]) -> float:
    """Shortest distance between the segments ``p`` and ``q`` (2-D, end points)."""

    def point(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
        d = b - a
        t = float(np.clip(np.dot(c - a, d) / max(float(np.dot(d, d)), 1e-12), 0.0, 1.0))
        return float(np.hypot(*(c - a - t * d)))

    # Crossing segments: distance 0.
    (a, b), (c, e) = p, q

    def side(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> float:
        return float((v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0]))

    if side(a, b, c) * side(a, b, e) < 0 and side(c, e, a) * side(c, e, b) < 0:
        return 0.0
    return min(point(a, c, e), point(b, c, e), point(c, a, b), point(e, a, b))


def _widths(blocks: np.ndarray, shared_width: float, layout: Layout) -> np.ndarray:
    widths = shared_width + (blocks[:, layout.i_dwidth] if layout.per_cell_width else 0.0)
    return np.maximum(np.broadcast_to(widths, (len(blocks),)), 0.2)


def _pair(blocks: np.ndarray, widths: np.ndarray, i: int, j: int) -> float:
    limit = OVERLAP_TOLERANCE * (widths[i] + widths[j]) / 2
    d = segment_distance(_segment(blocks[i], widths[i]), _segment(blocks[j], widths[j]))
    return max(limit - d, 0.0) / OVERLAP_SD_UM


def _wall(x: np.ndarray, layout: Layout, i: int) -> float:
    """Cell ``i``'s reach past the nearer trench wall beyond the tolerance, in s.d."""
    n, pc = layout.n, layout.per_cell
    blocks = x[: n * pc].reshape(n, pc)
    width = float(_widths(blocks[i : i + 1], x[n * pc], layout)[0])
    cx, _, angle, length = blocks[i, :4]
    half_extent = abs(math.sin(angle)) * max(max(length, width) - width, 0.0) / 2 + width / 2
    left, trench_width = x[n * pc + 1], x[n * pc + 2]
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

    def pair(xk: np.ndarray, i: int, j: int) -> float:
        bk = xk[: n * pc].reshape(n, pc)
        return _pair(bk, _widths(bk, xk[n * pc], layout), i, j)

    terms = [
        (functools.partial(pair, i=int(i), j=int(j)), [int(i), int(j)], [n * pc])
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
