"""Dataset export at scale: training sets for segmentation and tracking networks.

>>> from napari_symbac.export import ExportSettings, export_dataset
>>> settings = ExportSettings(n_items=1000, formats=["omnipose", "stardist"], seed=1)
>>> report = export_dataset(settings, "dataset", workers=4)  # doctest: +SKIP

Formats (see ``docs/export.md`` for the layout of each and a snippet that loads it):
``tiff``, ``png``, ``delta``, ``omnipose``, ``stardist``, ``coco``, ``ctc``,
``trackmate``, ``ome-zarr``.

Every file is written atomically and each item's manifest entry last, so an export
that crashed or was cancelled resumes when run again; items depend only on the seed and
their index, so serial and parallel runs write identical files.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from napari_symbac.arguments import require_argument
from napari_symbac.export.atomic import ExportError
from napari_symbac.export.dataset import (
    ExportSettings,
    PipelineSource,
    Randomisation,
    Range,
    export_of,
    load_export_settings,
    regenerate,
    unit_rng,
)
from napari_symbac.export.formats import FORMATS, FormatWriter, get_writer
from napari_symbac.export.item import ExportItem, instance_dtype, semantic_from_labels
from napari_symbac.export.manifest import check_manifest
from napari_symbac.export.runner import (
    Cancel,
    ExportReport,
    ItemSource,
    Progress,
    check_out_dir,
    manifest_header,
    run_export,
    write_items,
)
from napari_symbac.export.visibility import Visibility, contrast_to_noise
from napari_symbac.settings import PipelineSettings

__all__ = [
    "FORMATS",
    "ExportError",
    "ExportItem",
    "ExportReport",
    "ExportSettings",
    "FormatWriter",
    "ItemSource",
    "PipelineSource",
    "Randomisation",
    "Range",
    "Visibility",
    "check_export_folder",
    "contrast_to_noise",
    "export_dataset",
    "export_of",
    "get_writer",
    "instance_dtype",
    "load_export_settings",
    "regenerate",
    "run_export",
    "semantic_from_labels",
    "series_items",
    "unit_rng",
    "write_items",
]


def export_dataset(
    settings: ExportSettings,
    out_dir: str | os.PathLike,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Progress | None = None,
    cancel: Cancel | None = None,
    backend: str = "scipy",
) -> ExportReport:
    """Simulate, render and write a dataset; resume it if ``out_dir`` holds a partial run.

    Parameters
    ----------
    settings
        What to export (items, formats, seed, split, parameter ranges, pipeline).
    out_dir
        Dataset folder (created if missing).
    workers
        Worker processes of a local dask cluster bound to 127.0.0.1; ``None`` is one
        per core and ``1`` runs serially in this process.
    scheduler
        Address of a running dask scheduler to use instead of a local cluster (its
        workers must see ``out_dir`` at the same path).
    progress
        ``progress(done, total)`` in images, after each finished unit.
    cancel
        Callable returning ``True``, or a :class:`threading.Event`, checked between
        units; re-running the export completes it.
    backend
        Render backend (:func:`~napari_symbac.optics.batched.resolve_backend`):
        ``"scipy"`` (default), ``"torch"`` (cuda when available, else cpu; the frames of
        a time series in device batches), ``"torch:cpu"``, ``"torch:cuda"`` or
        ``"cupy"``. A backend other than scipy is recorded in the manifest (its noise
        stream differs), and resuming with another one is refused.

    Returns
    -------
    ExportReport
        Items written and skipped, time, workers, whether it was cancelled.

    Raises
    ------
    ExportError
        The disk is full, a path cannot be written, or ``out_dir`` holds another export;
        the message names the path and the fix.
    TypeError
        If ``settings`` is not :class:`ExportSettings` (the fix for a pipeline's
        settings: :func:`export_of`).
    """
    if isinstance(settings, PipelineSettings):  # found as an API user: an AttributeError
        raise TypeError(
            "export_dataset(settings=...) needs ExportSettings, got PipelineSettings: pass "
            "export_of(pipeline) (its default export; export_of(pipeline, n_items=...) sets "
            "more)"
        )
    require_argument(settings, ExportSettings, "export_dataset(settings=...)")
    return run_export(
        PipelineSource(settings, backend),
        out_dir,
        settings.formats,
        options={"coco_segmentation": settings.coco_segmentation},
        workers=workers,
        scheduler=scheduler,
        progress=progress,
        cancel=cancel,
    )


def check_export_folder(
    settings: ExportSettings,
    out_dir: str | os.PathLike,
    backend: str = "scipy",
    *,
    in_dock: bool = False,
) -> None:
    """Refuse, before any work and writing nothing, a folder :func:`export_dataset`
    would refuse: a file, a folder of other files, or one holding another export (made
    with other settings, another backend or another version). The folder of the same
    export (a resume) passes. ``in_dock``: the fixes in the Export dock's words.

    Raises
    ------
    ExportError
        Naming the folder, what differs and the fix.
    ValueError
        If ``backend`` is unknown or cannot render ``settings``.
    """
    check_manifest(
        check_out_dir(out_dir),
        manifest_header(PipelineSource(settings, backend), settings.formats),
        in_dock=in_dock,
    )


def series_items(
    images: np.ndarray,
    labels: np.ndarray,
    semantic: np.ndarray | None = None,
    *,
    lineage: dict[int, Any] | None = None,
    series: int = 0,
    split: str = "train",
    pixel_size_um: float = 1.0,
    frame_interval_min: float = 1.0,
    params: dict[str, Any] | None = None,
) -> list[ExportItem]:
    """Items for each frame of a rendered ``(T, Y, X)`` time series (e.g. the demo's).

    Parameters
    ----------
    images, labels, semantic
        ``(T, Y, X)`` stacks, e.g. the fields of :class:`napari_symbac.pipeline.RenderedSeries`.
    lineage
        ``Simulation.lineage`` (cell id -> record with ``parent_id``), for the tracking
        formats.
    series, split
        Series number and split of every item.
    pixel_size_um, frame_interval_min
        Calibration recorded in OME-Zarr and TrackMate files.
    params
        Recorded in each item's manifest entry.
    """
    images = np.asarray(images)
    labels = np.asarray(labels)
    if images.ndim != 3 or labels.shape != images.shape:
        raise ValueError(
            f"series_items expects (T, Y, X) stacks, got {images.shape}, {labels.shape}"
        )
    parents = {int(c): int(r.parent_id) for c, r in (lineage or {}).items()}
    n_frames = images.shape[0]
    max_label = max(max(parents, default=0), int(labels.max()) if labels.size else 0)
    width = max(4, len(str(n_frames - 1)))
    items = []
    for t in range(n_frames):
        present = np.unique(labels[t])
        items.append(
            ExportItem(
                name=f"s{series:04d}_t{t:0{width}d}",
                index=series * n_frames + t,
                image=images[t],
                labels=labels[t],
                semantic=None if semantic is None else semantic[t],
                split=split,  # type: ignore[arg-type]
                series=series,
                frame=t,
                n_frames=n_frames,
                parents={int(c): parents.get(int(c), 0) for c in present if c},
                max_label=max_label,
                pixel_size_um=pixel_size_um,
                frame_interval_min=frame_interval_min,
                params=dict(params or {}),
            )
        )
    return items
