"""Dock widget: export a randomised training dataset with a progress bar and cancel.

Headless equivalent: :func:`napari_symbac.export.export_dataset` (and the
``napari-symbac export`` command).
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

from magicgui.widgets import (
    ComboBox,
    Container,
    FileEdit,
    FloatSpinBox,
    Label,
    PushButton,
    Select,
    SpinBox,
)

from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY
from napari_symbac.export import FORMATS, ExportSettings
from napari_symbac.settings import PipelineSettings

if TYPE_CHECKING:
    import napari

__all__ = ["ExportWidget"]


class ExportWidget(Container):
    """Choose formats, number of items and a folder; export in the background.

    The optics come from the chosen rendered layer (as tuned with *Tune optics and
    noise*), or the defaults. The settings are saved with the dataset (its manifest),
    and a cancelled export resumes when run again into the same folder.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(name="symbac_export")
        self.viewer = viewer
        self.source = ComboBox(
            name="source", label="settings from", choices=self._rendered, nullable=True
        )
        self.formats = Select(
            name="formats", label="formats", choices=list(FORMATS), value=["tiff"]
        )
        self.kind = ComboBox(name="kind", label="items", choices=["frames", "timeseries"])
        self.n_items = SpinBox(name="n_items", label="number of items", value=100, min=1, max=10**7)
        self.seed = SpinBox(name="seed", label="seed", value=0, min=0, max=2**31 - 1)
        self.val_fraction = FloatSpinBox(
            name="val_fraction", label="validation fraction", value=0.1, min=0, max=0.9, step=0.05
        )
        self.workers = SpinBox(name="workers", label="worker processes", value=1, min=1, max=256)
        self.folder = FileEdit(name="folder", label="output folder", mode="d")
        self.export_button = PushButton(name="export", text="Export")
        self.cancel_button = PushButton(name="cancel", text="Cancel", enabled=False)
        self.status = Label(name="status", value="")
        self.extend(
            [
                self.source,
                self.formats,
                self.kind,
                self.n_items,
                self.seed,
                self.val_fraction,
                self.workers,
                self.folder,
                self.export_button,
                self.cancel_button,
                self.status,
            ]
        )
        self.export_button.changed.connect(self.export)
        self.cancel_button.changed.connect(self.cancel)
        for event in (viewer.layers.events.inserted, viewer.layers.events.removed):
            event.connect(lambda _e=None: self.source.reset_choices())
        self.worker = None
        self.report = None
        self._cancel = threading.Event()
        self._progress = None

    def _rendered(self, _widget=None) -> list:
        return [
            layer
            for layer in self.viewer.layers
            if SYMBAC_METADATA_KEY in layer.metadata and not hasattr(layer, "selected_label")
        ]

    def settings(self) -> ExportSettings:
        """The export settings in the form (validated)."""
        layer = self.source.value
        pipeline = (
            layer.metadata[SYMBAC_METADATA_KEY]["settings"]
            if layer is not None
            else PipelineSettings()
        )
        return ExportSettings(
            n_items=self.n_items.value,
            kind=self.kind.value,
            formats=list(self.formats.value),
            seed=self.seed.value,
            val_fraction=self.val_fraction.value,
            pipeline=dataclasses.replace(
                pipeline,
                simulation=dataclasses.replace(pipeline.simulation, seed=self.seed.value),
            ),
        )

    def export(self) -> None:
        """Validate the form and run the export in a worker thread."""
        from napari.qt.threading import thread_worker
        from napari.utils import progress

        from napari_symbac.export import export_dataset

        folder = Path(self.folder.value) if str(self.folder.value) not in ("", ".") else None
        if folder is None:
            self.status.value = "Choose an output folder"
            return
        try:
            settings = self.settings()
        except ValueError as err:
            self.status.value = f"Invalid settings: {err}"
            return
        workers = self.workers.value
        self._cancel = threading.Event()
        cancel = self._cancel

        @thread_worker
        def work():
            updates: queue.Queue = queue.Queue()
            with ThreadPoolExecutor(1) as pool:
                future = pool.submit(
                    export_dataset,
                    settings,
                    folder,
                    workers=workers,
                    progress=lambda done, total: updates.put((done, total)),
                    cancel=cancel,
                )
                while not future.done() or not updates.empty():
                    try:
                        yield updates.get(timeout=0.05)
                    except queue.Empty:
                        continue
                return future.result()

        self._progress = progress(total=settings.n_images, desc="SyMBac export")
        self.worker = work()
        self.worker.yielded.connect(self._on_progress)
        self.worker.returned.connect(self._on_returned)
        self.worker.errored.connect(self._on_errored)
        self.worker.finished.connect(self._on_finished)
        self.export_button.enabled = False
        self.cancel_button.enabled = True
        self.status.value = f"Exporting {settings.n_images} images to {folder}..."
        self.worker.start()

    def cancel(self) -> None:
        """Stop after the items in progress; running the export again completes it."""
        self._cancel.set()
        self.status.value = "Cancelling after the items in progress..."

    def _on_progress(self, update) -> None:
        done, total = update
        if self._progress is not None:
            self._progress.total = total
            self._progress.n = done
            self._progress.refresh()
        self.status.value = f"Exported {done} of {total} images"

    def _on_returned(self, report) -> None:
        self.report = report
        self.status.value = str(report)

    def _on_errored(self, err: Exception) -> None:
        self.status.value = f"Export failed: {err}"

    def _on_finished(self) -> None:
        if self._progress is not None:
            self._progress.close()
            self._progress = None
        self.worker = None
        self.export_button.enabled = True
        self.cancel_button.enabled = False
