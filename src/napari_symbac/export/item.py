"""One exported sample: an image, its ground truth and how it was made."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

__all__ = [
    "ExportItem",
    "instance_dtype",
    "item_objects",
    "semantic_from_labels",
]

Split = Literal["train", "val"]

#: A float image spanning fewer counts than this, not in whole numbers, is refused: its
#: values are no camera's counts (a normalised image), and rounding would flatten it.
MIN_FLOAT_SPAN_COUNTS = 16


def instance_dtype(max_label: int) -> np.dtype:
    """The narrowest unsigned type, uint16 or wider, that holds ``max_label`` without wrapping."""
    if max_label < 0:
        raise ValueError(f"instance labels are non-negative, got a maximum of {max_label}")
    if max_label <= np.iinfo(np.uint16).max:
        return np.dtype(np.uint16)
    if max_label <= np.iinfo(np.uint32).max:
        return np.dtype(np.uint32)
    return np.dtype(np.uint64)


def semantic_from_labels(labels: np.ndarray) -> np.ndarray:
    """A uint8 mask, 1 in cells, with a zero-valued pixel wherever two cells touch.

    Used when an item brings no semantic mask of its own (DeLTA expects cells separated by
    background). Scenes from :mod:`napari_symbac.scene` provide their own (eq. 4-5).
    """
    labels = np.asarray(labels)
    padded = np.pad(labels, 1, mode="constant")
    centre = padded[1:-1, 1:-1]
    touching = np.zeros(labels.shape, dtype=bool)
    # zero the pixel of the higher label wherever two cells meet (4-connectivity): one
    # pixel of background then separates every pair of touching cells
    for dy, dx in ((0, 1), (1, 0), (1, 2), (2, 1)):
        neighbour = padded[dy : dy + labels.shape[0], dx : dx + labels.shape[1]]
        touching |= (neighbour > 0) & (centre > neighbour)
    return ((labels > 0) & ~touching).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class ExportItem:
    """One sample of a dataset at camera resolution.

    Parameters
    ----------
    name
        File stem, unique in the dataset (``"000042"``, ``"s0003_t0012"``).
    index
        Unique non-negative number of the item in the dataset (the COCO image id - 1).
    image
        ``(Y, X)`` camera image, uint16.
    labels
        ``(Y, X)`` instance mask; a value is the cell id (0 is background). Stored as
        uint16, or uint32 when a label exceeds 65535 (never wrapped).
    semantic
        ``(Y, X)`` uint8 mask, 1 in cells, cells separated by zero pixels; derived from
        ``labels`` with :func:`semantic_from_labels` when not given.
    split
        ``"train"`` or ``"val"``.
    series, frame, n_frames
        For time series: which series (>= 0), which frame of it and how many frames it
        has. ``None`` for independent images.
    sequence
        For time series: the number (>= 0) of the series among the series of its
        split, so each split's CTC sequences are ``01, 02, ...``; defaults to
        ``series``.
    parents
        Parent cell id of each cell id (0 = no parent) for the tracking formats; ids not
        listed have no parent.
    max_label
        Largest cell id of the whole series (fixes one mask dtype for every frame of a
        time series); defaults to ``labels.max()``.
    pixel_size_um, frame_interval_min
        Physical calibration written to OME-Zarr and TrackMate files.
    params
        Parameters drawn for this item (recorded in the manifest so it can be regenerated).
    contrast_to_noise, faint_cells
        Per-cell contrast-to-noise ratio and the cells below the dataset's visibility
        threshold (:mod:`napari_symbac.export.visibility`), recorded in the manifest;
        empty when not measured.
    """

    name: str
    index: int
    image: np.ndarray
    labels: np.ndarray
    semantic: np.ndarray | None = None
    split: Split = "train"
    series: int | None = None
    frame: int | None = None
    n_frames: int | None = None
    parents: Mapping[int, int] = field(default_factory=dict)
    max_label: int | None = None
    pixel_size_um: float = 1.0
    frame_interval_min: float = 1.0
    params: Mapping[str, Any] = field(default_factory=dict)
    sequence: int | None = None
    contrast_to_noise: Mapping[int, float] = field(default_factory=dict)
    faint_cells: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if not self.name or any(c in self.name for c in "/\\:") or self.name.startswith("."):
            raise ValueError(f"ExportItem.name {self.name!r} must be a plain file stem")
        if not isinstance(self.index, (int, np.integer)) or self.index < 0:
            raise ValueError(f"ExportItem.index must be a non-negative integer, got {self.index!r}")
        image = np.asarray(self.image)
        labels = np.asarray(self.labels)
        if image.ndim != 2 or labels.shape != image.shape:
            raise ValueError(
                f"ExportItem {self.name}: image {image.shape} and labels {labels.shape} must "
                "be 2-D arrays of the same shape"
            )
        if not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(f"ExportItem {self.name}: labels must be integers, got {labels.dtype}")
        if labels.size and labels.min() < 0:
            raise ValueError(f"ExportItem {self.name}: labels must be non-negative")
        if self.split not in ("train", "val"):
            raise ValueError(f"ExportItem.split must be 'train' or 'val', got {self.split!r}")
        if (self.series is None) != (self.frame is None):
            raise ValueError(f"ExportItem {self.name}: give both series and frame, or neither")
        if self.sequence is None:
            object.__setattr__(self, "sequence", self.series)
        elif self.series is None or self.sequence < 0:
            raise ValueError(
                f"ExportItem {self.name}: sequence is the non-negative number of a time "
                f"series in its split, got {self.sequence!r} (series={self.series!r})"
            )
        semantic = semantic_from_labels(labels) if self.semantic is None else self.semantic
        semantic = np.asarray(semantic)
        if semantic.shape != image.shape:
            raise ValueError(f"ExportItem {self.name}: semantic mask shape {semantic.shape}")
        object.__setattr__(self, "image", image)
        self.image_uint16()  # refused now, not by a worker mid-export
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "semantic", (semantic > 0).astype(np.uint8))
        top = int(labels.max()) if labels.size else 0
        if self.max_label is not None and self.max_label < top:
            raise ValueError(f"ExportItem {self.name}: max_label {self.max_label} < labels.max()")
        object.__setattr__(
            self, "max_label", top if self.max_label is None else int(self.max_label)
        )

    @property
    def is_timeseries(self) -> bool:
        """Whether the item is a frame of a time series."""
        return self.series is not None

    @property
    def label_dtype(self) -> np.dtype:
        """uint16, or uint32 when the series has a cell id above 65535."""
        return instance_dtype(self.max_label)

    def instance_mask(self) -> np.ndarray:
        """``labels`` in :attr:`label_dtype` (checked, never wrapped)."""
        return self.labels.astype(self.label_dtype, copy=False)

    def image_uint16(self) -> np.ndarray:
        """``image`` as uint16, refusing values that would be clipped or wrapped, and a
        float image that rounding to counts would flatten (spanning fewer than
        :data:`MIN_FLOAT_SPAN_COUNTS` counts, not whole numbers)."""
        image = self.image
        if image.dtype == np.uint16:
            return image
        if np.issubdtype(image.dtype, np.integer) and image.size:
            if image.min() < 0 or image.max() > 65535:
                raise ValueError(f"ExportItem {self.name}: image values outside uint16")
            return image.astype(np.uint16)
        if image.size and (
            not np.all(np.isfinite(image)) or image.min() < 0 or image.max() > 65535
        ):
            raise ValueError(f"ExportItem {self.name}: image values outside uint16")
        rounded = np.rint(image)
        if (
            image.size
            and float(rounded.max() - rounded.min()) < MIN_FLOAT_SPAN_COUNTS
            and not np.array_equal(rounded, image)
        ):  # found as a user: an image normalised to 0..1 was written as 0s and 1s
            raise ValueError(
                f"ExportItem {self.name}: a {image.dtype} image of values "
                f"{float(image.min()):.3g}..{float(image.max()):.3g} would be written as whole "
                f"counts {int(rounded.min())}..{int(rounded.max())} (the formats store uint16 "
                "counts): scale it to counts first (a normalised image: e.g. image * 65535), "
                "or give an integer image"
            )
        return rounded.astype(np.uint16)


def item_objects(item: ExportItem) -> list[list[float]]:
    """Per-cell summary ``[id, parent_id, centroid_y_px, centroid_x_px, area_px]``.

    Stored in the manifest entry of each item; the tracking formats are assembled from
    these at the end of an export, without reading the masks back.
    """
    labels = item.labels
    ids, inverse, counts = np.unique(labels.ravel(), return_inverse=True, return_counts=True)
    ys, xs = np.indices(labels.shape)
    sum_y = np.bincount(inverse, weights=ys.ravel(), minlength=ids.size)
    sum_x = np.bincount(inverse, weights=xs.ravel(), minlength=ids.size)
    rows = []
    for k, cell in enumerate(ids):
        if cell == 0:
            continue
        rows.append(
            [
                int(cell),
                int(item.parents.get(int(cell), 0)),
                round(float(sum_y[k] / counts[k]), 4),
                round(float(sum_x[k] / counts[k]), 4),
                int(counts[k]),
            ]
        )
    return rows
