"""Kymographs of a trench time series (supplement Fig. S2.1, S11)."""

from __future__ import annotations

import numpy as np

__all__ = ["kymograph"]


def kymograph(images: np.ndarray, gap_px: int = 0, fill: float = 0) -> np.ndarray:
    """Tile the frames of one trench side by side, time running left to right.

    Parameters
    ----------
    images
        ``(T, Y, X)`` stack (images or label masks) of one trench.
    gap_px
        Columns of ``fill`` between consecutive frames.
    fill
        Value of the gap columns.

    Returns
    -------
    numpy.ndarray
        ``(Y, T * X + (T - 1) * gap_px)`` array of the input's dtype; frame ``t``
        occupies columns ``t * (X + gap_px)`` to ``t * (X + gap_px) + X``.
    """
    images = np.asarray(images)
    if images.ndim != 3:
        raise ValueError(f"kymograph expects a (T, Y, X) stack, got shape {images.shape}")
    if not isinstance(gap_px, (int, np.integer)) or gap_px < 0:
        raise ValueError(f"gap_px must be a non-negative integer, got {gap_px!r}")
    t, y, x = images.shape
    out = np.full((y, t * x + max(t - 1, 0) * gap_px), fill, dtype=images.dtype)
    for k in range(t):
        start = k * (x + gap_px)
        out[:, start : start + x] = images[k]
    return out
