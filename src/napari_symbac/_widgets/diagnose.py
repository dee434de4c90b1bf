"""Dock widget: diagnose what the fitted model misses in a recording (issue 11).

Runs what ``napari-symbac diagnose`` runs, in a worker: the scene fit of the
recording's frame on screen (:func:`napari_symbac.fit.fit_scene`), the base design
(:func:`~napari_symbac.diagnose.model.build_design`), and
:func:`~napari_symbac.diagnose.run.diagnose`. The standardised residual and each
accepted effect's map are added as layers, the report is shown in the dock, and the
updated settings (:func:`~napari_symbac.diagnose.stages.updated_settings`) are kept in
the residual layer's ``metadata["symbac"]["settings"]``, so Export offers them under
"settings from".
"""

from __future__ import annotations

import textwrap
import threading
from typing import TYPE_CHECKING

import numpy as np
from magicgui.widgets import ComboBox, Container, LineEdit, PushButton, SpinBox

from napari_symbac._widgets._forms import fill_height, hide_label, message_label, report_box
from napari_symbac._widgets._jobs import Job, blocking_steps, notify_warning, removed_words
from napari_symbac._widgets._links import ViewerLinks
from napari_symbac._widgets._recording import (
    GUI_CAMERA_FIX,
    GUI_MODALITY_ADVICE,
    check_recording_frame,
    choose_masks,
    followed_layer,
    given_camera,
    is_recording,
    mask_layers,
    modality_render,
    no_recording_message,
    output_metadata,
    real_images,
    recording_microscope,
    watch_recordings,
)
from napari_symbac._widgets._residual import (
    RESIDUAL_COLORMAP,
    RESIDUAL_LEGEND,
    add_residual_layer,
    symmetric_limits,
)
from napari_symbac._widgets.real_image import class_layer_name
from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY

if TYPE_CHECKING:
    import napari

__all__ = ["DIAGNOSIS_RESIDUAL_LAYER", "WINDOW_KEY", "DiagnoseWidget", "effect_layer_name"]

#: How the dock's advice for an image that is not yet a recording ends.
WAITING_THEN = "choose it here"

#: Metadata of the diagnosis' layer: the diagnosed window's ``(rows, columns)`` when
#: smaller than the recording (its settings draw frames of that size), else ``None``.
WINDOW_KEY = "diagnosed_window_px"

#: The layer of the base fit's standardised residual; it carries the updated settings.
DIAGNOSIS_RESIDUAL_LAYER = "diagnosis residual"
#: The layer of the residual after the accepted effects.
DIAGNOSIS_AFTER_LAYER = "diagnosis residual after"
#: The label of the dock's field of the window diagnosed.
WINDOW_LABEL = "window (rows, columns)"
#: The width of the report's own lines (what the diagnosis changed, at its top): the
#: report box shows about this many characters in the workflow dock at 1366 x 768.
REPORT_COLUMNS = 64
#: The label of the dock's field of the cells' instance masks.
MASKS_LABEL = "cell masks"
#: What the dock asks of a start wider than any rod
#: (:class:`~napari_symbac.fit.start.WideStartError`).
WIDE_START_FIX = (
    f"open the cells' instance masks (a Labels layer) and choose them in '{MASKS_LABEL}', "
    f"or enter a window of separate cells in '{WINDOW_LABEL}'"
)
#: The dock's words for a start that found no bright cell
#: (:class:`~napari_symbac.fit.start.FaintStartError`).
FAINT_START_FIX = (
    f"choose the cells' instance masks in '{MASKS_LABEL}', or paint rough cell and media "
    "strokes on the recording in the Recording step"
)


def window_words(region: tuple[int, int, int, int], full: tuple[int, ...], how: str) -> str:
    """The window diagnosed, in words: ``"the centre 256 x 256 px of the 512 x 512 frame,
    rows 128:384 and columns 128:384"``; "the chosen" for a window chosen, "the 256 x 256
    px ... that hold the most cells" for the cells' window (``how``:
    :func:`~napari_symbac.diagnose.region.placement` of the *window* field)."""
    y0, y1, x0, x1 = region
    size = f"{y1 - y0} x {x1 - x0} px of the {full[0]} x {full[1]} frame"
    which = f"the {size} that hold the most cells" if how == "cells" else f"the {how} {size}"
    return f"{which}, rows {y0}:{y1} and columns {x0}:{x1}"


