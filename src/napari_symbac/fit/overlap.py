"""Penalty on overlapping cells: two rods cannot share space.

The scene takes the thickest chord per pixel, so a second rod inside a first costs
nothing in the image: the fit could hide duplicates. Cells are solid and lie in
one layer (a trench, a pad), so two spherocylinders of radius ``r`` whose axis
segments come closer than ``OVERLAP_TOLERANCE * 2 r`` overlap; each overlapping
pair adds a residual ``(OVERLAP_TOLERANCE * 2 r - d) / sd`` to the cost
(``d`` the shortest distance between the axis segments).
"""

from __future__ import annotations

import math

import numpy as np

from napari_symbac.fit.engine import Layout

__all__ = ["OVERLAP_SD_UM", "OVERLAP_TOLERANCE", "overlap_terms", "segment_distance"]

#: Fraction of the width two touching cells may overlap without penalty (septa and
#: neighbours on a pad press into each other a little).
OVERLAP_TOLERANCE = 0.9
#: Scale of the penalty (um): 20 nm of overlap costs as much as one s.d. of a pixel.
OVERLAP_SD_UM = 0.02


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


def overlap_terms(
    x: np.ndarray, layout: Layout, scales: np.ndarray | None = None, step: float = 1e-3
) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals of the overlapping pairs and, with ``scales``, their Jacobian.

    Returns the residuals of the pairs that overlap (none when no cells do) and
    ``d r / d z`` (``z = x / scales``, central differences of ``step`` scaled units
    on the two cells' parameters and the shared width), one row per pair.
    """
    n, pc = layout.n, layout.per_cell
    if n < 2:
        return np.zeros(0), (np.zeros((0, x.size)) if scales is not None else None)
    blocks = x[: n * pc].reshape(n, pc)
    widths = _widths(blocks, x[n * pc], layout)
    reach = np.maximum(blocks[:, 3], widths) / 2
    gap = np.hypot(blocks[:, None, 0] - blocks[None, :, 0], blocks[:, None, 1] - blocks[None, :, 1])
    near = np.argwhere(np.triu(gap < reach[:, None] + reach[None, :], 1))
    pairs = [(int(i), int(j)) for i, j in near if _pair(blocks, widths, int(i), int(j)) > 0]
    res = np.array([_pair(blocks, widths, i, j) for i, j in pairs])
    if scales is None:
        return res, None
    jac = np.zeros((len(pairs), x.size))
    for row, (i, j) in enumerate(pairs):
        for k in [*range(i * pc, (i + 1) * pc), *range(j * pc, (j + 1) * pc), n * pc]:
            h = step * scales[k]
            values = []
            for sign in (1.0, -1.0):
                xk = x.copy()
                xk[k] += sign * h
                bk = xk[: n * pc].reshape(n, pc)
                values.append(_pair(bk, _widths(bk, xk[n * pc], layout), i, j))
            jac[row, k] = (values[0] - values[1]) / (2 * step)
    return res, jac
