"""Dock widget: simulate growth in a worker thread, preview live, render with masks.

The headless calls behind it are :func:`napari_symbac.sim.Simulator` and
:func:`napari_symbac.pipeline.render_simulation`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from magicgui.widgets import CheckBox, ComboBox, Container, PushButton

from napari_symbac._widgets._backend import backend_combo
from napari_symbac._widgets._forms import SettingsForm, hide_label, message_label
from napari_symbac._widgets._jobs import Job
from napari_symbac._widgets._links import ViewerLinks
from napari_symbac._widgets._recording import (
    PIXEL_PROBLEM_KEY,
    axis_labels,
    first_frame,
    followed_layer,
    in_pixel_units,
    layer_axes,
    layer_pixel_size_um,
    modality_render,
    output_metadata,
    real_images,
    recording_camera,
    recording_class_means,
    recording_microscope,
    recordings,
    watch_recordings,
)
from napari_symbac.fit.preflight import camera_pixel_problem
from napari_symbac.io import SYMBAC_METADATA_KEY
from napari_symbac.settings import Microscope, PipelineSettings, SimulationSettings

if TYPE_CHECKING:
    import napari

__all__ = [
    "DRAWN_PIXEL_KEY",
    "FITTED_TO_KEY",
    "PREVIEW_LAYER",
    "RESULT_IMAGE_LAYER",
    "RESULT_LABELS_LAYER",
    "RESULT_OPL_LAYER",
    "RESULT_TRACKS_LAYER",
    "SYMBAC_METADATA_KEY",
    "SimulateWidget",
]

PREVIEW_LAYER = "simulation preview"
RESULT_IMAGE_LAYER = "synthetic"
RESULT_LABELS_LAYER = "synthetic labels"
#: The simulation's ground-truth tracks (a Tracks layer, hidden at first).
RESULT_TRACKS_LAYER = "synthetic tracks"
#: Metadata key of a layer of Simulate's that holds no settings (its tracks): the pixel
#: size it was drawn at, so that it moves between pixels and micrometres with the others.
DRAWN_PIXEL_KEY = "drawn_pixel_um"
RESULT_OPL_LAYER = "synthetic optical path length"
#: How the status starts while no recording is chosen and an image waits to be one.
WAITING_WORDS = "Built-in settings:"
#: Key, in a rendered layer's SyMBac metadata, of the name of the recording Auto-fit
#: fitted the layer's settings to (absent until a fit).
FITTED_TO_KEY = "fitted_to"


class SimulateWidget(Container):
    """Simulation settings form with Run / Cancel, a progress bar and a live preview.

    While the simulation runs, the ``simulation preview`` labels layer shows the cells
    of the newest frame; when it finishes, every frame is rendered and shown as the
    ``synthetic`` image layer with its ``synthetic labels`` instance masks (cell ids
    consistent over time). Cancelling removes the preview and leaves earlier results
    untouched.

    With a recording chosen (a real image whose pixel size was set in *Real image and
    classes*), its pixel size, microscope and modality are simulated, and its measured
    class means start the intensities; every layer is scaled to micrometres.
    """

    def __init__(self, viewer: napari.viewer.Viewer, settings: PipelineSettings | None = None):
        super().__init__(name="symbac_simulate", labels=True)
        self.viewer = viewer
        #: the settings each run starts from (the recording, the form and the geometry's
        #: optics change them); ``pipeline`` holds the last run's
        self.given = settings or PipelineSettings()
        self.pipeline = self.given
        self.recording = ComboBox(
            name="recording",
            label="your recording",
            choices=lambda _w=None: recordings(viewer),
            nullable=True,
            tooltip=(
                "Simulate with this recording's pixel size, microscope and modality "
                "(set them in 'Real image and classes'); none: the built-in microscope."
            ),
        )
        self.form = SettingsForm(
            SimulationSettings,
            self.given.simulation,
            name="settings",
            label="simulation",
            title="simulation",
        )
        self.show_opl = CheckBox(
            name="show_opl",
            text="also show optical path length (eq. OPL1-3)",
            tooltip="Add a hidden layer of the optical path length at render resolution.",
        )
        self.backend = backend_combo()
        self.run_button = PushButton(
            text="Run simulation", name="run", tooltip="Simulate growth, then render every frame."
        )
        self.cancel_button = PushButton(
            text="Cancel", name="cancel", enabled=False, tooltip="Stop; nothing is kept."
        )
        self.status = message_label("status")
        # Run, Cancel and the status above the form's ~30 rows: found as a user at 1366 x
        # 768, the Run button lay below them, out of sight until scrolled to
        self.extend(
            [
                self.recording,
                self.backend,
                self.show_opl,
                self.run_button,
                self.cancel_button,
                self.status,
                self.form,
            ]
        )
        hide_label(self.form)
        hide_label(self.status)
        if hasattr(self.form, "geometry"):
            self.form.geometry.changed.connect(self._show_geometry_settings)
            self._show_geometry_settings()
        self.worker: Job | None = None  # before the recordings are followed
        self._source = ""  # where the running simulation's camera and intensities come from
        self._compared_with = ""  # the name of the recording it was chosen beside
        self._warning = ""  # the recording's pixel-size problem, said while it runs
        self._scale_of = None  # the recording whose camera it renders with
        self._followed: tuple | None = None  # the recording as last followed
        self.recording.changed.connect(self._follow_recording)
        self._links = ViewerLinks(self.native)
        watch_recordings(viewer, self._refresh_recordings, self._links)
        self._refresh_recordings()
        self.run_button.changed.connect(self.run)
        self.cancel_button.changed.connect(self.cancel)
        self.simulation = None
        self.series = None
        self._n_frames = 0

    def _refresh_recordings(self, _event=None) -> None:
        """Offer the viewer's recordings; pick the newest when none is chosen, and follow
        the chosen one again when its pixel size or modality changed (found as a user:
        a crop taken for phase contrast stayed simulated as a trench after its modality
        was set to fluorescence)."""
        self.recording.reset_choices()
        choices = [c for c in self.recording.choices if c is not None]
        followed = followed_layer(_event, choices, busy=self.worker is not None)
        if followed is not None and followed is not self.recording.value:
            self.recording.value = followed
        elif self.recording.value is None and choices:
            self.recording.value = choices[-1]
        elif self.recording.value is None and self.worker is None:
            if note := self._waiting_note():
                self.status.value = note
        elif self.recording.value is not None and (
            _followed_key(self.recording.value) != self._followed
        ):
            self._follow_recording(self.recording.value)
        if self.recording.value is not None and self.status.value.startswith(WAITING_WORDS):
            self.status.value = ""  # the image waited for is the recording now

    def _waiting_note(self) -> str:
        """Without a chosen recording: the built-in settings, and which images wait for
        their pixel size to be offered (found as a user: a TIFF without one was not
        offered, the run used the built-in settings, and nothing said either)."""
        if self.recording.value is not None:
            return ""
        images = real_images(self.viewer)
        refused = [layer for layer in images if layer.metadata.get(PIXEL_PROBLEM_KEY)]
        if refused:  # found as a user: 65 typed, "once its pixel size is entered" said
            layer = refused[-1]
            return (
                f"{WAITING_WORDS} {layer.name} is not offered as your recording: "
                f"{layer.metadata[PIXEL_PROBLEM_KEY]}; correct it in step 1, Recording"
            )
        waiting = [layer.name for layer in images]
        if not waiting:
            return ""
        return (
            f"{WAITING_WORDS} {', '.join(waiting)} "
            f"{'is' if len(waiting) == 1 else 'are'} offered as your recording once "
            "its pixel size is entered (step 1, Recording)"
        )

    def _follow_recording(self, layer=None) -> None:
        """A newly chosen recording sets the geometry as ``napari-symbac fit`` would
        choose it for that image: a trench of the recording's size when it is a phase
        image at most :data:`~napari_symbac.fit.preflight.TRENCH_MAX_WIDTH_PX` wide and
        twice as tall (:meth:`_size_trench`), else an agar pad (found
        as a user: an open fluorescence field was simulated, and Auto-fitted, as a
        trench), the pad the size of the recording (a 500 px pad beside a 512 px field
        left a strip of the recording uncovered). The form can still be changed after."""
        from napari_symbac.calibrate.core import pad_edge_margin_um
        from napari_symbac.fit.preflight import default_geometry

        if layer is None or not hasattr(self.form, "geometry"):
            return
        self._followed = _followed_key(layer)
        microscope = recording_microscope(layer, self.given.microscope)
        rows, cols = (int(n) for n in layer.data.shape[-2:])
        field = default_geometry((rows, cols), microscope.modality) == "field"
        self.form.geometry.value = "agar_pad" if field else "trench"
        if not field and hasattr(self.form, "trench"):
            self._size_trench(rows, cols, microscope.pixel_size_um)
        pad = getattr(self.form, "agar_pad", None)
        if field and pad is not None:
            width_um, height_um = cols * microscope.pixel_size_um, rows * microscope.pixel_size_um
            # a small field keeps room inside its margin (as calibrate lays a pad out)
            margin = pad_edge_margin_um(width_um, height_um, pad.edge_margin_um.value)
            pad.edge_margin_um.value = round(margin, 3)
            pad.field_width_um.value = width_um
            pad.field_height_um.value = height_um
            self._lay_out_as(layer, microscope)

    def _lay_out_as(self, layer, microscope: Microscope) -> None:
        """The pad's colonies as the recording's clusters of cells, before any fit
        (:func:`~napari_symbac.calibrate.core.rough_pad_layout` of its first frame; found
        as a user: a ColiCoords field of eight cells was simulated as one founder on an
        empty pad, in fluorescence and then in bright field, and a phase colony of 77
        cells as one founder grown 60 frames to 7 cells). Said in the status; Auto-fit
        lays it out from the fitted cells."""
        from napari_symbac.calibrate.core import rough_pad_layout

        frame = first_frame(layer).astype(np.float64)
        settings = self.form.value
        layout = rough_pad_layout(
            frame,
            microscope.pixel_size_um,
            settings.cell_width_um,
            settings.cell_max_length_um,
            microscope.modality,
        )
        if layout is None:  # no cell to see: the defaults' colony
            return
        fields, note = layout
        try:
            self.form.value = dataclasses.replace(settings, **fields)
        except ValueError as err:  # e.g. more colonies than the pad has room for
            self.status.value = f"The pad is not laid out as {layer.name}: {err}"
            return
        self.status.value = f"{layer.name}: {note}"

    def _size_trench(self, rows: int, cols: int, pixel_um: float) -> None:
        """Frames of the recording's size: the trench and its margins of PDMS as wide as
        the recording (``cols`` pixels of ``pixel_um``; the margins shrink for a narrow
        one, then the trench), the trench as long as it less the top margin (a fitted
        ``top_margin_um``, else the sides'; found as a user: the default trench was drawn
        46 px wide beside a 32 px wide recording). The width and margins start from the
        dock's own settings, not the form's last sizing (found as a user: a pixel size
        typed 10 times too large and then corrected left a trench 3 um wide without
        walls, the whole frame)."""
        trench, own = self.form.trench, self.given.simulation.trench
        width_um, height_um = cols * pixel_um, rows * pixel_um
        room = max((width_um - own.width_um) / 2, 0.0)
        margin = round(min(own.margin_um, room), 3)
        top = trench.value.top_margin_um  # a fitted closed end's place, kept
        trench.margin_um.value = margin
        trench.width_um.value = round(width_um - 2 * margin, 3)
        trench.length_um.value = round(height_um - (margin if top is None else top), 3)

    def pipeline_settings(self) -> PipelineSettings:
        """The settings to run: the form, and the chosen recording's microscope.

        Raises
        ------
        ValueError
            If the form's settings are invalid.
        """
        return self._settings_and_source()[0]

    def _settings_and_source(self) -> tuple[PipelineSettings, str, bool]:
        """:meth:`pipeline_settings`, where the chosen recording's camera and intensities
        come from, in words ("" without a recording), and whether the render is on the
        recording's scale (its camera used).

        The recording's camera (given, else measured from it, as ``napari-symbac fit``
        does) and its class means above that camera's offset (painted, else a rough
        split of cells and background): found as a user, an 8-bit colony (54-241) was
        simulated at 2488-2909 ADU with the built-in camera and intensities. A recording
        the fit refuses (a constant image, normalised values opened by napari's own
        reader) keeps the built-in camera, and the built-in intensities unless painted,
        said with the reason.
        """
        pipeline = dataclasses.replace(self.given, simulation=self.form.value)
        layer = self.recording.value
        if layer is None:
            return _halo_on_pads(pipeline), "", False
        microscope = recording_microscope(layer, pipeline.microscope)
        modality = microscope.modality
        refused = ""
        try:
            camera, camera_from = recording_camera(layer)
        except ValueError as err:
            camera, camera_from, refused = pipeline.camera, "built in", f" ({err})"
        means, means_from = None, "the built-in defaults"
        if not refused or layer.metadata.get("class_means_adu"):
            means, means_from = recording_class_means(layer, modality, camera.baseline_adu)
        render = modality_render(pipeline.render, modality, means)
        source = f"camera {camera_from}, intensities from {means_from}{refused}"
        chosen = {"microscope": microscope, "render": render, "camera": camera}
        pipeline = _halo_on_pads(dataclasses.replace(pipeline, **chosen))
        if pipeline.render.phase_model == "partially_coherent":
            source += "; the cells drawn by their phase (the colony fit's starting optics)"
        return pipeline, source, not refused

    def _show_geometry_settings(self, _value=None) -> None:
        """Show only the sub-form of the chosen geometry (the trench also sizes a chamber)."""
        kind = self.form.geometry.value
        visible = {
            "trench": kind in ("trench", "chamber"),
            "agar_pad": kind == "agar_pad",
            "outline": kind == "outline",
        }
        for name, show in visible.items():
            if hasattr(self.form, name):
                getattr(self.form, name).visible = show

    # -- actions -------------------------------------------------------------------------

    def run(self) -> None:
        """Validate the form and start simulating and rendering in a worker thread."""
        if self.worker is not None:
            return
        try:
            pipeline, source, on_its_scale = self._settings_and_source()
        except ValueError as err:
            self.status.value = f"Invalid settings: {err}"
            return
        recording = self.recording.value
        self._source = f"{recording.name}: {source}" if source else self._waiting_note()
        # found as a user: a 10x pixel size, warned in the Recording step, ran here for
        # minutes with no word (cells 1.3 px wide on a 423 um pad): said while it runs
        slip = recording is not None and camera_pixel_problem(
            pipeline.microscope, where="the Recording step"
        )
        self._warning = f"<br>Warning: {slip}" if slip else ""
        self._source += self._warning
        self._compared_with = recording.name if recording is not None else ""
        self._scale_of = recording if on_its_scale else None
        sim_settings = pipeline.simulation
        n_frames = sim_settings.n_frames
        self._n_frames = n_frames
        self._pixel_um = pipeline.microscope.pixel_size_um
        with_opl = self.show_opl.value
        backend = self.backend.value
        steps = (3 if with_opl else 2) * n_frames

        def work():
            from napari_symbac.pipeline import RenderedSeries, draw_frame, iter_render
            from napari_symbac.scene import draw_scene, field_of
            from napari_symbac.sim import Simulator

            simulator = Simulator(sim_settings, np.random.default_rng(sim_settings.seed))
            field = field_of(sim_settings)
            for index, frame in enumerate(simulator.iter_frames()):
                scene = draw_scene(
                    frame, sim_settings.trench, pipeline.microscope, pipeline.render, field=field
                )
                yield index + 1, ("simulated", index + 1, scene.camera_labels())
            simulation = simulator.result()
            frames = []
            for rendered in iter_render(simulation, pipeline, backend=backend):
                frames.append(rendered)
                yield n_frames + len(frames), ("rendered", len(frames), None)
            series = RenderedSeries.from_frames(frames)
            opl = None
            if with_opl:
                opl = []
                for index in range(n_frames):
                    scene = draw_frame(simulation, pipeline, index)
                    opl.append(scene.interior(scene.optical_path_length()))
                    yield 2 * n_frames + index + 1, ("opl", index + 1, None)
                opl = np.stack(opl)
            return simulation, pipeline, series, opl

        self.worker = Job(
            work,
            total=steps,
            description="SyMBac simulate + render",
            what="Simulation",
            on_yield=self._on_yielded,
            on_return=self._on_returned,
            on_error=self._on_errored,
            on_abort=self._on_aborted,
            on_finish=self._on_finished,
            owner=self.native,
        )
        self.run_button.enabled = False
        self.cancel_button.enabled = True
        self.status.value = "Simulating..." + self._warning
        self.worker.start()

    def cancel(self) -> None:
        """Stop the running worker at its next frame."""
        if self.worker is not None:
            self.status.value = "Cancelling..."
            self.worker.quit()

    # -- worker callbacks -----------------------------------------------------------------

    def _on_yielded(self, message) -> None:
        stage, done, labels = message
        if stage == "simulated":
            self.status.value = f"Simulated frame {done} of {self._n_frames}{self._warning}"
            placement = self._placement(self._pixel_um, 2)
            if PREVIEW_LAYER in self.viewer.layers:
                preview = self.viewer.layers[PREVIEW_LAYER]
                preview.data = labels
                _follow_placement(preview, placement)  # a pixel size entered meanwhile
            else:
                self.viewer.add_labels(labels, name=PREVIEW_LAYER, **placement)
        elif stage == "rendered":
            self._remove_preview()
            self.status.value = f"Rendered frame {done} of {self._n_frames}{self._warning}"
        else:
            self.status.value = f"Optical path length of frame {done}"

    def _on_returned(self, result) -> None:
        self.simulation, self.pipeline, self.series, opl = result
        self._remove_preview()
        metadata = {SYMBAC_METADATA_KEY: {"simulation": self.simulation, "settings": self.pipeline}}
        axes = self._placement(self.pipeline.microscope.pixel_size_um, 3)
        for name, data, kind in (
            (RESULT_IMAGE_LAYER, self.series.images, "image"),
            (RESULT_LABELS_LAYER, self.series.labels, "labels"),
        ):
            if name in self.viewer.layers:
                self.viewer.layers.remove(name)  # new shape, scale or modality
            if kind == "image":
                self.viewer.add_image(data, name=name, metadata=metadata, **axes)
            else:
                labels = self.viewer.add_labels(data, name=name, metadata=metadata, **axes)
                # outlines: filled, the labels hid the image (found as a user: Tune's
                # sliders changed the synthetic cells under solid colours, unseen)
                labels.contour = 1
        self._show_tracks(axes)
        if opl is not None:
            self._show_opl(opl, metadata)
        # the last frame's cells, to compare with the recording's (found as a user: "361
        # cells", the lineage's, read as the colony's 181)
        frames = self.simulation.frames
        self.status.value = (
            f"Done: {len(frames)} frames, {len(frames[-1].ids)} cells in the last "
            f"({len(self.simulation.lineage)} over the lineage)"
        )
        # napari shows a new stack's middle frame: without a recording its first, with one
        # its last, grown as the recording was laid out (found as a user: Sample000252's
        # colony was shown as the first frame's founder beside the recording's 77 cells)
        compared = self._compared_with
        recording = self.recording.value
        if recording is None or np.ndim(recording.data) < 3:
            self.viewer.dims.set_current_step(0, len(frames) - 1 if compared else 0)
        # else the frame of the time-lapse the user looks at stays (found as a user: the
        # slider moved to the simulation's last frame, and Auto-fit fitted another frame
        # of the recording than the one it had shown)
        if compared:
            self.status.value += f", shown to compare with {compared}"
        if RESULT_TRACKS_LAYER in self.viewer.layers:
            self.status.value += f" (their tracks: the layer '{RESULT_TRACKS_LAYER}')"
        if self._source:
            self.status.value += f"<br>{self._source}"
        shown_like = self._scale_of
        if shown_like is not None and shown_like in self.viewer.layers:
            # on the recording's scale: shown with its grey levels, like for like (each
            # layer's own range showed the synthetic pad white beside a grey one)
            self.viewer.layers[RESULT_IMAGE_LAYER].contrast_limits = shown_like.contrast_limits

    def _show_tracks(self, placement: dict) -> None:
        """The simulation's ground-truth tracks over its frames: a Tracks layer of each
        cell's centroid, frame by frame, with its divisions (the labels keep each cell's
        id over its life, its lineage names each daughter's mother), each track in its
        cell's label colour, as Auto-fit shows a fitted time-lapse's."""
        from napari_symbac._widgets._tracks import replace_tracks
        from napari_symbac.track_points import napari_tracks

        data, graph = np.zeros((0, 4)), {}
        if len(self.simulation.frames) >= 2:
            parents = {cell: record.parent_id for cell, record in self.simulation.lineage.items()}
            data, graph = napari_tracks(self.series.labels, parents)
        replace_tracks(
            self.viewer, RESULT_TRACKS_LAYER, data, graph,
            self.viewer.layers[RESULT_LABELS_LAYER], visible=False,
            metadata={**output_metadata("Simulate"),
                      DRAWN_PIXEL_KEY: self.pipeline.microscope.pixel_size_um},
            tail_length=min(10, len(self.simulation.frames)), **placement,
        )  # fmt: skip

    def _show_opl(self, opl: np.ndarray, metadata: dict) -> None:
        """Show the render-resolution OPL aligned with the camera-resolution layers."""
        placement = self._placement(self.pipeline.microscope.pixel_size_um, 3)
        pixel = placement.get("scale", (1.0,))[-1]  # of the camera, in its units
        upsample = self.pipeline.render.upsample
        # Camera pixel i covers render pixels upsample*i .. upsample*(i+1) - 1.
        offset = pixel * (1 / (2 * upsample) - 0.5)
        kwargs = {
            **placement,
            "scale": (1.0, pixel / upsample, pixel / upsample),
            "translate": (0.0, offset, offset),
            "metadata": metadata,
            "colormap": "magma",
        }
        if RESULT_OPL_LAYER in self.viewer.layers:
            self.viewer.layers.remove(RESULT_OPL_LAYER)
        self.viewer.add_image(opl, name=RESULT_OPL_LAYER, visible=False, **kwargs)

    def _placement(self, pixel_um: float, ndim: int) -> dict[str, tuple]:
        """Layer keyword arguments placing a new ``ndim``-axis layer drawn at ``pixel_um``.

        In micrometres (:func:`~napari_symbac._widgets._recording.layer_axes`), except
        while no recording is chosen and the viewer shows a layer still in pixels (an
        image whose pixel size is not entered yet): then in pixels, with a step of 1.
        napari compares the layers' units axis by axis and, when they differ, warns
        "Inconsistent units across layers" and drops them (found as a user). The
        *Recording* dock moves the layers to micrometres when the pixel size is entered.
        """
        if self.recording.value is None and _shown_in_pixels(self.viewer):
            return {"axis_labels": axis_labels(ndim)}
        return layer_axes(pixel_um, ndim)

    def _on_aborted(self) -> None:
        self._remove_preview()
        self.status.value = "Cancelled: nothing was kept"

    def _on_errored(self, err: BaseException) -> None:
        self._remove_preview()
        self.status.value = f"Failed: {err}"

    def _on_finished(self) -> None:
        self.worker = None
        self.run_button.enabled = True
        self.cancel_button.enabled = False

    def _remove_preview(self) -> None:
        if PREVIEW_LAYER in self.viewer.layers:
            self.viewer.layers.remove(PREVIEW_LAYER)


def _halo_on_pads(pipeline: PipelineSettings) -> PipelineSettings:
    """``pipeline`` with an agar pad in phase contrast drawn through the partially
    coherent model at the colony fit's start
    (:func:`~napari_symbac.fit.colony.colony_phase_render`): found as a user, the linear
    kernel drew a real colony's pad as dark rods on a flat grey (normalised background
    0.95 against the recording's 0.44, Omnipose's Sample000252), without the halo around
    the colony and the bright seams between its cells. A trench keeps the linear kernel
    of the supplement (eq. 7-15)."""
    from napari_symbac.fit.colony import colony_phase_render

    if pipeline.microscope.modality != "phase" or pipeline.simulation.geometry != "agar_pad":
        return pipeline
    render = colony_phase_render(pipeline.render, pipeline.microscope)
    return dataclasses.replace(pipeline, render=render)


def _followed_key(layer) -> tuple:
    """What the form follows of a recording: which layer, its pixel size and modality."""
    return id(layer), layer_pixel_size_um(layer), layer.metadata.get("modality")


def _follow_placement(layer, placement: dict[str, tuple]) -> None:
    """Give a ``(Y, X)`` layer the scale and units of ``placement`` when they differ."""
    scale = tuple(placement.get("scale", (1.0, 1.0)))
    units = tuple(placement.get("units", ("pixel", "pixel")))
    if in_pixel_units(layer) != (units[-1] == "pixel") or tuple(layer.scale) != scale:
        layer.scale = scale
        layer.units = units


def _shown_in_pixels(viewer: napari.viewer.Viewer) -> bool:
    """Whether the viewer shows a layer of the user's (not Simulate's) still in pixels."""
    return any(
        in_pixel_units(layer)
        for layer in viewer.layers
        if SYMBAC_METADATA_KEY not in layer.metadata
        and DRAWN_PIXEL_KEY not in layer.metadata
        and layer.name != PREVIEW_LAYER
    )
