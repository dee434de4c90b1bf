"""Dock widget: a training dataset matched to a recording, in one step (issue 14).

Runs what ``napari-symbac calibrate`` runs, in a worker: :func:`napari_symbac.calibrate.
calibrate` on the frame on screen (with the cell masks when chosen), then the first items
of the matched dataset (:func:`~napari_symbac.calibrate.export_settings`), compared with
the recording (:func:`~napari_symbac.calibrate.compare_with_dataset`). Item 0 and its
masks are added as layers; the image layer carries the calibration, so Export offers it
under "settings from" and writes the matched dataset (the ``calibrate`` command's, at the
Export tab's size, formats and seed).
"""

from __future__ import annotations

import dataclasses
import threading
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.widgets import CheckBox, ComboBox, Container, FloatSpinBox, PushButton

from napari_symbac._widgets._forms import fill_height, hide_label, message_label, report_box
from napari_symbac._widgets._jobs import Job, blocking_steps, notify_warning, removed_words
from napari_symbac._widgets._links import ViewerLinks
from napari_symbac._widgets._recording import (
    GUI_MODALITY_ADVICE,
    RECORDING_STEP,
    check_recording_frame,
    followed_layer,
    given_camera,
    in_pixel_units,
    is_recording,
    layer_axes,
    layer_pixel_size_um,
    mask_layers,
    newest_masks,
    pixel_size_problem,
    real_images,
    recording_microscope,
    shown_frame,
    watch_recordings,
)
from napari_symbac._widgets.real_image import enter_pixel_size
from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY
from napari_symbac.calibrate import items_words

if TYPE_CHECKING:
    import napari

__all__ = ["CALIBRATED_TO_KEY", "CALIBRATION_KEY", "CalibrateWidget", "calibrated_layer_name"]

#: Metadata key (under ``metadata["symbac"]``) of the :class:`~napari_symbac.calibrate.
#: Calibration` a calibrated layer carries: Export writes its matched dataset.
CALIBRATION_KEY = "calibration"
#: Metadata key of the recording a layer was calibrated to.
CALIBRATED_TO_KEY = "calibrated_to"


#: How far the pixel size a cell width gives from the masks may lie from the
#: recording's own before Calibrate refuses the pair (a species' width is known to
#: about 10 %).
CELL_WIDTH_TOLERANCE = 0.15


def calibrated_layer_name(recording: str) -> str:
    """The layer of a calibration's dataset item 0."""
    return f"synthetic (calibrated to {recording})"


@dataclasses.dataclass(frozen=True)
class _Outcome:
    """A calibration, the dataset items compared with the recording (item 0 first) and
    the comparison, and where the pixel size came from."""

    calibration: Any
    items: list
    comparison: Any
    pixel_note: str
    #: The recording's microscope when its pixel size comes from a cell width and the
    #: recording has none: the derived pixel size is entered for it; else ``None``.
    enter_for: Any = None


