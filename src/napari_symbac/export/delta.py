"""DeLTA 2.x training sets: segmentation with weight maps, and tracking for time series."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from napari_symbac.export.atomic import write_png
from napari_symbac.export.item import ExportItem
from napari_symbac.export.weights import segmentation_weights, to_weight_png, tracking_weights
from napari_symbac.export.writer import FormatWriter, relative

__all__ = ["DeltaWriter"]


class DeltaWriter(FormatWriter):
    """DeLTA 2.x training sets, segmentation and (for time series) tracking.

    Segmentation, as ``delta.data.trainGenerator_seg(batch, img, seg, wei, ...)`` reads
    it: ``delta/{split}/{img,seg,wei}/{name}.png`` with ``img`` the 16-bit image, ``seg``
    an 8-bit mask (255 in cells, touching cells separated by background) and ``wei`` the
    U-Net border weight map (:func:`~napari_symbac.export.weights.segmentation_weights`,
    16-bit, ``100 * w``).

    Tracking, for every frame ``t >= 1`` of a time series and every cell ``c`` of frame
    ``t - 1``, as ``delta.data.trainGenerator_track(batch, img, seg, previmg, segall,
    mot_dau, wei, ...)`` reads it: ``delta/{split}/tracking/{img,seg,previmg,segall,
    mot_dau,wei}/{name}_cell{c}.png`` with ``img`` frame ``t``, ``previmg`` frame
    ``t - 1``, ``seg`` the seed (cell ``c`` in frame ``t - 1``), ``segall`` every cell
    of frame ``t``, ``mot_dau`` cell ``c`` and the daughters it divided into in frame
    ``t`` (empty if it left the trench) and ``wei`` the tracking weight map
    (:func:`~napari_symbac.export.weights.tracking_weights`).
    """

    name = "delta"

    def __init__(self) -> None:
        self._previous: ExportItem | None = None

    def remember(self, item: ExportItem) -> None:
        self._previous = item

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name / item.split
        paths = [base / d / f"{item.name}.png" for d in ("img", "seg", "wei")]
        write_png(paths[0], item.image_uint16())
        write_png(paths[1], (item.semantic * 255).astype(np.uint8))
        write_png(paths[2], to_weight_png(segmentation_weights(item.labels * item.semantic)))
        paths += self._write_tracking(base / "tracking", item)
        return [relative(out_dir, p) for p in paths]

    def _write_tracking(self, base: Path, item: ExportItem) -> list[Path]:
        previous = self._previous
        if not (
            item.is_timeseries
            and item.frame
            and previous is not None
            and previous.series == item.series
            and previous.frame == item.frame - 1
        ):
            return []
        separated = item.labels * item.semantic
        daughters: dict[int, list[int]] = defaultdict(list)
        before = set(np.unique(previous.labels).tolist())
        for cell in np.unique(item.labels):
            parent = int(item.parents.get(int(cell), 0))
            if cell and int(cell) not in before and parent:
                daughters[parent].append(int(cell))
        width = max(6, len(str(item.max_label)))
        all_cells = (item.semantic * 255).astype(np.uint8)
        image, previous_image = item.image_uint16(), previous.image_uint16()
        paths = []
        for cell in np.unique(previous.labels):
            if not cell:
                continue
            track = np.isin(separated, [int(cell), *daughters.get(int(cell), [])])
            name = f"{item.name}_cell{int(cell):0{width}d}.png"
            files = {
                "img": image,
                "seg": ((previous.labels == cell) * 255).astype(np.uint8),
                "previmg": previous_image,
                "segall": all_cells,
                "mot_dau": (track * 255).astype(np.uint8),
                "wei": to_weight_png(tracking_weights(track, separated > 0)),
            }
            for folder, array in files.items():
                paths.append(base / folder / name)
                write_png(paths[-1], array)
        return paths
