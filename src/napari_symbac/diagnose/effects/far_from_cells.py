"""The pixels far from every cell, grouped into bins, for the effects' own checks.

An effect of the camera or of the light acts on every pixel of the field, not only on
the cells, so its fit must also explain the residual where no cell is: the pixels at
least :data:`FAR_FROM_CELLS_PX` from any cell edge (``Geometry.distance_px``), where the
cells' misfit does not reach. ``fixed_pattern_noise`` judges its column offsets by the
column means of those pixels, ``uneven_illumination`` its surface by their means over
tiles of the field (:meth:`~napari_symbac.diagnose.effects.base.Effect.confirm`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from napari_symbac.diagnose.model import Geometry

__all__ = ["FAR_FROM_CELLS_PX", "MIN_FAR_PIXELS", "FarBins", "far_bins"]

#: Pixels at least this far from every cell edge (px) see no cell.
FAR_FROM_CELLS_PX = 8.0
#: Far pixels (all frames together) a bin needs for its mean to judge an effect there.
MIN_FAR_PIXELS = 8


@dataclass(frozen=True, eq=False)
class FarBins:
    """The far-from-cells pixels of a ``(T, Y, X)`` stack, grouped into bins.

    Attributes
    ----------
    far
        ``(T, Y, X)``: the valid pixels :data:`FAR_FROM_CELLS_PX` or more from any cell.
    index
        The bin of each far pixel (in the order of ``values[far]``).
    judged
        ``(n_bins,)``: the bins with :data:`MIN_FAR_PIXELS` or more far pixels.
    counts
        Far pixels of each judged bin.
    """

    far: np.ndarray
    index: np.ndarray
    judged: np.ndarray
    counts: np.ndarray

    @property
    def n_bins(self) -> int:
        return len(self.judged)

    def means(self, values: np.ndarray) -> np.ndarray:
        """The mean of ``values`` (broadcast to ``(T, Y, X)``) over the far pixels of
        each judged bin."""
        v = np.broadcast_to(values, self.far.shape)[self.far]
        return np.bincount(self.index, v, self.n_bins)[self.judged] / self.counts

    def variances_of_means(self, values: np.ndarray) -> np.ndarray:
        """The variance of each judged bin's mean of ``values``: the scatter of its far
        pixels over their number (pixels taken as independent)."""
        mean = self.means(values)
        square = self.means(np.square(values))
        return np.maximum(square - mean**2, 0.0) / self.counts


def far_bins(geometry: Geometry, valid: np.ndarray, bins: np.ndarray, n_bins: int) -> FarBins:
    """:class:`FarBins` of the pixels in ``valid`` far from every cell of ``geometry``.

    Parameters
    ----------
    bins
        ``(Y, X)`` bin of each pixel, ``0 .. n_bins - 1`` (the same in every frame).
    """
    far = valid & (geometry.distance_px >= FAR_FROM_CELLS_PX)
    index = np.broadcast_to(bins, far.shape)[far]
    counts = np.bincount(index, minlength=n_bins)
    judged = counts >= MIN_FAR_PIXELS
    return FarBins(far, index, judged, counts[judged])
