"""Which cells an image shows: per-cell contrast-to-noise, and what to do with faint cells.

A mask must not hold cells that the image does not show: a segmenter trained on such
pairs learns to invent cells in empty background. With per-cell brightness variation
(``RenderSettings.cell_brightness_cv``) some cells come out as bright as the medium
around them and vanish in the noise.

The rule (:func:`contrast_to_noise`), measured on the rendered camera image:

* contrast of cell ``k`` = ``|median(image in k) - median(image in its ring)|``, the ring
  being the pixels within ``ring_px`` of the cell that are growth medium (not another
  cell, not a device wall: a cell is seen against the medium it sits in);
* noise = the pixel noise of the background, ``1.4826 * MAD(d) / sqrt(2)`` of the
  differences ``d`` between horizontally adjacent background pixels (robust to the slow
  changes of the halo and the illumination, which a difference cancels);
* ``CNR_k = contrast_k / noise``.

A cell with ``CNR_k < min_contrast_to_noise`` is *faint*. :class:`Visibility` says what
happens to it: ``"flag"`` (default) keeps the masks and lists the faint cells and every
cell's CNR in the manifest; ``"drop"`` removes faint cells from the masks (independent
images only: in a time series a cell that fades for a frame would break its track);
``"keep"`` measures nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage

__all__ = ["Visibility", "camera_medium", "contrast_to_noise", "faint_cells", "pixel_noise"]

Action = Literal["flag", "drop", "keep"]


@dataclass(frozen=True)
class Visibility:
    """What a dataset does with cells the image barely shows (module notes).

    Parameters
    ----------
    min_contrast_to_noise
        Cells whose contrast to their surroundings is below this many pixel-noise
        standard deviations are faint.
    action
        ``"flag"``: list faint cells in the manifest (``faint_cells`` and
        ``contrast_to_noise`` of each item), masks unchanged; ``"drop"``: remove them
        from the masks (``kind="frames"`` only); ``"keep"``: do not measure.
    ring_px
        Width of the background ring around each cell the contrast is measured against.
    """

    min_contrast_to_noise: float = 1.0
    action: Action = "flag"
    ring_px: int = 3

    def __post_init__(self) -> None:
        value = self.min_contrast_to_noise
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value >= 0
        ):
            raise ValueError(
                f"Visibility.min_contrast_to_noise must be a number >= 0, got {value!r}"
            )
        if self.action not in ("flag", "drop", "keep"):
            raise ValueError(
                f"Visibility.action must be 'flag', 'drop' or 'keep', got {self.action!r}"
            )
        if isinstance(self.ring_px, bool) or not isinstance(self.ring_px, int) or self.ring_px < 1:
            raise ValueError(f"Visibility.ring_px must be an integer >= 1, got {self.ring_px!r}")


#: Pixel noise (ADU s.d.) below which :func:`pixel_noise` stops trusting the MAD.
FEW_GREY_LEVELS = 2.0


def pixel_noise(image: np.ndarray, background: np.ndarray) -> float:
    """Robust standard deviation of the pixel noise over ``background`` pixels.

    ``1.4826 * MAD / sqrt(2)`` of the differences between horizontally adjacent pixels
    that are both background; ``nan`` if there are fewer than 10 such pairs. When that
    is within :data:`FEW_GREY_LEVELS` of 0, the noise is a grey level or two of an
    integer image (an 8-bit recording's camera): most neighbours are equal, the MAD
    moves in steps of 1 ADU (0 for noise of 0.45 ADU, which made every cell "visible"),
    and the rms of the differences within that many grey levels measures it instead.
    """
    image = np.asarray(image, dtype=np.float64)
    pairs = background[:, 1:] & background[:, :-1]
    d = (image[:, 1:] - image[:, :-1])[pairs]
    if d.size < 10:
        return math.nan
    d = d - np.median(d)
    robust = float(1.4826 * np.median(np.abs(d)) / math.sqrt(2))
    if robust >= FEW_GREY_LEVELS:
        return robust
    near = d[np.abs(d) <= 2 * FEW_GREY_LEVELS]  # not the halo's or the cells' edges
    return float(np.sqrt(np.mean(near**2) / 2))


def camera_medium(scene) -> np.ndarray:
    """Camera pixels that are mostly growth medium in a :class:`~napari_symbac.scene.Scene`."""
    u = int(scene.upsample)
    height, width = scene.camera_shape
    media = np.asarray(scene.interior(scene.media), dtype=np.float64)[: height * u, : width * u]
    return media.reshape(height, u, width, u).mean(axis=(1, 3)) > 0.5


def contrast_to_noise(
    image: np.ndarray,
    labels: np.ndarray,
    ring_px: int = 3,
    medium: np.ndarray | None = None,
) -> dict[int, float]:
    """Contrast-to-noise ratio of every cell of ``labels`` in ``image`` (module notes).

    Parameters
    ----------
    image, labels
        Camera image and its instance mask.
    ring_px
        Width of the ring of surroundings each cell is compared with.
    medium
        Optional mask of the pixels that are growth medium (not device walls): the
        ring and the noise estimate then use medium pixels only, so a cell is compared
        with the medium it sits in, not with a dark trench wall. A cell with no medium
        around it is compared with all non-cell pixels of its ring.

    Returns
    -------
    dict
        Cell id -> CNR (``inf`` for a noise-free image, ``nan`` for a cell with no
        background around it).
    """
    image = np.asarray(image, dtype=np.float64)
    labels = np.asarray(labels)
    cells = labels > 0
    background = ~ndimage.binary_dilation(cells, iterations=1)
    if medium is not None:
        medium = np.asarray(medium, dtype=bool)
        if medium.shape != labels.shape:
            raise ValueError(f"medium mask {medium.shape} and labels {labels.shape} differ")
        noise = pixel_noise(image, background & medium)
        if not math.isfinite(noise):
            noise = pixel_noise(image, background)
    else:
        noise = pixel_noise(image, background)
    ring_shape = ndimage.generate_binary_structure(2, 1)
    result: dict[int, float] = {}
    for index, box in enumerate(ndimage.find_objects(labels.astype(np.int64)), start=1):
        if box is None:
            continue
        rows = slice(max(box[0].start - ring_px, 0), box[0].stop + ring_px)
        cols = slice(max(box[1].start - ring_px, 0), box[1].stop + ring_px)
        cell = labels[rows, cols] == index
        ring = ndimage.binary_dilation(cell, ring_shape, iterations=ring_px) & ~cells[rows, cols]
        if medium is not None and (ring & medium[rows, cols]).any():
            ring &= medium[rows, cols]
        if not ring.any():
            result[index] = math.nan
            continue
        patch = image[rows, cols]
        contrast = abs(float(np.median(patch[cell])) - float(np.median(patch[ring])))
        result[index] = contrast / noise if noise > 0 else math.inf
    return result


def faint_cells(cnr: dict[int, float], min_contrast_to_noise: float) -> list[int]:
    """Ids of the cells whose CNR is below the threshold (``nan`` counts as faint)."""
    return sorted(c for c, v in cnr.items() if not v >= min_contrast_to_noise)
