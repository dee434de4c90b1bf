"""Which cells touch: the gaps between capsules.

A cell is a capsule: the segment ``centre +- half`` (its axis, ``half`` the vector
from the centre to a cap's centre) dilated by half its width. The gap between two
cells is the distance between their axes minus the two half-widths.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["axis_distance", "capsule_axes", "neighbour_gaps"]


def capsule_axes(angle_rad: np.ndarray, length_um: np.ndarray, width_um: np.ndarray) -> np.ndarray:
    """``(n, 2)`` vectors from each centre to one cap's centre (``angle_rad`` from +y,
    as in :class:`~napari_symbac.sim.cells.FrameCells`)."""
    half = np.maximum(length_um - width_um, 0.0) / 2
    return np.c_[np.sin(angle_rad), np.cos(angle_rad)] * half[:, None]


def neighbour_gaps(
    pos_um: np.ndarray, axes_um: np.ndarray, width_um: np.ndarray, within_um: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(k, 2)`` of cells whose capsules may be closer than ``within_um`` and
    their gaps ``(k,)`` (negative: overlap)."""
    if len(pos_um) < 2:
        return np.empty((0, 2), dtype=np.intp), np.empty(0)
    reach = float(np.hypot(axes_um[:, 0], axes_um[:, 1]).max() + width_um.max() / 2)
    pairs = cKDTree(pos_um).query_pairs(2 * reach + within_um, p=np.inf, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    gap = axis_distance(pos_um[i], axes_um[i], pos_um[j], axes_um[j])
    return pairs, gap - (width_um[i] + width_um[j]) / 2


def axis_distance(
    centre_a: np.ndarray, half_a: np.ndarray, centre_b: np.ndarray, half_b: np.ndarray
) -> np.ndarray:
    """Distance between the segments ``centre +- half`` of each row (the capsules'
    axes): the closest points of two segments, clamped to both (Ericson,
    *Real-Time Collision Detection*, 5.1.9)."""
    p, q = centre_a - half_a, centre_b - half_b
    d1, d2, r = 2 * half_a, 2 * half_b, p - q
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    tiny = 1e-12
    a_ = np.where(a > tiny, a, 1.0)
    e_ = np.where(e > tiny, e, 1.0)
    denom = a * e - b * b
    skew = denom > tiny * a_ * e_  # not parallel: else any s, take 0
    s = np.where(skew, np.clip((b * f - c * e) / np.where(skew, denom, 1.0), 0, 1), 0.0)
    t = (b * s + f) / e_
    s = np.where(t < 0, np.clip(-c / a_, 0, 1), np.where(t > 1, np.clip((b - c) / a_, 0, 1), s))
    t = np.clip(t, 0, 1)
    point_b = e <= tiny  # b is a point (a round cell)
    s = np.where(point_b, np.clip(-c / a_, 0, 1), s)
    t = np.where(point_b, 0.0, t)
    point_a = a <= tiny
    t = np.where(point_a, np.where(point_b, 0.0, np.clip(f / e_, 0, 1)), t)
    s = np.where(point_a, 0.0, s)
    gap = p + d1 * s[:, None] - (q + d2 * t[:, None])
    return np.hypot(gap[:, 0], gap[:, 1])