class CalibrateWidget(Container):
    """Fit a recording and turn the fit into a matched training dataset's settings.

    Choose the recording (a field: agar pad or colony; a mother-machine trench is
    fitted with Auto-fit instead) and, when you have them, its cell masks; for a
    recording whose pixel size is not known, give the cells' width (um) with the masks
    and the pixel size is measured from them. The result: item 0 of the matched
    dataset beside the recording, a report of where every setting came from and of
    real against synthetic, and a layer Export writes the dataset from.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(name="symbac_calibrate")
        self.viewer = viewer
        self.recording = ComboBox(
            name="recording", label="real image", choices=self._images, nullable=True
        )
        self.recording.tooltip = (
            "The recording to match: an agar-pad field or colonies (its frame on screen)."
        )
        self.masks = ComboBox(
            name="masks", label="cell masks", choices=self._mask_layers, nullable=True
        )
        self.masks.tooltip = (
            "Instance masks of the recording (optional): the fit starts from them, and the "
            "cells' sizes, layout, packing and the masks' outline convention are measured "
            "on them. Without masks the fit finds the cells."
        )
        self.cell_width_um = FloatSpinBox(
            name="cell_width_um",
            label="cell width (um; 0: use the pixel size)",
            value=0.0,
            min=0.0,
            max=10.0,
            step=0.05,
            tooltip=(
                "For a recording whose pixel size is not known (a PNG): the cells' width "
                "(1.0 for E. coli); the pixel size is this over the masks' median width. "
                "Needs cell masks."
            ),
        )
        self.envelope_stain = CheckBox(
            name="envelope_stain",
            text="stain in the cell envelope (membrane dye)",
            tooltip=(
                "Fluorescence: fit the fraction of the stain in the cell envelope (cells "
                "brighter at the rim than on the centre line), as napari-symbac calibrate "
                "--envelope-stain; the dataset draws it. A membrane-stained field calibrated "
                "without it gets volume-stained cells, about 1.5 times too wide."
            ),
        )
        self.depth = CheckBox(
            name="depth",
            text="image the cells in depth (eq. 16)",
            tooltip=(
                "Fluorescence: image the stain in slabs through the cells, each through the "
                "PSF defocused by its distance from the focal plane, which is fitted, as "
                "napari-symbac calibrate --depth-layers 5; the fit takes 2-5 times as long. "
                "The dataset draws it."
            ),
        )
        self.run_button = PushButton(
            name="calibrate",
            text="Calibrate",
            tooltip="Fit the recording and make the matched dataset's settings.",
        )
        self.cancel_button = PushButton(
            name="cancel", text="Cancel", enabled=False, tooltip="Stop the calibration."
        )
        self.status = message_label("status")
        self.report = report_box()
        self.extend(
            [
                self.recording,
                self.masks,
                self.cell_width_um,
                self.envelope_stain,
                self.depth,
                self.run_button,
                self.cancel_button,
                self.status,
                self.report,
            ]
        )
        hide_label(self.report)
        hide_label(self.status)
        fill_height(self, self.report)
        self.worker: Job | None = None
        self._camera_words = "the camera measured from the recording"  # of the last run
        self.calibration = None
        self.run_button.changed.connect(self.run)
        self.cancel_button.changed.connect(self.cancel)
        self.recording.changed.connect(self._choose_masks)
        self.recording.changed.connect(self._show_stain_boxes)
        self._links = ViewerLinks(self.native)
        watch_recordings(viewer, self._refresh_choices, self._links)
        self._refresh_choices()
        self._show_stain_boxes()

    # -- choices --------------------------------------------------------------------------

    def _images(self, _widget=None) -> list:
        return real_images(self.viewer)

    def _mask_layers(self, _widget=None) -> list:
        return mask_layers(self.viewer)

    def _refresh_choices(self, event=None) -> None:
        self.recording.reset_choices()
        self.masks.reset_choices()
        choices = [c for c in self.recording.choices if c is not None]
        followed = followed_layer(event, choices, busy=self.worker is not None)
        if followed is not None and followed is not self.recording.value:
            self.masks.value = None  # chosen for the recording before
            self.recording.value = followed
        elif self.recording.value is None and choices:
            ready = [c for c in choices if is_recording(c)]
            self.recording.value = (ready or choices)[-1]
        if getattr(event, "type", "") == "inserted":  # masks opened after the recording
            self._choose_masks(only=event.value)

    def _show_stain_boxes(self, _value=None) -> None:
        """The stain's boxes for a fluorescence recording only (as Auto-fit's), or while
        no recording is chosen; a box ticked for another recording is refused by name."""
        layer = self.recording.value
        fluorescence = layer is None or layer.metadata.get("modality") in (None, "fluorescence")
        for box in (self.envelope_stain, self.depth):
            box.visible = fluorescence or box.value

    def _choose_masks(self, _value=None, *, only=None) -> None:
        """With none chosen, the newest labels layer of the recording's frame size with
        cells in it (``only``: the layer just added), as Tune's Auto-fit does."""
        recording = self.recording.value
        if self.masks.value is not None or recording is None:
            return
        masks = newest_masks(self.viewer, recording, only)
        if masks is not None:
            self.masks.value = masks

    # -- input ----------------------------------------------------------------------------

    def _input(self) -> tuple:
        """Frame, masks (or ``None``), microscope, cell width (or ``None``), pixel note,
        and the microscope to enter for a recording without a pixel size whose cell width
        gives it (``None`` otherwise).

        Raises
        ------
        ValueError
            With what to do, when something needed is missing or cannot be used.
        """
        from napari_symbac.fit.preflight import (
            check_instance_masks,
            check_modality,
            default_geometry,
            lying_trench_problem,
        )
        from napari_symbac.settings import Microscope

        layer = self.recording.value
        if layer is None:
            raise ValueError(
                f"No recording: open your image in {RECORDING_STEP}, then choose it here"
            )
        frame = shown_frame(self.viewer, np.asarray(layer.data))
        if frame.ndim != 2:
            raise ValueError(f"{layer.name} must be one 2D frame or a (T, Y, X) series")
        check_recording_frame(frame, layer.name)
        masks = None
        if self.masks.value is not None:
            masks = shown_frame(self.viewer, np.asarray(self.masks.value.data))
            check_instance_masks(masks, frame.shape, f"cell masks '{self.masks.value.name}'")
        width = self.cell_width_um.value or None
        if width is not None and masks is None:
            raise ValueError(
                "the cell width sets the pixel size from the cells' masks: choose the cell "
                "masks too (or set the width to 0 to use the recording's pixel size)"
            )
        problem = pixel_size_problem(layer_pixel_size_um(layer))
        if width is not None and problem is None:  # both: they must agree (found as a
            # user: 0.065 um entered, a width of 1 um gave 0.134 um, and the calibrated
            # layers were drawn at twice the recording's scale without a word)
            from napari_symbac.fit.masks import estimate_pixel_size_um

            given, measured = layer_pixel_size_um(layer), estimate_pixel_size_um(masks, width)
            if abs(measured / given - 1) > CELL_WIDTH_TOLERANCE:
                raise ValueError(
                    f"{layer.name} has a pixel size of {given:.4g} um, and a cell width of "
                    f"{width:g} um makes it {measured:.4g} um from the masks: set the cell "
                    f"width to 0 to calibrate at {given:.4g} um, or enter {measured:.4g} um "
                    f"in {RECORDING_STEP} if the cells are {width:g} um wide"
                )
            width = None  # they agree: the recording's
        if width is not None:
            microscope = layer.metadata.get("microscope") or Microscope()
            microscope = dataclasses.replace(
                microscope, modality=layer.metadata.get("modality") or microscope.modality
            )
            note = f"from the masks' median width and a cell width of {width:g} um"
        elif problem is not None:
            raise ValueError(
                f"{layer.name}: {problem} in {RECORDING_STEP}; or, with cell masks, give the "
                "cells' width (um) here"
            )
        else:
            microscope = recording_microscope(layer)
            note = "the recording's"
        # the modality checked here, in this dock's words (calibrate checks it again)
        check_modality(frame, microscope.modality, masks=masks, advice=GUI_MODALITY_ADVICE)
        ticked = [box.text for box in (self.envelope_stain, self.depth) if box.value]
        if ticked and microscope.modality != "fluorescence":
            raise ValueError(
                f"'{ticked[0]}' is fitted in fluorescence; {layer.name} is "
                f"{microscope.modality}: untick it"
            )
        lying = lying_trench_problem(frame.shape, microscope.modality, layer.name)
        if lying or default_geometry(frame.shape, microscope.modality) == "trench":
            shape = (
                f"{lying}; and Calibrate does not lay out a trench"
                if lying
                else f"{layer.name} is {frame.shape[0]} x {frame.shape[1]} px, narrow and "
                "tall: a mother-machine trench, which Calibrate does not lay out"
            )
            raise ValueError(
                f"{shape} (it matches fields: agar pads and colonies). Fit the trench with "
                "Auto-fit (3 Tune + fit), then Export from the fitted layer"
            )
        enter_for = microscope if width is not None and problem is not None else None
        return frame, masks, microscope, width, note, enter_for

    # -- run ------------------------------------------------------------------------------

    def run(self) -> None:
        """Check the input and calibrate in a worker."""
        if self.worker is not None:
            return
        try:
            frame, masks, microscope, width, pixel_note, enter_for = self._input()
        except ValueError as err:
            self.status.value = f"Not calibrated: {err}"
            return
        camera = given_camera(self.recording.value)  # None: measured from the frame
        from napari_symbac.fit.scene_fit import DEPTH_FIT_LAYERS

        envelope_stain = self.envelope_stain.value  # read here, in the GUI thread
        depth_layers = DEPTH_FIT_LAYERS if self.depth.value else 0
        self._camera_words = (
            "the camera given in the Recording step" if camera else "the camera measured from "
            "the recording"
        )
        cancelled = threading.Event()

        def calibrate_and_draw(progress, cancel):
            from napari_symbac.calibrate import (
                COMPARED_ITEMS,
                calibrate,
                compare_with_dataset,
                export_settings,
            )
            from napari_symbac.calibrate.compare import GUI_WORDS
            from napari_symbac.fit import FitCancelled

            renders = [0]

            def fit_progress(done: int, total: int) -> None:
                renders[0] = done
                progress(done, total)

            def stage(words: str) -> None:  # a stage that renders nothing: words, no count
                progress(renders[0], words)

            calibration = calibrate(
                frame,
                microscope=microscope,
                camera=camera,
                masks=masks,
                cell_width_um=width,
                envelope_stain=envelope_stain,
                depth_layers=depth_layers,
                pixel_note=f"pixel size {microscope.pixel_size_um:.4g} um, {pixel_note}",
                progress=fit_progress,
                cancel=cancel,
                stage=stage,
            )
            if cancel():  # before the dataset's first items are simulated
                raise FitCancelled("calibration cancelled")
            stage(f"simulating the dataset's first {COMPARED_ITEMS} items to compare")
            comparison, items = compare_with_dataset(
                calibration,
                export_settings(calibration, n_items=COMPARED_ITEMS),
                masks_given=masks is not None,
                words=GUI_WORDS,
            )
            return _Outcome(calibration, items, comparison, pixel_note, enter_for)

        def work():
            return (yield from blocking_steps(calibrate_and_draw, cancelled.is_set))

        self.worker = Job(
            work,
            total=0,
            description="SyMBac calibrate",
            what="Calibrate",
            on_yield=self._on_progress,
            on_return=self._on_returned,
            on_error=self._on_errored,
            on_abort=self._on_cancelled,
            on_finish=self._on_finished,
            owner=self.native,
            cancelled=cancelled,
        )
        self.worker.stop_if_removed(self.viewer.layers, (self.recording.value,))
        self._recording_layer = self.recording.value
        self.run_button.enabled = False
        self.cancel_button.enabled = True
        self.status.value = "Calibrating: fitting the recording..."
        self.worker.start()

    def cancel(self) -> None:
        """Stop at the fit's next render or before the next simulated colony."""
        if self.worker is not None:
            self.worker.quit()
            self.status.value = "Cancelling..."

    def _on_progress(self, message) -> None:
        """``(done, total)`` renders of the fit, or ``(done, words)`` of a later stage."""
        done, total = message
        if isinstance(total, str):
            self.status.value = f"Calibrating: {total}..."
        else:
            self.status.value = (
                f"Calibrating: fit, {done} renders so far (a converging fit ends far below "
                f"its bound of {total})"
            )

    def _on_returned(self, outcome: _Outcome) -> None:
        calibration = outcome.calibration
        self.calibration = calibration
        recording = self._recording_layer
        name = calibrated_layer_name(recording.name)
        for old in (name, f"{name} masks"):
            if old in self.viewer.layers:
                self.viewer.layers.remove(old)
        px = calibration.settings.microscope.pixel_size_um
        entered = ""
        if outcome.enter_for is not None:  # a cell width's pixel size, for every layer
            enter_pixel_size(
                self.viewer, recording, dataclasses.replace(outcome.enter_for, pixel_size_um=px)
            )
            entered = (
                f" Pixel size {px:.4g} um (from the cell width) entered for '{recording.name}'."
            )
        axes = {} if in_pixel_units(recording) else layer_axes(px, 2)
        self.viewer.add_image(
            outcome.items[0].image,
            name=name,
            metadata={
                SYMBAC_METADATA_KEY: {
                    "settings": calibration.settings,
                    CALIBRATION_KEY: calibration,
                    CALIBRATED_TO_KEY: recording.name,
                }
            },
            **axes,
        )
        self.viewer.add_labels(
            np.asarray(outcome.items[0].labels),
            name=f"{name} masks",
            metadata={SYMBAC_METADATA_KEY: {CALIBRATED_TO_KEY: recording.name}},
            opacity=0.4,
            **axes,
        )
        comparison = outcome.comparison
        self.report.value = "\n".join(
            [
                f"Calibration of {recording.name}",
                *calibration.report_lines(outcome.pixel_note),
                "",
                f"REAL AGAINST SYNTHETIC (the dataset's {items_words(len(outcome.items))}; "
                "each 1-99 % normalised; the layer shows item 0)",
                comparison.table(),
            ]
        )
        checks = comparison.checks()
        matched = sum(check.matched for check in checks)
        from napari_symbac.fit.report import unmeasured_noise_adu

        camera_words = self._camera_words
        if unmeasured_noise_adu(calibration.settings.camera) is not None:
            # found as a user: "the camera measured from the recording" beside a report
            # that said it could not be (ColiCoords' flattened bright-field crop)
            camera_words = "its own pixel noise (the camera not measurable from the recording)"
        self.status.value = (
            f"{calibration.method}: the recording against the dataset's "
            f"{items_words(len(outcome.items))}: {matched} of {len(checks)} comparisons match "
            "(the report says which, and what to do). Layer "
            f"'{name}' holds the matched settings, with {camera_words}: Export "
            f"writes the dataset from it (its 'settings from').{entered}"
        )
        if calibration.cautions:  # found as a user: 1.8 um wide cells exported unsaid
            warning = "Warning: " + "; ".join(calibration.cautions)
            self.status.value = f"{warning}\n{self.status.value}"
            notify_warning(f"Calibrate: {warning}")

    def _on_cancelled(self) -> None:
        self.status.value = f"Calibration cancelled{removed_words(self.worker)}: nothing added"

    def _on_errored(self, err: BaseException) -> bool:
        from napari_symbac.fit import FitCancelled

        if isinstance(err, FitCancelled) or self.worker.cancelled.is_set():
            self._on_cancelled()
            return True
        self.status.value = f"Calibration failed: {err}"
        return False

    def _on_finished(self) -> None:
        self.worker = None
        self.run_button.enabled = True
        self.cancel_button.enabled = False
        if self.status.value.startswith(("Calibrating", "Cancelling")):
            self.status.value = "Calibration stopped"
