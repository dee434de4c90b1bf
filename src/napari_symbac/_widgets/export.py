"""Dock widget: export a randomised training dataset with a progress bar and cancel.

Headless equivalent: :func:`napari_symbac.export.export_dataset` (and the
``napari-symbac export`` command).
"""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from magicgui.widgets import (
    ComboBox,
    Container,
    FileEdit,
    FloatSpinBox,
    LineEdit,
    PushButton,
    Select,
    SpinBox,
)

from napari_symbac._widgets._backend import backend_combo
from napari_symbac._widgets._forms import hide_label, message_label
from napari_symbac._widgets._jobs import Job, blocking_steps
from napari_symbac._widgets._links import ViewerLinks
from napari_symbac._widgets._recording import watch_recordings
from napari_symbac._widgets.calibrate import CALIBRATION_KEY
from napari_symbac._widgets.simulate import FITTED_TO_KEY, SYMBAC_METADATA_KEY
from napari_symbac.export import FORMATS, ExportSettings, export_of
from napari_symbac.export.dataset import no_validation_note
from napari_symbac.settings import PipelineSettings

if TYPE_CHECKING:
    import napari

__all__ = ["ExportWidget"]


class ExportWidget(Container):
    """Choose formats, number of items and a folder; export in the background.

    The settings (your recording's microscope and modality, as simulated, tuned and
    fitted) come from the chosen rendered layer: the newest one unless you pick
    another; a layer Auto-fit has fitted is listed as ``name (fitted to recording)``,
    its fitted settings being what the export uses; a layer Calibrate made writes the
    recording's matched dataset (single frames). With none, the built-in defaults
    (said in the status line). The settings are saved with the dataset (its manifest),
    and a cancelled export resumes when run again into the same folder. Errors
    (read-only folder, full disk) are shown as a notification and the widget stays
    usable.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(name="symbac_export")
        self.viewer = viewer
        self.source = ComboBox(
            name="source",
            label="settings from",
            choices=self._rendered,
            nullable=True,
            tooltip=(
                "The rendered layer whose simulation, optics and noise (as tuned and "
                "fitted) the dataset uses; the newest one by default. After Auto-fit it "
                "reads '(fitted to <recording>)': the fitted settings are used."
            ),
        )
        self.formats = Select(
            name="formats", label="formats", choices=list(FORMATS), value=["tiff"]
        )
        self.kind = ComboBox(name="kind", label="items", choices=["frames", "timeseries"])
        self.n_items = SpinBox(name="n_items", label="number of items", value=100, min=1, max=10**7)
        # found as a user: a series as long as the source layer's simulation (60 frames
        # beside a 6-frame recording), only the CLI's --n-frames could change it
        self.n_frames = SpinBox(
            name="n_frames", label="frames per series", value=0, min=0, max=10**5
        )
        self.seed = SpinBox(name="seed", label="seed", value=0, min=0, max=2**31 - 1)
        self.val_fraction = FloatSpinBox(
            name="val_fraction", label="validation fraction", value=0.1, min=0, max=0.9, step=0.05
        )
        self.workers = SpinBox(name="workers", label="worker processes", value=1, min=1, max=256)
        # found as a user: the CLI's --scheduler had no place in the dock, so a lab that
        # outgrew one machine could not export from napari on its cluster
        self.scheduler = LineEdit(name="scheduler", label="dask scheduler", value="")
        self.backend = backend_combo()
        self.folder = FileEdit(name="folder", label="output folder", mode="d")
        self.export_button = PushButton(name="export", text="Export")
        self.cancel_button = PushButton(name="cancel", text="Cancel", enabled=False)
        self.status = message_label("status")
        self.extend(
            [
                self.source,
                self.formats,
                self.kind,
                self.n_items,
                self.n_frames,
                self.seed,
                self.val_fraction,
                self.workers,
                self.scheduler,
                self.backend,
                self.folder,
                self.export_button,
                self.cancel_button,
                self.status,
            ]
        )
        hide_label(self.status)  # its words take the dock's whole width
        self.export_button.changed.connect(self.export)
        self.cancel_button.changed.connect(self.cancel)
        tips = {
            self.formats: "Dataset formats to write (several at once share the images).",
            self.kind: "frames: single images; timeseries: stacks with lineage.",
            self.n_items: "Items to export, each with freshly drawn parameters.",
            self.n_frames: "Frames simulated for each item (timeseries: the length of each "
            "series); 0: as many as the chosen layer's simulation.",
            self.seed: "Seed of every random draw: same seed, same dataset bit for bit.",
            self.val_fraction: "Fraction of items put in the validation split.",
            self.workers: "Worker processes (1: in this process); not used with a dask "
            "scheduler.",
            self.scheduler: "Address of your dask scheduler (tcp://host:8786), whose workers "
            "write the dataset (they must see the output folder at the same path); empty: "
            "worker processes on this machine.",
            self.folder: "Output folder; an unfinished export there is resumed.",
            self.export_button: "Write the dataset in the background.",
            self.cancel_button: "Stop after the items in progress; Export again resumes.",
        }
        for widget, tip in tips.items():
            widget.tooltip = tip
        # layers added or removed, and a layer's settings fitted (its metadata)
        self._links = ViewerLinks(self.native)
        watch_recordings(viewer, self._refresh_source, self._links)
        self.worker: Job | None = None
        self.report = None
        self._origin = ""
        self._split_note: str | None = None
        self._refresh_source()

    def _refresh_source(self, event=None) -> None:
        """Offer the rendered layers; choose the newest: one just added (a simulation, a
        diagnosis' settings), else the one chosen while it is left (renamed as fitted),
        else the newest left."""
        previous = self.source.value
        self.source.reset_choices()
        choices = [c for c in self.source.choices if c is not None]
        added = getattr(event, "value", None) if getattr(event, "type", "") == "inserted" else None
        if added is not None and any(added is c for c in choices):
            self.source.value = added
        elif any(previous is c for c in choices):
            self.source.value = previous
        elif choices:
            self.source.value = choices[-1]

    def _rendered(self, _widget=None) -> list[tuple[str, object]]:
        """``(label, layer)`` of each rendered layer; the label says when it is fitted."""
        return [
            (_source_label(layer), layer)
            for layer in self.viewer.layers
            if SYMBAC_METADATA_KEY in layer.metadata and not hasattr(layer, "selected_label")
        ]

    def settings(self) -> ExportSettings:
        """The export settings in the form (validated); for a layer Calibrate made, its
        matched dataset's (:func:`~napari_symbac.calibrate.export_settings`, as the
        ``calibrate`` command writes it)."""
        from napari_symbac.export.formats import tracking_formats

        layer = self.source.value
        meta = {} if layer is None else layer.metadata[SYMBAC_METADATA_KEY]
        if meta.get(CALIBRATION_KEY) is not None:
            return self._calibrated(meta[CALIBRATION_KEY])
        pipeline = meta["settings"] if layer is not None else PipelineSettings()
        # said in the dock's words (found as a user: "set ExportSettings.kind to
        # 'timeseries' (`napari-symbac export --kind timeseries`)", "napari-symbac export
        # --n-frames N", neither of which the dock has)
        tracking = tracking_formats(self.formats.value)
        if tracking and self.kind.value != "timeseries":
            raise ValueError(
                f"{', '.join(tracking)} hold tracking ground truth: choose items "
                "'timeseries'"
            )
        if self.n_frames.value > 0:  # the run as the form asks (the CLI's --n-frames)
            simulation = dataclasses.replace(pipeline.simulation, n_frames=self.n_frames.value)
            pipeline = dataclasses.replace(pipeline, simulation=simulation)
        n_frames = pipeline.simulation.n_frames
        if self.kind.value == "timeseries" and n_frames < 2:
            raise ValueError(
                f"a time series needs a simulation of at least 2 frames to track cells; "
                f"'{self.source.current_choice}' is {n_frames} frame (a field that "
                "Auto-fit fitted is one): simulate more frames in the Simulate step and "
                "export that layer, or choose items 'frames'"
            )
        return export_of(
            dataclasses.replace(
                pipeline,
                simulation=dataclasses.replace(pipeline.simulation, seed=self.seed.value),
            ),
            n_items=self.n_items.value,
            kind=self.kind.value,
            formats=list(self.formats.value),
            seed=self.seed.value,
            val_fraction=self.val_fraction.value,
        )

    def _calibrated(self, calibration) -> ExportSettings:
        """The matched dataset of ``calibration``: single frames (the ``calibrate``
        command's), at the form's size, formats, seed and validation fraction."""
        from napari_symbac.calibrate import export_settings

        if self.kind.value != "frames":
            raise ValueError(
                "a calibrated dataset holds single frames: choose items 'frames' (tracking "
                "ground truth needs a time series: Simulate one with the recording chosen, "
                "then Export it)"
            )
        if self.n_frames.value > 0:
            raise ValueError(
                "a calibrated dataset's frames come from a run laid out to grow to the "
                "recording's size: set 'frames per series' to 0"
            )
        return export_settings(
            calibration,
            n_items=self.n_items.value,
            formats=list(self.formats.value),
            seed=self.seed.value,
            val_fraction=self.val_fraction.value,
        )

    def export(self) -> None:
        """Validate the form and run the export in a worker thread."""
        from napari_symbac.export import export_dataset

        if self.worker is not None:
            return
        folder = Path(self.folder.value) if str(self.folder.value) not in ("", ".") else None
        if folder is None:
            self.status.value = "Choose an output folder"
            return
        try:
            settings = self.settings()
        except ValueError as err:
            self.status.value = f"Invalid settings: {err}"
            return
        from napari_symbac.export import check_export_folder
        from napari_symbac.export.atomic import check_output_folder

        backend = self.backend.value
        # as the CLI: a folder that cannot be written is refused before any work, and so
        # is one holding another export (found as a user: an error notification from
        # the job); the same export's folder is resumed
        try:
            check_output_folder(folder, "the output folder")
            check_export_folder(settings, folder, backend, in_dock=True)
        except (ValueError, RuntimeError) as err:  # ExportError is a RuntimeError
            self.status.value = f"Not exported: {err}"
            return
        workers = self.workers.value
        scheduler = self.scheduler.value.strip() or None
        if scheduler is not None:  # as the folder: a malformed address before any work
            from napari_symbac.export.cluster import check_scheduler_address

            try:
                check_scheduler_address(scheduler)
            except ValueError as err:
                self.status.value = f"Not exported: {err}"
                return
        origin = (
            f"'{self.source.current_choice}'"
            if self.source.value is not None
            else "the built-in defaults, not matched to any recording: simulate or fit first"
        )
        cancelled = threading.Event()

        def work():
            return (
                yield from blocking_steps(
                    lambda progress, cancel: export_dataset(
                        settings,
                        folder,
                        workers=None if scheduler else workers,
                        scheduler=scheduler,
                        progress=progress,
                        cancel=cancel,
                        backend=backend,
                    ),
                    cancelled.is_set,
                )
            )

        self.worker = Job(
            work,
            total=settings.n_images,
            description="SyMBac export",
            what="Export",
            on_yield=self._on_progress,
            on_return=self._on_returned,
            on_error=self._on_errored,
            on_finish=self._on_finished,
            owner=self.native,
            cancelled=cancelled,
        )
        self.export_button.enabled = False
        self.cancel_button.enabled = True
        self._origin = origin
        self._split_note = no_validation_note(settings)
        where = f" on the dask scheduler at {scheduler}" if scheduler else ""
        self.status.value = (
            f"Exporting {settings.n_images} images to {folder}{where} (settings: {origin})..."
        )
        self.worker.start()

    def cancel(self) -> None:
        """Stop after the items in progress; running the export again completes it."""
        if self.worker is not None:
            self.worker.cancelled.set()  # the export stops between items
            self.status.value = "Cancelling after the items in progress..."

    def _on_progress(self, update) -> None:
        done, total = update
        self.status.value = f"Exported {done} of {total} images"

    def _on_returned(self, report) -> None:
        self.report = report
        # which settings stays said (found as a user: with no rendered layer the dataset
        # was the defaults' trench, said only while exporting)
        self.status.value = f"{report} (settings: {self._origin})"
        if self._split_note and report.complete:
            self.status.value += f"<br>Note: {self._split_note}"

    def _on_errored(self, err: BaseException) -> None:
        self.status.value = f"Export failed: {err}"

    def _on_finished(self) -> None:
        self.worker = None
        self.export_button.enabled = True
        self.cancel_button.enabled = False


def _source_label(layer) -> str:
    """``layer``'s name, and the recording it was fitted to once Auto-fit has fitted it,
    or the window a diagnosis was made of (found as a user: after a diagnosis of a
    128 x 128 px window, chosen for speed, Export wrote 128 x 128 px images of a
    512 x 512 px recording, said only in the Diagnose tab)."""
    from napari_symbac._widgets.diagnose import WINDOW_KEY

    meta = layer.metadata[SYMBAC_METADATA_KEY]
    if (fitted := meta.get(FITTED_TO_KEY)) is not None:
        return f"{layer.name} (fitted to {fitted})"
    if (window := meta.get(WINDOW_KEY)) is not None:
        return f"{layer.name} (images of the diagnosed window, {window[0]} x {window[1]} px)"
    return layer.name