def no_cells_in_window(
    err: Exception, region: tuple[int, int, int, int], full: tuple[int, ...], how: str
) -> str:
    """The base fit's "no cells" in the window the dock diagnoses, said with that window
    and what to do. Found as a user: a 300 x 300 px field whose cells lie outside its
    centre 256 x 256 px said only "Diagnosis failed: the start found no cells in the
    image", of an image with cells in it. A small window may hold a cell with too
    little background around it for the start, as the CLI says (found as a user: 60 x
    100 px around a bright cell were told to "enter one with cells")."""
    from napari_symbac.diagnose.region import SMALL_WINDOW_PX

    y0, y1, x0, x1 = region
    fix = f"enter one with cells in '{WINDOW_LABEL}' (Y0:Y1,X0:X1 in pixels, or full)"
    if min(y1 - y0, x1 - x0) < SMALL_WINDOW_PX:
        fix = (
            f"the {y1 - y0} x {x1 - x0} px window may be too small for the start to tell "
            f"the cells from the background: {fix}, of at least {SMALL_WINDOW_PX} x "
            f"{SMALL_WINDOW_PX} px around them"
        )
    return (
        f"{getattr(err, 'cause', err)}, in {window_words(region, full, how)}, the window "
        f"diagnosed: {fix}"
    )


def _frame_words(layer, viewer) -> str:
    """`` (frame N of T)`` for a time-lapse, which frame is diagnosed; ``""`` for one
    image (found as a user: a diagnosis of frame 10 of 30 never said which frame, and its
    2D layers lie over every frame)."""
    data = layer.data
    if data.ndim != 3:
        return ""
    index = min(int(viewer.dims.current_step[0]), len(data) - 1)
    return f" (frame {index} of {len(data)})"


def effect_layer_name(name: str) -> str:
    """The layer of an accepted effect's map."""
    return f"diagnosis effect: {name}"


