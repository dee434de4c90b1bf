"""Per-cell scaling of a scene's cell material (optical path or stain content)."""

from __future__ import annotations

import numpy as np

from napari_symbac.scene._draw import Scene

__all__ = ["scale_cells"]


def scale_cells(scene: Scene, ids: np.ndarray, gains: np.ndarray) -> Scene:
    """``scene`` with the material of cell ``ids[k]`` multiplied by ``gains[k]``.

    A pixel takes the gain of the cell its label names (the thickest cell there); a
    pixel of no listed cell keeps its material. The gain scales the cell's thickness
    and the medium fills the rest of the column: a gain ``g < 1`` gives the ``1 - g``
    share of the cell back to the medium, so a thinner cell fades towards the medium
    around it and never below it, and ``g > 1`` takes the extra share from the medium,
    so that eq. 3 adds ``g (I_c - I_m)`` either way (where a cell comes out thicker than
    the scene's depth the medium's share is negative: the shares are eq. 3's linear
    weights) and a transparent cell passes as much light as the medium. In phase
    contrast the gain scales the cell's optical path (eq. OPL2's thickness times the
    refractive-index step), in fluorescence its stain above the background.
    """
    ids = np.asarray(ids, np.int64)
    gains = np.asarray(gains, np.float64)
    if ids.shape != gains.shape:
        raise ValueError(f"one gain per cell id: {ids.size} ids, {gains.size} gains")
    if not np.all(np.isfinite(gains) & (gains >= 0)):
        raise ValueError("cell gains must be finite and non-negative")
    lut_ids = np.concatenate([[0], ids])
    lut_gain = np.concatenate([[1.0], gains]).astype(np.float32)
    order = np.argsort(lut_ids)
    lut_ids, lut_gain = lut_ids[order], lut_gain[order]
    labels = scene.labels.astype(np.int64)
    index = np.clip(np.searchsorted(lut_ids, labels), 0, lut_ids.size - 1)
    per_pixel = np.where(lut_ids[index] == labels, lut_gain[index], np.float32(1.0))
    per_pixel = per_pixel.astype(np.float32)
    cells = np.asarray(scene.cells, np.float32)
    media = np.asarray(scene.media, np.float32) + cells * (np.float32(1.0) - per_pixel)
    return scene.replace_cells(cells * per_pixel).replace_media(media)
