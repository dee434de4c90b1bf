"""The writer protocol every dataset format implements.

A writer has two methods:

``write_item(out_dir, item) -> list[str]``
    Write the files of one :class:`~napari_symbac.export.item.ExportItem` (image first,
    then its masks, each atomically) and return their paths relative to ``out_dir``.
``finalize(out_dir, records) -> list[str]``
    Write dataset-level files (COCO JSON, ``man_track.txt``, TrackMate XML) from the
    manifest entries of all finished items, without reading the masks back.

and may keep the previous item of a time series with ``remember(item)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

from napari_symbac.export.item import ExportItem

__all__ = ["FormatWriter", "Record", "relative"]

Record = Mapping[str, Any]


class FormatWriter:
    """Base class of the writers; subclasses set :attr:`name` and override the methods."""

    #: Registry key and folder name.
    name: ClassVar[str] = ""
    #: Whether the format only makes sense for time series (tracking formats).
    timeseries_only: ClassVar[bool] = False

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        """Write one item's files; return their paths relative to ``out_dir``."""
        raise NotImplementedError

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        """Write dataset-level files from the manifest entries of all items."""
        return []

    def remember(self, item: ExportItem) -> None:
        """Called with every item of a unit in order, written or not (resumed runs).

        Writers whose items depend on the previous frame (DeLTA tracking) keep it.
        """

    def _check(self, item: ExportItem) -> None:
        if self.timeseries_only and not item.is_timeseries:
            raise ValueError(
                f"the {self.name!r} format holds time series (tracking ground truth); item "
                f"{item.name} is a single image: export with kind='timeseries'"
            )


def relative(out_dir: Path, path: Path) -> str:
    return path.relative_to(out_dir).as_posix()