class DiagnoseWidget(Container):
    """Find, name and fit the effects the forward model misses in a recording.

    Choose a recording (pixel size set in *Real image and classes*); its painted
    classes are used when there are any. The diagnosis fits the scene of the frame on
    screen, then tests the catalogue's effects stepwise (score tests, held-out
    bootstrap). ``candidates`` and ``n_bootstrap`` are passed to
    :func:`~napari_symbac.diagnose.run.diagnose` (tests use a few for speed).
    """

    def __init__(
        self,
        viewer: napari.viewer.Viewer,
        *,
        candidates: tuple[str, ...] | None = None,
        n_bootstrap: int = 30,
        max_pixels: int | None = None,
    ):
        super().__init__(name="symbac_diagnose")
        self.viewer = viewer
        self.candidates = candidates
        self.n_bootstrap = n_bootstrap
        self.max_pixels = max_pixels
        self.reference = ComboBox(
            name="reference", label="real image", choices=self._recordings, nullable=True
        )
        self.reference.tooltip = "The recording to diagnose (its pixel size must be set)."
        self.masks = ComboBox(
            name="masks", label=MASKS_LABEL, choices=self._mask_layers, nullable=True
        )
        self.masks.tooltip = (
            "Instance masks of the real image (a Labels layer, 0 background, one number per "
            "cell, e.g. from Cellpose or Omnipose): the base fit starts from these cells, as "
            "napari-symbac diagnose --masks. Empty: painted classes or the fit's own "
            "segmentation."
        )
        self.window = LineEdit(name="window", label=WINDOW_LABEL, value="cells")
        self.window.tooltip = (
            "The part of the frame to diagnose, in camera pixels: cells (the whole frame "
            "up to 256 x 256 px, else the window of that many pixels that holds the most "
            "whole cells, of the cell masks when chosen), centre (its centre window), full "
            "(the whole frame: a diagnosis's time and memory grow faster than its pixels), or "
            "Y0:Y1,X0:X1 (rows Y0 to Y1, columns X0 to X1, e.g. 96:192,48:112); as "
            "napari-symbac diagnose --region."
        )
        self.seed = SpinBox(
            name="seed",
            label="seed",
            value=0,
            min=0,
            max=2**31 - 1,
            tooltip="Seed of the bootstrap: same seed, same diagnosis.",
        )
        self.max_effects = SpinBox(
            name="max_effects",
            label="at most (effects)",
            value=4,
            min=1,
            max=20,
            tooltip="Effects a diagnosis accepts at most, as napari-symbac diagnose "
            "--max-effects; the report names the candidates left untested when it stops "
            "there.",
        )
        self.run_button = PushButton(
            name="diagnose",
            text="Diagnose",
            tooltip="Fit the scene, then find and fit the effects the model misses.",
        )
        self.cancel_button = PushButton(
            name="cancel", text="Cancel", enabled=False, tooltip="Stop the diagnosis."
        )
        self.status = message_label("status")
        self.report = report_box()
        self.extend(
            [
                self.reference,
                self.masks,
                self.window,
                self.seed,
                self.max_effects,
                self.run_button,
                self.cancel_button,
                self.status,
                self.report,
            ]
        )
        # the report takes the dock's width and spare height (it starts "Diagnosis of
        # the mismatch": no row label needed)
        hide_label(self.report)
        hide_label(self.status)
        fill_height(self, self.report)
        self.worker: Job | None = None
        self.result = None
        self.run_button.changed.connect(self.run)
        self.cancel_button.changed.connect(self.cancel)
        self.reference.changed.connect(self._choose_masks)
        self._links = ViewerLinks(self.native)
        watch_recordings(viewer, self._refresh_choices, self._links)
        self._refresh_choices()

    def _recordings(self, _widget=None) -> list:
        return [layer for layer in self.viewer.layers if is_recording(layer)]

    def _mask_layers(self, _widget=None) -> list:
        return mask_layers(self.viewer)

    def _refresh_choices(self, _event=None) -> None:
        self.reference.reset_choices()
        self.masks.reset_choices()
        choices = [c for c in self.reference.choices if c is not None]
        followed = followed_layer(_event, choices, busy=self.worker is not None)
        if followed is not None and followed is not self.reference.value:
            self.masks.value = None  # chosen for the recording before
            self.reference.value = followed
        elif self.reference.value is None and choices:
            self.reference.value = choices[-1]
        if getattr(_event, "type", "") == "inserted":  # masks opened after the recording
            self._choose_masks(only=_event.value)
        self._say_what_waits(choices)

    def _say_what_waits(self, choices: list) -> None:
        """Name the opened image that waits for its pixel size, and take that back once
        it is a recording. Found as a user: the dock said nothing until *Diagnose* was
        clicked, then kept saying "... has no pixel size yet" after it was entered."""
        if self.worker is not None:
            return
        if not choices and any(not is_recording(layer) for layer in real_images(self.viewer)):
            self.status.value = no_recording_message(self.viewer, WAITING_THEN)
        elif self.status.value.endswith(WAITING_THEN):  # a recording now: advice done
            self.status.value = ""

    def _choose_masks(self, _value=None, *, only=None) -> None:
        """With no cell masks chosen, the newest layer of instance masks of the recording's
        frame size (cells in it), as Tune's Auto-fit chooses them (``only``: the layer
        just added, the one to consider)."""
        choose_masks(self.masks, self.viewer, self.reference.value, only)

    # -- input ----------------------------------------------------------------------------

    def _input(self) -> tuple:
        """Frame, classes (or ``None``), cell masks (or ``None``), microscope, start
        render, camera, geometry, region.

        The camera is the one given in the Recording step, else ``None``: the base fit
        measures it from the recording (gain and read noise, as Auto-fit and
        ``napari-symbac fit`` do), so that the diagnosis does not report the difference
        from an assumed camera as a finding. ``region`` (rows
        ``y0:y1``, columns ``x0:x1``) is the *window* field's, read by the CLI's parser
        (:func:`~napari_symbac.diagnose.region.parse_region`): by default a frame larger
        than :data:`~napari_symbac.diagnose.region.MAX_DIAGNOSIS_PIXELS` is diagnosed on
        the window that holds the most whole cells, as the CLI does.

        Raises
        ------
        ValueError
            With what to do, when no recording is chosen or the window is not one.
        """
        from napari_symbac.diagnose.region import MAX_DIAGNOSIS_PIXELS, parse_region
        from napari_symbac.fit.preflight import check_modality
        from napari_symbac.settings import RenderSettings

        layer = self.reference.value
        if layer is None:
            raise ValueError(no_recording_message(self.viewer, WAITING_THEN))
        microscope = recording_microscope(layer)
        data = np.asarray(layer.data)
        index = int(self.viewer.dims.current_step[0]) if data.ndim == 3 else 0
        frame = data[min(index, len(data) - 1)] if data.ndim == 3 else data
        if frame.ndim != 2:
            raise ValueError(f"{layer.name} must be one frame or a series, got {data.shape}")
        check_recording_frame(frame, layer.name)  # what the fit refuses
        labels = None
        name = class_layer_name(layer.name)
        if name in self.viewer.layers:
            labels = np.asarray(self.viewer.layers[name].data)
            if labels.ndim == 3:
                labels = labels[min(index, len(labels) - 1)]
            if labels.shape != frame.shape or not labels.any():
                labels = None
        given_masks = self._frame_masks(index, data.shape[-2:])
        region = parse_region(
            self.window.value,
            frame,
            masks=given_masks,
            max_pixels=self.max_pixels or MAX_DIAGNOSIS_PIXELS,
            name="window",
        )
        y0, y1, x0, x1 = region
        frame = frame[y0:y1, x0:x1]
        if labels is not None:
            labels = labels[y0:y1, x0:x1]
            if not labels.any():
                labels = None
        masks = self._window_masks(given_masks, region, microscope.modality)
        # what the fit refuses (as the CLI): a modality the image contradicts
        check_modality(
            frame, microscope.modality, labels=labels, masks=masks, advice=GUI_MODALITY_ADVICE
        )
        means = layer.metadata.get("class_means_adu")
        if means or microscope.modality == "fluorescence":
            render = modality_render(RenderSettings(), microscope.modality, means)
        else:  # the CLI's start (``napari-symbac diagnose``)
            render = RenderSettings()
        camera = given_camera(layer)  # None: measured by the base fit
        # as the CLI: a narrow phase field is a trench; fluorescence shows no walls
        from napari_symbac.fit.preflight import default_geometry, lying_trench_problem

        if problem := lying_trench_problem(frame.shape, microscope.modality, layer.name):
            raise ValueError(problem)
        named = default_geometry(frame.shape, microscope.modality)
        geometry = "open" if named == "field" else named
        return frame, labels, masks, microscope, render, camera, geometry, region

    def _frame_masks(self, index: int, shape: tuple) -> np.ndarray | None:
        """The chosen cell masks' instance ids over the whole frame (frame ``index`` of
        masks given per frame), checked as the CLI checks ``--masks``; ``None`` when
        none are chosen."""
        from napari_symbac.fit.preflight import as_instance_ids, check_instance_masks

        layer = self.masks.value
        if layer is None:
            return None
        masks = np.asarray(layer.data)
        if masks.ndim == 3:
            masks = masks[min(index, len(masks) - 1)]
        check_instance_masks(masks, tuple(shape), f"'{MASKS_LABEL}' {layer.name}")
        return as_instance_ids(masks)[0]

    def _window_masks(
        self, masks: np.ndarray | None, region: tuple, modality: str
    ) -> np.ndarray | None:
        """The frame's ``masks`` (:meth:`_frame_masks`) in the window, refused when it
        holds none of their cells or a dense colony of them."""
        from napari_symbac.fit.colony import is_dense_colony

        if masks is None:
            return None
        name = f"'{MASKS_LABEL}' {self.masks.value.name}"
        y0, y1, x0, x1 = region
        masks = masks[y0:y1, x0:x1]
        if not masks.any():
            raise ValueError(
                f"{name} hold no cell in rows {y0}:{y1}, columns {x0}:{x1} (the window "
                f"diagnosed): enter a window with cells in '{WINDOW_LABEL}', or choose no "
                "cell masks"
            )
        if is_dense_colony(masks, modality):
            raise ValueError(
                f"{name} hold a dense colony of touching cells in the window: its halo and "
                "bright seams are drawn by Tune's Auto-fit from the masks (the partially "
                "coherent model), not by Diagnose's scene of separate rods; enter a window "
                f"of separate cells in '{WINDOW_LABEL}'"
            )
        return masks

    # -- run ------------------------------------------------------------------------------

    def run(self) -> None:
        """Fit the scene and diagnose it in a worker (progress in napari's activity dock)."""
        from napari_symbac.diagnose.region import placement

        if self.worker is not None:
            return
        try:
            frame, labels, masks, microscope, render, camera, geometry, region = self._input()
            full = np.asarray(self.reference.value.data).shape[-2:]
        except ValueError as err:
            self.status.value = str(err)
            notify_warning(str(err))
            return
        cancelled = threading.Event()
        seed, candidates, n_bootstrap = self.seed.value, self.candidates, self.n_bootstrap
        max_effects = self.max_effects.value
        base_simulation = self._simulation_to_export()
        how = placement(self.window.value)

        def compute(progress, cancel):
            from napari_symbac.diagnose.model import build_design
            from napari_symbac.diagnose.region import simulated_shape
            from napari_symbac.diagnose.run import diagnose
            from napari_symbac.diagnose.stages import refitted_render
            from napari_symbac.fit import fit_scene
            from napari_symbac.fit.clipped_background import fitted_clip
            from napari_symbac.fit.fitted_settings import fitted_or_kept
            from napari_symbac.fit.report import camera_text, measured_camera_note

            try:
                fit = fit_scene(
                    frame,
                    microscope,
                    render,
                    camera,
                    labels=labels,
                    masks=masks,
                    geometry=geometry,
                    # a negative total marks the scene fit's renders (_on_progress)
                    progress=lambda done, total: progress(done, -total),
                    cancel=cancel,
                )
            except ValueError as err:
                if "no cells" not in str(err) or region == (0, full[0], 0, full[1]):
                    raise
                from napari_symbac.fit.start import FaintStartError

                said = no_cells_in_window(err, region, full, how)
                if isinstance(err, FaintStartError):  # a faint cell may be there: its fix
                    raise FaintStartError(said) from err  # too (found as a user: an error)
                raise ValueError(said) from err
            if cancel():
                raise InterruptedError("diagnosis cancelled")
            layout = simulated_shape(region, full, fit.trench is not None)
            exported = fitted_or_kept(base_simulation, fit, layout, microscope.pixel_size_um)
            design = build_design([fit.scene], microscope, fit.render, fit.camera)
            result = diagnose(
                frame,
                design,
                candidates=candidates,
                n_bootstrap=n_bootstrap,
                max_steps=max_effects,
                rng=np.random.default_rng(seed),
                progress=progress,
                cancel=cancel,
            )
            final = refitted_render(fit.render, result.final_model, microscope.modality)
            camera_note = (
                measured_camera_note(frame, fit.camera, give_camera=GUI_CAMERA_FIX)[0]
                if camera is None
                else f"camera given in the Recording step: {camera_text(camera)}"
            )
            # the recording's clipped background, as fit and the command draw it
            clipped = fitted_clip(frame, fit.scene, fit.camera, microscope.modality)
            exported = (*exported, layout != tuple(full))
            return fit, result, final, exported, camera_note, (clipped, camera is None)

        self.worker = Job(
            lambda: (yield from blocking_steps(compute, cancelled.is_set)),
            cancelled=cancelled,
            total=0,
            description="SyMBac diagnose",
            what="Diagnose",
            on_yield=self._on_progress,
            on_return=self._on_returned,
            on_error=self._on_errored,
            on_abort=self._on_cancelled,
            on_finish=self._on_finished,
            owner=self.native,
        )
        self.worker.stop_if_removed(self.viewer.layers, (self.reference.value,))
        self._layer = self.reference.value
        self._microscope = microscope
        self._region = region
        self.run_button.enabled = False
        self.cancel_button.enabled = True
        self._window_note = _frame_words(self.reference.value, self.viewer)
        self._window_note += self._window_note_of(region, full, how)
        self.status.value = "Fitting the scene..." + self._window_note
        self.report.value = ""  # found as a user: a failed run left the last one's report
        self.worker.start()

    def _window_note_of(
        self, region: tuple[int, int, int, int], full: tuple[int, ...], how: str
    ) -> str:
        """What the status lines add about the window: which one, when not the whole
        frame, and that it may take long when larger than the centre window may be (as
        the CLI, a large window is diagnosed: the user chose it)."""
        from napari_symbac.diagnose.region import MAX_DIAGNOSIS_PIXELS

        note = ""
        if region != (0, full[0], 0, full[1]):
            note = f" (in {window_words(region, full, how)}"
            note += (
                ": a diagnosis's time and memory grow faster than its pixels; "
                f"'{WINDOW_LABEL}' picks another window)"
                if how != "chosen"
                else ")"
            )
        y0, y1, x0, x1 = region
        pixels, cap = (y1 - y0) * (x1 - x0), self.max_pixels or MAX_DIAGNOSIS_PIXELS
        if pixels > cap:
            note += (
                f" ({pixels:,} pixels, more than the {cap:,} of 'cells': a diagnosis's "
                "time and memory grow faster than its pixels, so this one may take long "
                "and much memory; Cancel stops it)"
            )
        return note

    def cancel(self) -> None:
        """Stop the diagnosis at its next check; nothing is added."""
        if self.worker is not None:
            self.worker.quit()
            self.status.value = "Cancelling..."

    def _simulation_to_export(self):
        """The simulation of the newest simulated layer (the Simulate tab's choices, or
        Auto-fit's), the defaults without one: the base that the diagnosis' own fit
        updates (:func:`~napari_symbac.fit.fitted_settings.fitted_or_kept`)."""
        from napari_symbac.settings import PipelineSettings

        for layer in reversed(self.viewer.layers):
            meta = layer.metadata.get(SYMBAC_METADATA_KEY) or {}
            settings = meta.get("settings")
            if meta.get("simulation") is not None and isinstance(settings, PipelineSettings):
                return settings.simulation
        return PipelineSettings().simulation

    def _on_progress(self, message) -> None:
        """The scene fit's renders (a negative total), then the held-out checks, each with
        the window (found as a user: minutes of "Fitting the scene..." with no count on a
        ColiCoords field, and the window's note gone once the checks were counted)."""
        done, total = message
        if total < 0:
            self.status.value = (
                f"Fitting the scene: {done} of at most {-total} renders" + self._window_note
            )
        elif total > 1:
            self.status.value = (
                f"Diagnosing: {done} of at most {total} held-out checks" + self._window_note
            )

    def _on_returned(self, output) -> None:
        from napari_symbac.diagnose.stages import updated_settings
        from napari_symbac.fit.clipped_background import drawn_clipped
        from napari_symbac.settings import PipelineSettings

        fit, result, (final_render, held), exported, camera_note, (clipped, noise) = output
        simulation, kept, windowed = exported
        self.result = result
        camera = fit.camera
        base = PipelineSettings(
            simulation=simulation,
            microscope=self._microscope,
            render=final_render,  # the intensities refitted with the effects
            camera=camera,
        )
        settings, extra = updated_settings(base, result.accepted)
        if clipped is not None:  # the recording's background clipped at 0, as drawn
            settings, _ = drawn_clipped(settings, clipped, noise=noise)
        layer = self._layer
        scale = tuple(layer.scale[-2:])
        y0, _, x0, _ = self._region  # the layers sit over the window diagnosed
        translate = (layer.translate[-2] + y0 * scale[0], layer.translate[-1] + x0 * scale[1])
        kwargs = {"scale": scale, "units": tuple(layer.units[-2:]), "translate": translate}
        # one scale for both residuals: compared by eye before and after the effects
        limits = symmetric_limits(result.residual_before[0], floor=3.0)
        for name in [n for n in self.viewer.layers if str(n).startswith("diagnosis ")]:
            self.viewer.layers.remove(name)
        add_residual_layer(
            self.viewer,
            result.residual_before[0],
            name=DIAGNOSIS_RESIDUAL_LAYER,
            limits=limits,
            metadata={
                SYMBAC_METADATA_KEY: {
                    "settings": settings,
                    "extra_stages": extra,
                    "diagnosis": result.as_dict(),
                    # Export names it: its images are the window's size
                    WINDOW_KEY: tuple(result.residual_before[0].shape) if windowed else None,
                }
            },
            **kwargs,
        )
        add_residual_layer(
            self.viewer,
            result.residual_after[0],
            name=DIAGNOSIS_AFTER_LAYER,
            limits=limits,
            visible=False,
            metadata=output_metadata("Diagnose"),
            **kwargs,
        )
        for effect in result.accepted:
            if effect.effect_map is None:
                continue
            emap = np.asarray(effect.effect_map[0], float)
            span = max(float(np.abs(emap).max()), 1e-12)
            self.viewer.add_image(
                emap,
                name=effect_layer_name(effect.name),
                colormap=RESIDUAL_COLORMAP,
                contrast_limits=(-span, span),
                visible=False,
                metadata=output_metadata("Diagnose"),
                **kwargs,
            )
        from napari_symbac.diagnose.stages import drawn_by_export
        from napari_symbac.fit.report import base_fit_problems

        accepted = [e.name for e in result.accepted]
        if kept:
            simulated = f"the simulation is kept as it was ({kept})"
        else:
            where = "the diagnosed window" if windowed else "the recording"
            simulated = f"the cells and layout fitted, sized as {where}"
        residual_hint = f"see the layer '{DIAGNOSIS_RESIDUAL_LAYER}'"
        # as the command warns (found as a user: unsaid), the base fit's problems first
        problems = [
            f"base fit: {p}" for p in base_fit_problems(fit, self._microscope, residual_hint)
        ]
        cautions = problems + result.cautions(residual_hint, GUI_CAMERA_FIX)
        # what changed leads the report, in lines of the box's width; the status keeps
        # to the outcome (found as a user: 17 lines of status left the report 2 lines of
        # the dock at 1366 x 768)
        said = [
            f"Export now takes the updated settings (its 'settings from' names the "
            f"'{DIAGNOSIS_RESIDUAL_LAYER}' layer, which carries them): {simulated}"
            + (f"; {drawn_by_export(accepted)}." if accepted else "."),
            f"{camera_note[:1].upper()}{camera_note[1:]}.",
            *([f"Note: {held}."] if held else []),
            *(f"CAUTION: {p}" for p in problems),
            f"Layers '{DIAGNOSIS_RESIDUAL_LAYER}' (the base fit) and "
            f"'{DIAGNOSIS_AFTER_LAYER}' (with the effects), in s.d. of the noise: "
            f"{RESIDUAL_LEGEND}.",
        ]
        preamble = "\n".join(
            textwrap.fill(line, REPORT_COLUMNS, subsequent_indent="  ") for line in said
        )
        report = result.report(residual_hint, GUI_CAMERA_FIX)
        self.report.value = f"{preamble}\n\n{report}"
        names = ", ".join(accepted) or "nothing significant"
        count = f"{len(cautions)} caution" + ("s" if len(cautions) > 1 else "")
        self.status.value = (
            f"Accepted: {names}{self._window_note}. "
            + (f"{count}, what Export draws" if cautions else "What Export draws")
            + " and the camera are said at the top of the report below."
        )
        if cautions:
            notify_warning("Diagnose: " + "; ".join(cautions))

    def _on_cancelled(self) -> None:
        self.status.value = f"Diagnosis cancelled{removed_words(self.worker)}: nothing added"

    def _on_errored(self, err: BaseException) -> bool:
        from napari_symbac.fit import FitCancelled
        from napari_symbac.fit.start import FaintStartError, WideStartError

        if isinstance(err, (FitCancelled, InterruptedError)) or self.worker.cancelled.is_set():
            self._on_cancelled()
            return True
        fix = {WideStartError: WIDE_START_FIX, FaintStartError: FAINT_START_FIX}.get(type(err))
        if fix is not None:  # the engine's words (--masks) are the CLI's, not this dock's
            self.status.value = f"Diagnosis failed: {err.cause}; {fix}"
            notify_warning(self.status.value)
            return True
        self.status.value = f"Diagnosis failed: {err}"
        return False

    def _on_finished(self) -> None:
        self.worker = None
        self.run_button.enabled = True
        self.cancel_button.enabled = False
        if self.status.value.startswith(("Fitting", "Diagnosing", "Cancelling")):
            self.status.value = "Diagnosis stopped"
