"""Dock widget: tune PSF, intensities and noise live on a rendered simulation.

Headless equivalent: :class:`napari_symbac.fit.live.LivePreview`.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FloatSlider,
    Image,
    PushButton,
    SpinBox,
    Table,
)

from napari_symbac._widgets._forms import hide_label, message_label
from napari_symbac._widgets._jobs import Job, blocking_steps, notify_warning, removed_words
from napari_symbac._widgets._links import ViewerLinks
from napari_symbac._widgets._recording import (
    GUI_CAMERA_FIX,
    GUI_MODALITY_ADVICE,
    RECORDING_STEP,
    axis_labels,
    check_recording_frame,
    choose_masks,
    followed_layer,
    given_camera,
    is_recording,
    layer_pixel_size_um,
    mask_layers,
    modality_render,
    no_recording_message,
    output_metadata,
    pixel_size_problem,
    real_images,
    recording_microscope,
    shown_frame,
    watch_recordings,
)
from napari_symbac._widgets._residual import add_residual_layer
from napari_symbac._widgets.real_image import class_layer_name
from napari_symbac._widgets.simulate import FITTED_TO_KEY, SYMBAC_METADATA_KEY

if TYPE_CHECKING:
    import napari
    from napari_symbac.settings import Microscope

__all__ = [
    "FIT_RESIDUAL_LAYER",
    "FIT_SYNTHETIC_LAYER",
    "FIT_TRACKS_LAYER",
    "FIT_TRACK_MASKS_LAYER",
    "SLIDERS",
    "TuneWidget",
    "convergence_caption",
    "convergence_plot",
    "terms_plot",
]

#: Layers the auto-fit adds: the fitted scene rendered, and real minus it.
FIT_SYNTHETIC_LAYER = "auto-fit synthetic"
FIT_RESIDUAL_LAYER = "auto-fit residual"
#: ... and after a joint fit of a time-lapse, the cells' tracks (a Tracks layer) and
#: every frame's fitted cells labelled by track id (a Labels layer).
FIT_TRACKS_LAYER = "auto-fit tracks"
FIT_TRACK_MASKS_LAYER = "auto-fit track masks"

#: Largest relative difference in size between the real image and the rendered frames
#: that matching pads or crops away (the rendered trench has a margin of a pixel or two).
MATCH_SIZE_TOLERANCE = 0.1

#: Slider name -> (label, minimum, maximum). Each name is a RenderSettings field.
SLIDERS: dict[str, tuple[str, float, float]] = {
    "cell_intensity": ("cell intensity (ADU)", 0.0, 20000.0),
    "media_intensity": ("media intensity (ADU)", 0.0, 20000.0),
    "device_intensity": ("device intensity (ADU)", 0.0, 20000.0),
    "apodisation_sigma_um": ("apodisation sigma (um)", 0.05, 3.0),
    "defocus_sigma_um": ("defocus sigma (um)", 0.0, 1.0),
    "ring_contrast": ("ring contrast", 0.0, 3.0),
    "psf_offset": ("PSF offset", -0.05, 0.05),
    "gaussian_noise_sd_adu": ("gaussian noise sd (ADU)", 0.0, 1000.0),
    # the partially coherent phase model's own (docs/physics.md), shown in its place of
    # ring contrast and PSF offset (COHERENT_ONLY, LINEAR_ONLY)
    "cell_phase_rad": ("cell phase (rad)", 0.0, 3.0),
    "phase_ring_width_scale": ("phase ring width", 0.5, 3.0),
    "plate_transmission": ("phase plate transmission", 0.02, 1.0),
    # bright field's lens term of cells out of focus (docs/physics.md)
    "defocus_contrast_um2": ("lens term (um^2)", -0.1, 0.1),
}
#: Sliders of one phase model only: the other model, fluorescence (an Airy PSF) and
#: bright field leave the image unchanged.
COHERENT_ONLY = ("cell_phase_rad", "phase_ring_width_scale", "plate_transmission")
LINEAR_ONLY = ("ring_contrast", "psf_offset")
#: The phase-contrast PSF's, of both phase models; unused by fluorescence and bright field.
PHASE_ONLY = ("apodisation_sigma_um",)
#: The cell intensity's tooltip in the partially coherent phase model, where a cell's
#: intensity is its bright-field transmission ``B = I_c / I_m`` (docs/physics.md).
COHERENT_CELL_TIP = (
    "In this phase model the cells are dark by their phase (cell phase), not by their "
    "intensity: cell intensity / media intensity is their bright-field transmission B, "
    "1 (equal intensities) for transparent cells as in real phase contrast; lower it "
    "only for cells that absorb."
)
#: Sliders of bright field only; the phase kernel's are hidden there.
BRIGHTFIELD_ONLY = ("defocus_contrast_um2",)
#: Sliders of the gaussian noise model only; camera noise and none leave the image unchanged.
GAUSSIAN_NOISE_ONLY = ("gaussian_noise_sd_adu",)


#: Colours of the values before and after the fit (:func:`terms_plot`, the squares of
#: :func:`convergence_plot`) and of the convergence curve.
BEFORE_COLOUR = (150, 150, 150)
AFTER_COLOUR = (255, 150, 40)
CURVE_COLOUR = (240, 240, 240)


def terms_plot(terms: dict[str, tuple[float, float]], width: int = 240) -> np.ndarray:
    """A small RGB bar chart of objective terms: grey before, orange after (per term).

    Each pair of bars is scaled to the larger of the two, so every term shows how
    much the fit reduced it. A term that is not a finite number (NaN: e.g. an edge
    profile with too few painted edge pixels) is drawn as a red stripe, not a bar.
    """
    bar, gap = 7, 5
    height = max(1, len(terms)) * (2 * bar + gap) + gap
    image = np.full((height, width, 3), 40, np.uint8)
    for row, (before, after) in enumerate(terms.values()):
        top = gap + row * (2 * bar + gap)
        finite = [abs(v) for v in (before, after) if np.isfinite(v)]
        scale = max(finite, default=0.0) or 1.0
        for offset, value, colour in ((0, before, BEFORE_COLOUR), (bar, after, AFTER_COLOUR)):
            rows = slice(top + offset, top + offset + bar - 1)
            if not np.isfinite(value):
                image[rows, 1 : width - 1 : 4] = (220, 40, 40)
                continue
            length = round((width - 2) * abs(value) / scale)
            image[rows, 1 : 1 + length] = colour
    return image


def convergence_plot(
    history: Sequence[float],
    objective_before: float,
    objective_after: float,
    width: int = 240,
    height: int = 70,
) -> np.ndarray:
    """A small RGB line plot of the fit's reduced chi-square per accepted step, beside
    the objective at the start and at the end (the status line's).

    Log scale from the lowest to the highest value; a white line on the dark background
    of :func:`terms_plot`, the start's objective a grey square at the left edge and the
    end's an orange one at the right edge (its colours), a grey line at reduced chi-square 1 when it
    is within the range. Non-finite values are left out. :func:`convergence_caption`
    says the numbers.
    """
    image = np.full((height, width, 3), 40, np.uint8)
    values = _positive(history)
    ends = _positive([objective_before, objective_after])
    if values.size + ends.size == 0:
        return image
    logs = np.log10(values)
    everything = np.log10(np.concatenate([values, ends]))
    low, high = float(everything.min()), float(everything.max())
    span = max(high - low, 1e-6)

    def row_of(value: float) -> int:
        return round((height - 4) * (1 - (value - low) / span)) + 2

    if low <= 0.0 <= high:
        image[row_of(0.0), 1 : width - 1] = (110, 110, 110)
    if values.size:
        xs = np.linspace(6, width - 7, max(values.size, 2)).round().astype(int)
        ys = [row_of(v) for v in (logs if logs.size > 1 else np.repeat(logs, 2))]
        for (x0, y0), (x1, y1) in zip(zip(xs, ys), zip(xs[1:], ys[1:])):
            steps = max(abs(x1 - x0), abs(y1 - y0), 1)
            rr = np.linspace(y0, y1, steps + 1).round().astype(int)
            cc = np.linspace(x0, x1, steps + 1).round().astype(int)
            image[rr, cc] = CURVE_COLOUR
    for value, column, colour in (
        (objective_before, 2, BEFORE_COLOUR),
        (objective_after, width - 3, AFTER_COLOUR),
    ):
        if np.isfinite(value) and value > 0:
            row = row_of(float(np.log10(value)))
            image[row - 1 : row + 2, column - 1 : column + 2] = colour
    return image


def convergence_caption(
    history: Sequence[float], objective_before: float, objective_after: float
) -> str:
    """What :func:`convergence_plot` shows, in words and numbers: its axes, the curve's
    first and last values, and the objective at the start and the end.

    The curve is not the objective: each step's reduced chi-square is weighed with the
    noise model of its reweighting round, re-estimated between rounds, and the moves
    add and remove cells, so it may rise where the objective (the pixel term, weighed
    with the fitted noise model at the start and at the end) fell (found as a user:
    ColiCoords ds1 00002, objective 4.415 -> 2.497 and a curve that rose).
    """
    values = _positive(history)
    objective = (
        f"Objective (pixel term, weighed with the fitted noise model): start "
        f"{_format(objective_before)} (grey square) -> end {_format(objective_after)} "
        "(orange square)."
    )
    if values.size == 0:
        return f"{objective} No fit step was recorded."
    everything = _positive([*values, objective_before, objective_after])
    steps = "step" if values.size == 1 else "steps"
    # the plot draws the line at 1 only within its range (found as a user: said, not drawn)
    one = ", a grey line at 1" if everything.min() <= 1.0 <= everything.max() else ""
    return (
        f"{objective} White line: reduced chi-square after each of the fit's "
        f"{values.size} accepted {steps} (x, in order), {_format(values[0])} at the first, "
        f"{_format(values[-1])} at the last; y: log scale, {_format(everything.min())} to "
        f"{_format(everything.max())}{one}. Each step is weighed with its "
        "round's noise model, re-estimated between rounds, and cells are added and removed "
        "between them: where the line rises, the weights or the cells changed, not the fit "
        "got worse."
    )


def _positive(values: Sequence[float]) -> np.ndarray:
    """The finite positive ``values`` (a log scale's)."""
    return np.asarray([v for v in values if np.isfinite(v) and v > 0], float)


def _fit_to_shape(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Centre-crop or reflect-pad ``image`` to ``shape`` (sizes within 10 %).

    Raises
    ------
    ValueError
        If a side differs by more than :data:`MATCH_SIZE_TOLERANCE`.
    """
    for have, want in zip(image.shape, shape):
        if abs(have - want) > MATCH_SIZE_TOLERANCE * want:
            raise ValueError(
                f"the real image ({image.shape[0]} x {image.shape[1]} px) and the rendered "
                f"frames ({shape[0]} x {shape[1]} px) differ by more than "
                f"{MATCH_SIZE_TOLERANCE:.0%}: simulate a field of the recording's size "
                "(trench length = rows x pixel size) or crop the real image to it"
            )
    out = image
    for axis, want in enumerate(shape):
        have = out.shape[axis]
        if have > want:
            start = (have - want) // 2
            out = np.take(out, range(start, start + want), axis=axis)
        elif have < want:
            pad = [(0, 0), (0, 0)]
            pad[axis] = ((want - have) // 2, want - have - (want - have) // 2)
            out = np.pad(out, pad, mode="reflect")
    return out


class TuneWidget(Container):
    """Sliders for the forward model's parameters, updating the preview while dragging.

    Choose a rendered layer (made by *Simulate and render*). Each change re-renders the
    frame on screen from cached convolutions; other frames are re-rendered when you
    step to them. The tuned settings are written back into the layer's metadata, so
    an export from that layer uses them. With a real image chosen, the preview can be
    matched to its Fourier spectrum and histogram.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(name="symbac_tune")
        self.viewer = viewer
        self.source = ComboBox(name="source", label="rendered layer", choices=self._rendered)
        self.reference = ComboBox(
            name="reference", label="real image", choices=self._references, nullable=True
        )
        self.masks = ComboBox(
            name="masks", label="cell masks", choices=self._mask_layers, nullable=True
        )
        self.modality = ComboBox(
            name="modality", label="modality", choices=["phase", "fluorescence", "brightfield"]
        )
        self.noise_model = ComboBox(
            name="noise_model", label="noise", choices=["camera", "gaussian", "none"]
        )
        self.sliders = {
            name: FloatSlider(name=name, label=label, min=low, max=high, readout=True)
            for name, (label, low, high) in SLIDERS.items()
        }
        from napari_symbac._widgets._forms import parameter_docs
        from napari_symbac.settings import RenderSettings

        self._docs = parameter_docs(RenderSettings)
        for name, slider in self.sliders.items():
            slider.tooltip = self._docs.get(name, slider.label)
        self.source.tooltip = "The rendered layer to tune (made by Simulate and render)."
        self.reference.tooltip = "The real recording to compare with, match to and fit to."
        self.masks.tooltip = (
            "Instance masks of the real image (a Labels layer, 0 background, one number per "
            "cell, e.g. from Cellpose or Omnipose): Auto-fit starts from these cells; a "
            "phase-contrast colony is then fitted with the partially coherent model (halo, "
            "bright seams). Empty: painted classes or the fit's own segmentation."
        )
        self.modality.tooltip = (
            "phase: dark cells on bright media; fluorescence: bright cells on a dark "
            "background; brightfield: cells that absorb a little, seen out of focus by "
            "their lens term (switching sets intensities of that polarity)."
        )
        self.noise_model.tooltip = "camera: shot + read noise (eq. 17); gaussian: fixed sd."
        self.match_fourier = CheckBox(name="match_fourier", text="match Fourier spectrum")
        self.match_histogram = CheckBox(name="match_histogram", text="match histogram")
        self.match_noise = CheckBox(name="match_noise", text="match noise")
        self.match_fourier.tooltip = (
            "Give the preview the real image's Fourier amplitude spectrum (SyMBac's matching)."
        )
        self.match_histogram.tooltip = "Map the preview's grey levels to the real image's."
        self.match_noise.tooltip = (
            "Gaussian noise with the sd measured on the real image (SyMBac's match_noise)."
        )
        self.status = message_label("status")
        self.fit_iterations = SpinBox(
            name="fit_iterations",
            label="fit iterations",
            value=25,
            min=1,
            max=500,
            tooltip="Gauss-Newton iterations per reweighting round of the scene fit (and of "
            "the joint refinement of a time-lapse).",
        )
        self.fit_all_frames = CheckBox(
            name="fit_all_frames",
            text="all frames jointly (a time-lapse)",
            tooltip=(
                "Fit every frame of the real time-lapse at once: one set of optics and one "
                "camera for all frames, each frame its own cells and intensities, cells "
                "linked into tracks (as napari-symbac fit --frames). Unticked: the frame shown."
            ),
        )
        self.fit_envelope_stain = CheckBox(
            name="fit_envelope_stain",
            text="stain in the cell envelope (membrane dye)",
            tooltip=(
                "Fluorescence: fit, with the cells and optics, the fraction of the stain in "
                "the cell envelope (cells brighter at the rim than on the centre line), as "
                "napari-symbac fit --envelope-stain; Export draws it."
            ),
        )
        self.fit_depth = CheckBox(
            name="fit_depth",
            text="image the cells in depth (eq. 16)",
            tooltip=(
                "Fluorescence: image the stain in slabs through the cells, each through the "
                "PSF defocused by its distance from the focal plane, which is fitted (a "
                "cell's top and bottom are out of focus), as napari-symbac fit "
                "--depth-layers 5; a fit takes 2-5 times as long. Export draws it."
            ),
        )
        self.fit_button = PushButton(
            name="fit",
            text="Auto-fit to the real image",
            tooltip=(
                "Fit cells, trench, optics and intensities so the rendered image overlays "
                "the real one (analysis by synthesis); painted classes add eq. 20 terms."
            ),
        )
        self.cancel_fit_button = PushButton(
            name="cancel_fit", text="Cancel fit", enabled=False, tooltip="Stop the fit."
        )
        self.terms_table = Table(name="terms", label="objective terms")
        self.terms_table.native.setMinimumWidth(0)  # scrolls inside; never widens the dock
        # its three columns share the width (found as a user: at 1366 x 768 the "after"
        # column was cut, behind a sideways scroll bar), no row numbers
        header = self.terms_table.native.horizontalHeader()
        header.setSectionResizeMode(header.ResizeMode.Stretch)
        self.terms_table.native.verticalHeader().setVisible(False)
        self.terms_image = Image(
            name="terms_plot",
            label="before (grey) / after (orange)",
            tooltip=(
                "Objective terms before and after the fit; below them the reduced "
                "chi-square after every fit step, between the objective at the start "
                "(grey) and at the end (orange): the caption below says the numbers"
            ),
        )
        # found as a user: a bare line, no axes or numbers, that rose while the
        # objective fell, read as a fit that got worse
        self.convergence_caption = message_label("convergence")
        # Auto-fit, its options and its result above the sliders' ~15 rows: found as a
        # user at 1366 x 768, the button lay below them, out of sight until scrolled to
        self.extend(
            [
                self.source,
                self.reference,
                self.masks,
                self.modality,
                self.noise_model,
                self.fit_iterations,
                self.fit_all_frames,
                self.fit_envelope_stain,
                self.fit_depth,
                self.fit_button,
                self.cancel_fit_button,
                self.status,
                self.terms_table,
                self.terms_image,
                self.convergence_caption,
                *self.sliders.values(),
                self.match_fourier,
                self.match_histogram,
                self.match_noise,
            ]
        )
        hide_label(self.status)  # its words take the dock's whole width
        self.terms_image.visible = False
        self.terms_table.visible = False  # an empty table until a fit fills it
        self.convergence_caption.visible = False
        self.fit_button.changed.connect(self.auto_fit)
        self.cancel_fit_button.changed.connect(self.cancel_fit)
        self.fit_worker: Job | None = None
        self._fit_notes: list[str] = []  # what the running fit cannot do (fit_notes)
        self._fit_microscope: Microscope | None = None  # the recording's, of the last fit
        self._camera_given = False  # the last fit's camera came from the Recording step
        self.fit_result = None
        self._modality = None
        self._polarity_changed = False
        self.preview = None
        self._stale: set[int] = set()
        self._loading = False
        self.source.changed.connect(self._load_source)
        for widget in (*self.sliders.values(), self.modality, self.noise_model):
            widget.changed.connect(self._on_parameter)
        for widget in (self.reference, self.match_fourier, self.match_histogram):
            widget.changed.connect(self._on_matching)
        self.reference.changed.connect(self._match_noise)
        self.reference.changed.connect(self._choose_masks)
        self.reference.changed.connect(self._follow_modality)
        self.match_noise.changed.connect(self._match_noise)
        self._links = ViewerLinks(self.native)
        self._links.connect(viewer.dims.events.current_step, self._on_step)
        watch_recordings(viewer, self._refresh_choices, self._links)
        self._choose_reference()  # a dock opened after the recording (found as a user)
        self._load_source()

    # -- choices --------------------------------------------------------------------------

    def _rendered(self, _widget=None) -> list:
        return [
            layer
            for layer in self.viewer.layers
            if "simulation" in (layer.metadata.get(SYMBAC_METADATA_KEY) or {})
            and layer.data.ndim == 3
            and not hasattr(layer, "selected_label")
        ]

    def _choose_reference(self, event=None) -> None:
        """The recording opened last (:func:`followed_layer`), else, with none chosen,
        the newest one whose pixel size is set."""
        recordings = [c for c in self.reference.choices if c is not None and is_recording(c)]
        followed = followed_layer(event, recordings, busy=self.fit_worker is not None)
        if followed is not None and followed is not self.reference.value:
            self.masks.value = None  # chosen for the recording before
            self.reference.value = followed
        elif self.reference.value is None and recordings:
            self.reference.value = recordings[-1]

    def _references(self, _widget=None) -> list:
        return real_images(self.viewer)

    def _mask_layers(self, _widget=None) -> list:
        return mask_layers(self.viewer)

    def _refresh_choices(self, _event=None) -> None:
        previous = self.source.value
        self.source.reset_choices()
        self.reference.reset_choices()
        self.masks.reset_choices()
        self._choose_reference(_event)
        if getattr(_event, "type", "") == "inserted":  # masks opened after the recording
            self._choose_masks(only=_event.value)
        if self.source.value is not previous:
            self._load_source()
        self._follow_modality()  # its modality set in the Recording step

    def _follow_modality(self, _value=None) -> None:
        """The preview takes the chosen recording's modality, as Simulate does (found as
        a user: a bright-field recording chosen beside a phase-contrast preview stayed
        compared with phase contrast until Auto-fit); the intensities of its polarity
        (:meth:`_switch_modality`). Not while a fit runs: it switches the preview itself."""
        layer = self.reference.value
        modality = None if layer is None else layer.metadata.get("modality")
        if (
            modality in self.modality.choices
            and modality != self.modality.value
            and self.preview is not None
            and self.fit_worker is None
        ):
            self.modality.value = modality  # _on_parameter switches the preview

    def _choose_masks(self, _value=None, *, only=None) -> None:
        """With no cell masks chosen, choose the newest Labels layer of instance masks of
        the real image's frame size (cells in it), when the real image is chosen and when
        such a layer is added. Found as a user: Omnipose's Sample000193 opened with its
        `_cp_masks.tif` (a Labels layer, as docs/gui.md says), then Auto-fit: the masks
        were not used, the colony was fitted without them for 13 min (reduced chi-square
        222, 45 of its 182 cells), and the report advised `napari-symbac fit --masks`.
        Choosing *cell masks* "-----" by hand keeps it so until another real image is
        chosen or masks are added (``only``: the layer just added, the one to consider)."""
        choose_masks(self.masks, self.viewer, self.reference.value, only)

    # -- state ----------------------------------------------------------------------------

    def _load_source(self, _value=None) -> None:
        from napari_symbac.fit.live import LivePreview
        from napari_symbac.pipeline import draw_frame

        layer = self.source.value
        if layer is None:
            self.preview = None
            self.status.value = "Render a simulation first (Simulate and render)"
            # nothing to tune: no slider (found as a user: twelve sliders at 0.00, the
            # phase ring's among them, beside a fluorescence recording)
            for slider in self.sliders.values():
                slider.visible = False
            return
        simulation = layer.metadata[SYMBAC_METADATA_KEY]["simulation"]
        settings = layer.metadata[SYMBAC_METADATA_KEY]["settings"]
        # the frames are drawn in the trench they were simulated in; after Auto-fit the
        # layer's settings hold the fitted simulation, which Export simulates anew
        drawn = dataclasses.replace(settings, simulation=simulation.settings)
        self.preview = LivePreview(
            lambda index: draw_frame(simulation, drawn, index),
            settings.microscope,
            settings.render,
            settings.camera,
            n_frames=len(simulation.frames),
            seed=settings.simulation.seed,
        )
        self._loading = True
        try:
            for name, slider in self.sliders.items():
                _set_slider(slider, getattr(settings.render, name))
                slider.visible = True  # then those of another model hidden
            self._show_model_sliders(settings.render, settings.microscope.modality)
            self.sliders["apodisation_sigma_um"].min = round(
                settings.microscope.min_apodisation_sigma_um, 3
            )
            self.modality.value = settings.microscope.modality
            self.noise_model.value = settings.render.noise_model
        finally:
            self._loading = False
        self._modality = settings.microscope.modality
        self._stale = set()
        self.status.value = ""

    def _current_frame(self) -> int:
        return int(self.viewer.dims.current_step[0]) if self.viewer.dims.ndim >= 3 else 0

    def _preview_frame(self) -> int:
        """The rendered frame shown: the current one, or the last the preview has when
        the slider stands beyond it (found as a user: a recording of 4 frames at frame 2
        beside a 2-frame simulation; Auto-fit's result was lost to an IndexError)."""
        return min(self._current_frame(), self.preview.n_frames - 1)

    def _show(self, index: int) -> None:
        layer = self.source.value
        image = self.preview.frame(index)
        info = np.iinfo(layer.data.dtype) if layer.data.dtype.kind in "ui" else None
        if info is not None:
            image = np.clip(np.rint(image), info.min, info.max)
        layer.data[index] = image.astype(layer.data.dtype)
        self._stale.discard(index)
        layer.refresh()

    def _show_model_sliders(self, render: Any, modality: str) -> None:
        """Only the sliders that change the image of the model in use: the phase kernel's
        in phase contrast (of its phase model), bright field's lens term, the gaussian
        noise sd with gaussian noise, the device's intensity where the simulation has a
        device (not an agar pad). Found as a user: in fluorescence ring contrast (and PSF
        offset, apodisation) moved and the image stayed the same."""
        phase = modality == "phase"
        coherent = phase and render.phase_model == "partially_coherent"
        layer = self.source.value
        pad = layer is not None and (
            layer.metadata[SYMBAC_METADATA_KEY]["simulation"].settings.geometry == "agar_pad"
        )
        shown = {
            "device_intensity": not pad,  # an agar pad has no device (found as a user)
            **dict.fromkeys(COHERENT_ONLY, coherent),
            **dict.fromkeys(LINEAR_ONLY, phase and not coherent),
            **dict.fromkeys(PHASE_ONLY, phase),
            **dict.fromkeys(BRIGHTFIELD_ONLY, modality == "brightfield"),
            **dict.fromkeys(GAUSSIAN_NOISE_ONLY, render.noise_model == "gaussian"),
        }
        for name, visible in shown.items():
            self.sliders[name].visible = visible
        # found as a user: cell intensity equal to the media's, read as a mistake
        self.sliders["cell_intensity"].tooltip = (
            COHERENT_CELL_TIP if coherent else self._docs.get("cell_intensity", "cell intensity")
        )
        fluorescence = modality == "fluorescence"
        for box in (self.fit_envelope_stain, self.fit_depth):
            box.visible = fluorescence
            if not fluorescence:  # a hidden box asks for nothing
                box.value = False

    def _store_fitted_simulation(self, result, colony_drawn=None) -> str:
        """The simulation the fit implies (the fitted cells' width and division length,
        the fitted trench or a pad laid out as the recording's field:
        :func:`~napari_symbac.fit.fitted_settings.fitted_simulation`, as in ``napari-symbac
        fit``'s settings.yaml) becomes the layer's, which Export simulates (found as a
        user: Export after Auto-fit drew the Simulate tab's 3.5 um cells in a 16 um trench
        for a recording of 5 um cells). The scene is sized in the recording's pixels; the
        status says so when the layer was simulated at another pixel size. A colony fit's
        simulation comes from the worker (``colony_drawn``: :func:`_colony_drawn`).
        Returns a sentence for the status."""
        from napari_symbac.fit.fitted_settings import fitted_simulation

        meta = self.source.value.metadata[SYMBAC_METADATA_KEY]
        shape = tuple(self.reference.value.data.shape[-2:])
        microscope = self._fit_microscope
        try:
            if colony_drawn is None:
                simulation = fitted_simulation(
                    meta["settings"].simulation, result, shape, microscope.pixel_size_um
                )
            elif colony_drawn[0] is None:
                raise ValueError(colony_drawn[1])
            else:
                simulation = colony_drawn[0].simulation
        except ValueError as err:
            return f"the simulation is kept as it was ({err})"
        meta["settings"] = dataclasses.replace(meta["settings"], simulation=simulation)
        drawn_um = meta["settings"].microscope.pixel_size_um
        if not math.isclose(drawn_um, microscope.pixel_size_um, rel_tol=1e-3):
            different = (
                f"; it is drawn at this layer's {drawn_um:g} um per pixel, not the "
                f"recording's {microscope.pixel_size_um:g}: Simulate again with the "
                "recording chosen there to export frames of the recording's pixels"
            )
        else:
            different = ""
        where = (
            f"a {simulation.trench.length_um:.1f} um trench"
            if simulation.geometry in ("trench", "chamber")
            else f"{simulation.agar_pad.n_colonies} "
            f"{'colony' if simulation.agar_pad.n_colonies == 1 else 'colonies'} on a pad the "
            "recording's size"
            + (
                f", packed as the recording's (gravity {simulation.gravity:g} um/min)"
                if colony_drawn is not None and simulation.gravity
                else ""
            )
        )
        return (
            f"Export simulates cells {simulation.cell_width_um:.2f} um wide dividing at "
            f"{simulation.cell_max_length_um:.2f} um in {where}, as fitted{different}"
        )

    def _mark_fitted(self) -> None:
        """Note in the rendered layer's metadata the recording its settings are now fitted
        to, and say so (``events.metadata``): Export's list then names the layer as
        fitted (found as a user: it still read "synthetic" after Auto-fit)."""
        layer = self.source.value
        layer.metadata[SYMBAC_METADATA_KEY][FITTED_TO_KEY] = self.reference.value.name
        layer.events.metadata()

    def _store_settings(self) -> None:
        layer = self.source.value
        meta = layer.metadata[SYMBAC_METADATA_KEY]
        meta["settings"] = dataclasses.replace(
            meta["settings"],
            microscope=self.preview.model.microscope,
            render=self.preview.render_settings,
            camera=self.preview.model.camera,
        )

    # -- events ---------------------------------------------------------------------------

    def _on_parameter(self, _value: Any = None) -> None:
        if self._loading or self.preview is None:
            return
        if self.fit_worker is not None:
            self.status.value = "Fitting: wait for the fit or cancel it"
            return
        if self.modality.value != self._modality:
            self._switch_modality(self.modality.value)
        changes = {name: slider.value for name, slider in self.sliders.items()}
        changes["noise_model"] = self.noise_model.value
        changes["modality"] = self.modality.value
        try:
            self.preview.update(**changes)
            self._stale = set(range(self.preview.n_frames))
            self._show(self._preview_frame())
        except ValueError as err:
            self.status.value = f"Not applied: {err}"
            return
        self.status.value = ""
        self._show_model_sliders(self.preview.render_settings, self.modality.value)
        self._store_settings()
        if self._polarity_changed:  # new grey levels: show them
            self._polarity_changed = False
            self.source.value.reset_contrast_limits()

    def _switch_modality(self, modality: str) -> None:
        """Intensities of the new modality's polarity: the recording's class means when
        it is of that modality, else the modality's defaults (fluorescence: bright cells
        on a dark background)."""
        reference = self.reference.value
        means = None
        if reference is not None and reference.metadata.get("modality") == modality:
            means = reference.metadata.get("class_means_adu")
        render = modality_render(self.preview.render_settings, modality, means)
        self._loading = True
        try:
            for name, slider in self.sliders.items():
                _set_slider(slider, float(getattr(render, name)))
            self._show_model_sliders(render, modality)
        finally:
            self._loading = False
        self._modality = modality
        self._polarity_changed = True

    def _on_matching(self, _value: Any = None) -> None:
        """Match the preview to the real image (its spectrum, its histogram), and say so
        (found as a user: ticking either box left the status line blank)."""
        matching = self.match_fourier.value or self.match_histogram.value
        if self.preview is None:
            if matching:
                self.status.value = "Not applied: nothing rendered to match; run Simulate first"
            return
        if not matching and self.preview.reference is None:
            return  # nothing to match, nothing matched before
        try:
            frame = self._reference_frame() if matching else None
            self.preview.set_reference(
                frame,
                fourier=self.match_fourier.value,
                histogram=self.match_histogram.value,
            )
            self._stale = set(range(self.preview.n_frames))
            self._show(self._preview_frame())
        except ValueError as err:
            self.status.value = f"Not applied: {err}"
            return
        what = [name for name, on in (("Fourier spectrum", self.match_fourier.value),
                                      ("histogram", self.match_histogram.value)) if on]
        self.status.value = (
            f"Preview matched to the {' and '.join(what)} of '{self.reference.value.name}'"
            if what and self.reference.value is not None
            else "Preview no longer matched to the real image"
        )

    # -- auto-fit -------------------------------------------------------------------------

    def auto_fit(self) -> None:
        """Fit the scene (cells, trench, optics, intensities) to the real image, in a worker.

        Runs :func:`napari_symbac.fit.fit_scene` on the chosen real image with its
        recording's microscope (pixel size set in *Real image and classes*) and the
        painted classes when there are any (:func:`~napari_symbac.fit.fit_colony` for a
        phase colony with its masks). With *all frames jointly* ticked, every frame of
        the time-lapse at once (:func:`~napari_symbac.fit.fit_series`,
        :func:`~napari_symbac.fit.fit_colony_series`): the shown frame's fitted settings
        go to the sliders, the synthetic and residual layers hold every frame. Progress
        and cancel go through napari's activity dock and the Cancel fit button; the
        fitted render settings become the rendered layer's settings (so Export uses them).
        """
        if self.fit_worker is not None:
            return
        all_frames = self.fit_all_frames.value
        try:
            job_input = self._fit_input(all_frames)
        except ValueError as err:
            self.status.value = str(err)
            notify_warning(str(err))
            return
        real, labels, masks, microscope, render, camera, geometry = job_input
        self._fit_microscope = microscope  # the recording's: it sizes the fitted scene
        self._camera_given = camera is not None
        from napari_symbac.fit.colony import is_dense_colony
        from napari_symbac.fit.report import fit_notes

        frames_masks = [] if masks is None else (masks if all_frames else [masks])
        colony = geometry == "open" and any(
            is_dense_colony(m, microscope.modality) for m in frames_masks
        )  # a time-lapse: once any frame is a colony, every frame is drawn alike (as the CLI)
        self._fit_notes = fit_notes(microscope.modality, geometry, colony=colony)
        if not colony and (render.phase_separate or render.phase_model != "linear"):
            # the scene fit's one linear kernel, whatever drew the layer (found as a
            # user: Simulate draws a phase pad with the colony's partially coherent
            # model, and Auto-fit without masks was refused, naming parameters no
            # control of the dock sets)
            render = dataclasses.replace(
                render, phase_model="linear", cell_phase_adu=None, device_phase_adu=None
            )
        options = {}
        stain_boxes = [b for b in (self.fit_envelope_stain, self.fit_depth) if b.value]
        if stain_boxes and microscope.modality != "fluorescence":
            message = (
                f"'{stain_boxes[0].text}' is fitted in fluorescence; this recording is "
                f"{microscope.modality}: untick it"
            )
            self.status.value = message
            notify_warning(message)
            return
        if self.fit_envelope_stain.value:
            from napari_symbac.fit.scene_fit import ENVELOPE_FIT_OPTICS, envelope_stain_start

            options["fit_optics"] = ENVELOPE_FIT_OPTICS
            render = envelope_stain_start(render)
        if self.fit_depth.value:
            from napari_symbac.fit.scene_fit import DEPTH_FIT_LAYERS, depth_fit_optics, depth_start

            options["fit_optics"] = depth_fit_optics(options.get("fit_optics"))
            render = depth_start(render, DEPTH_FIT_LAYERS)
        if masks is not None and labels is not None:
            self._fit_notes.append("the cell masks were used; the painted classes were not")
        iterations = self.fit_iterations.value
        if all_frames:  # the joint refinement's too (found as a user: "stopped at the
            # iteration limit (15)" whatever 'fit iterations' said)
            options["joint_iterations"] = iterations
        cancelled = threading.Event()

        def fit(progress, cancel):
            from napari_symbac.fit import fit_colony, fit_colony_series, fit_scene, fit_series

            if colony:
                fit_one = fit_colony_series if all_frames else fit_colony
                return fit_one(real, microscope, masks, progress=progress, cancel=cancel)
            return (fit_series if all_frames else fit_scene)(
                real,
                microscope,
                render,
                camera,
                labels=None if masks is not None else labels,
                masks=masks,
                geometry=geometry,
                max_iterations=iterations,
                progress=progress,
                cancel=cancel,
                **options,
            )

        shown = self._current_frame()
        advice = GUI_CAMERA_FIX
        if masks is None and labels is None and microscope.modality == "phase":
            advice += (
                "; a dense phase-contrast colony is fitted from its instance masks: choose "
                "them as 'cell masks'"
            ) * (geometry != "trench")

        layer_settings = self.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]

        def work():
            result = yield from blocking_steps(fit, cancelled.is_set)
            frame = real[min(shown, len(real) - 1)] if all_frames else real
            shown_fit = _shown_fit(result, shown)
            clipped = _clipped_background(shown_fit, frame, microscope)
            # a measured camera is checked model-free, as `fit` does without --camera
            check = _camera_check(shown_fit, frame, advice) if camera is None else None
            drawn = (  # simulated colonies (seconds of physics): not in the GUI thread
                _colony_drawn(layer_settings, shown_fit, frame.shape, microscope, cancelled)
                if colony
                else None
            )
            return _FitOutcome(result, shown, clipped, check, drawn)

        self.fit_worker = Job(
            work,
            cancelled=cancelled,
            total=0,
            description="SyMBac auto-fit",
            what="Auto-fit",
            on_yield=self._on_fit_progress,
            on_return=self._on_fit_returned,
            on_error=self._on_fit_errored,
            on_abort=self._on_fit_cancelled,
            on_finish=self._on_fit_finished,
            owner=self.native,
        )
        self.fit_worker.stop_if_removed(
            self.viewer.layers, (self.reference.value, self.source.value)
        )
        self.fit_button.enabled = False
        self.cancel_fit_button.enabled = True
        self.status.value = "Fitting..."
        self.fit_worker.start()

    def _fit_input(self, all_frames: bool = False) -> tuple:
        """Real frame, painted classes and cell masks (or ``None``), microscope, render,
        camera, geometry; with ``all_frames`` the ``(T, Y, X)`` stacks of the time-lapse.

        Raises
        ------
        ValueError
            With what to do, when something needed is missing.
        """
        reference = self.reference.value
        if self.preview is None:
            raise ValueError(
                "No rendered layer: Auto-fit starts from a rendered layer's optics and "
                "geometry. Run Simulate first (with your recording chosen there), then fit"
            )
        if reference is None:
            raise ValueError(
                no_recording_message(self.viewer, "choose it as the real image here")
            )
        settings = self.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
        problem = pixel_size_problem(layer_pixel_size_um(reference))
        if problem is not None:  # never the simulation's pixel size (found as a user: an
            # image without one was fitted at the preview's 0.065 um)
            raise ValueError(f"{reference.name}: {problem} in {RECORDING_STEP}, then fit it")
        microscope = recording_microscope(reference, self.preview.model.microscope)
        real = np.asarray(reference.data)
        if all_frames and (real.ndim != 3 or len(real) < 2):
            raise ValueError(
                f"'all frames jointly' fits a time-lapse, but the real image '{reference.name}' "
                "is a single frame: untick it to fit this frame"
            )
        from napari_symbac.fit.preflight import (
            check_instance_masks,
            check_modality,
            lying_trench_problem,
        )

        pick = self._frames_of if all_frames else self._frame_of
        real = real if all_frames else self._frame_of(real)  # a time-lapse: checked above
        check_recording_frame(real, reference.name)  # as `napari-symbac fit`
        labels = None
        name = class_layer_name(reference.name)
        if name in self.viewer.layers:
            labels = pick(np.asarray(self.viewer.layers[name].data), name)
            painted = [bool(frame.any()) for frame in (labels if all_frames else [labels])]
            if not any(painted):
                labels = None
            elif not all(painted):
                raise ValueError(
                    f"the classes '{name}' are painted in some frames only: paint them in "
                    "every frame (or clear them all for the automatic start) to fit all "
                    "frames jointly"
                )
        masks = None
        if self.masks.value is not None:
            layer = self.masks.value
            masks = pick(np.asarray(layer.data), f"cell masks '{layer.name}'")
            for frame in masks if all_frames else [masks]:
                check_instance_masks(frame, real.shape[-2:], f"cell masks '{layer.name}'")
        # what `napari-symbac fit` refuses: a modality the image contradicts (the first
        # frame of a time-lapse speaks for it)
        def first(stack: np.ndarray | None) -> np.ndarray | None:
            return stack[0] if all_frames and stack is not None else stack

        check_modality(first(real), microscope.modality, labels=first(labels),
                       masks=first(masks), advice=GUI_MODALITY_ADVICE)  # fmt: skip
        if problem := lying_trench_problem(real.shape, microscope.modality, reference.name):
            raise ValueError(problem)
        # In fluorescence the device is as dark as the media: no wall to place, so the
        # cells are fitted as in an open field.
        walled = settings.simulation.geometry in ("trench", "chamber")
        geometry = "trench" if walled and microscope.modality == "phase" else "open"
        # The camera given in the Recording step, as `fit --camera`; without one the fit
        # measures it from the recording (photon transfer, then its residual), and the
        # fitted camera then renders the preview and the export.
        camera = given_camera(reference)
        return real, labels, masks, microscope, self.preview.render_settings, camera, geometry

    def _frame_of(self, data: np.ndarray, _name: str = "") -> np.ndarray:
        """The frame shown of ``data`` (a 2D layer is every frame's)."""
        return shown_frame(self.viewer, data)

    def _frames_of(self, data: np.ndarray, name: str) -> np.ndarray:
        """Every frame of layer ``name``'s ``data`` for a joint fit of the real
        time-lapse: one per frame of it."""
        n_frames = len(self.reference.value.data)
        if data.ndim == 2:
            raise ValueError(
                f"{name} holds one frame but the real time-lapse has {n_frames}: give "
                "every frame its own (or untick 'all frames jointly')"
            )
        if len(data) != n_frames:
            raise ValueError(
                f"{name} has {len(data)} frames but the real time-lapse has {n_frames}: "
                "give every frame its own"
            )
        return data

    def cancel_fit(self) -> None:
        """Stop the fit before its next render; the parameters stay as they were."""
        if self.fit_worker is not None:
            self.fit_worker.quit()
            self.status.value = "Cancelling the fit..."

    def _on_fit_progress(self, message) -> None:
        done, total = message
        # the total is a bound that a converging fit stays far below (found as a user: "365
        # of about 80168 renders" for a joint fit that ended at ~760)
        # found as a user: "472 renders (at most 45684)" read as hours still to go
        self.status.value = (
            f"Fitting: {done} renders so far (a converging fit ends far below its bound "
            f"of {total})"
        )

    def _on_fit_returned(self, outcome: _FitOutcome) -> None:
        from napari_symbac.fit import ColonyFit
        from napari_symbac.fit.clipped_background import with_clip
        from napari_symbac.fit.fitted_settings import fitted_render
        from napari_symbac.fit.report import (
            cells_counted,
            colony_gains_text,
            fit_problems,
            lens_problem,
            read_noise_note,
            unmeasured_noise_adu,
        )

        result, clipped = outcome.result, outcome.clipped
        self.fit_result = result
        series = _series_of(result)
        result = _shown_fit(result, outcome.shown)  # it sets the sliders (optics are shared)
        fit_render, fit_camera = (result.render, result.camera) if clipped is None else clipped[:2]
        fit_microscope = self._fit_microscope
        if not isinstance(result, ColonyFit):  # the cells' own brightness spread
            spread = fitted_render(
                result, fit_microscope.modality if fit_microscope else self.modality.value
            )
            fit_render = dataclasses.replace(
                fit_render,
                cell_brightness_cv=spread.cell_brightness_cv,
                cell_brightness_max_gain=spread.cell_brightness_max_gain,
            )
        colony_drawn = outcome.colony_drawn
        if colony_drawn is not None and colony_drawn[0] is not None:  # per drawn material
            fit_render = dataclasses.replace(
                fit_render, cell_phase_rad=colony_drawn[0].render.cell_phase_rad
            )
        fitted = {name: float(getattr(fit_render, name)) for name in self.sliders}
        # the preview takes the recording's modality with its fitted settings (found as a
        # user: a bright-field recording fitted beside a phase preview left the preview,
        # and Export, in phase contrast with the lens term unused)
        modality = self._fit_microscope.modality if self._fit_microscope else None
        self._loading = True
        try:
            if modality is not None and modality != self.modality.value:
                self.modality.value = modality
            for name, value in fitted.items():
                if np.isfinite(value):
                    _set_slider(self.sliders[name], value)
            self.noise_model.value = result.render.noise_model  # a colony fit: gaussian
            self._show_model_sliders(result.render, self.modality.value)
        finally:
            self._loading = False
        colony = isinstance(result, ColonyFit)
        simulated = ""
        try:
            camera = {} if fit_camera is None else dataclasses.asdict(fit_camera)
            render = fit_render
            if colony:  # its sampling was chosen for the recording's pixels
                from napari_symbac.fit.colony import resample_render

                render = resample_render(
                    render, result.pixel_size_um, self.preview.model.microscope
                )
            now = self.preview.render_settings
            drawn = ("upsample", "psf_radius_px", "envelope_stain_fraction", "depth_layers")
            switched = self.modality.value != self.preview.model.microscope.modality
            if switched or any(getattr(render, name) != getattr(now, name) for name in drawn):
                # the scenes are drawn at that sampling, with that stain, for that
                # modality (a fluorescence stain): a new preview draws them anew
                meta = self.source.value.metadata[SYMBAC_METADATA_KEY]
                meta["settings"] = dataclasses.replace(
                    meta["settings"],
                    microscope=dataclasses.replace(
                        meta["settings"].microscope, modality=self.modality.value
                    ),
                    render=render,
                    camera=dataclasses.replace(meta["settings"].camera, **camera),
                )
                self._load_source()
            else:
                self.preview.update(**dataclasses.asdict(render), **camera)
            self._stale = set(range(self.preview.n_frames))
            self._show(self._preview_frame())
            self._store_settings()
            if clipped is not None:  # Export clips the recorded values as the recording
                meta = self.source.value.metadata[SYMBAC_METADATA_KEY]
                meta["settings"] = dataclasses.replace(
                    meta["settings"],
                    extra_stages=with_clip(meta["settings"].extra_stages, clipped[2]),
                )
            simulated = self._store_fitted_simulation(result, colony_drawn)
            self._mark_fitted()
        except ValueError as err:
            notify_warning(f"The fitted settings were not applied to the preview: {err}")
        self._show_fit_layers(series or result)
        self.source.value.reset_contrast_limits()  # the fitted intensities may lie outside
        nan_terms = [
            name
            for name, pair in result.terms.items()
            if not all(np.isfinite(value) for value in pair)
        ]
        self.terms_table.value = {
            "term": list(result.terms),
            "before": [_format(before) for before, _ in result.terms.values()],
            "after": [_format(after) for _, after in result.terms.values()],
        }
        self.terms_table.visible = True
        before, after = result.objective_before, result.objective_after
        plot = np.concatenate(
            [terms_plot(result.terms), convergence_plot(result.history, before, after)]
        )
        self.terms_image.value = plot
        # magicgui's image takes what the layout leaves it (18 px under a long status):
        # ask for the plot's own height
        self.terms_image.native.setMinimumHeight(plot.shape[0])
        self.terms_image.visible = True
        self.convergence_caption.value = convergence_caption(result.history, before, after)
        self.convergence_caption.visible = True
        objective = f"{_format(result.objective_before)} -> {_format(result.objective_after)}"
        if series is None:
            # which frame of a time-lapse (found as a user: a fit of frame 15 of 30 never
            # said so, and its 2D layers lie over every frame)
            reference = self.reference.value
            series_frame = reference is not None and np.ndim(reference.data) == 3
            which = f" frame {outcome.shown} (of {len(reference.data)})" if series_frame else ""
            self.status.value = (
                f"Fitted{which} in {result.n_evaluations} renders: objective {objective}"
            )
        else:
            shown = _series_status(series, outcome.shown)
            self.status.value = f"{shown}<br>This frame: objective {objective}"
        if colony:
            from napari_symbac.fit.report import colony_noise_text

            self.status.value += (
                "<br>Colony fitted from its masks with the partially coherent phase model; "
                f"noise: Gaussian, {colony_noise_text(result)} (used by the preview and "
                "Export)"
            )
        elif fit_camera is not None:
            cam = fit_camera
            how = "given in the Recording step"
            how = how if self._camera_given else "measured from the recording"
            words = (
                f"{cam.sensitivity_adu_per_e:.3g} ADU/e-, read noise {cam.dark_noise_e:.3g} e-"
            )
            if (sd := unmeasured_noise_adu(cam)) is not None:  # found as a user: "0.001
                # ADU/e-, read noise 2.77e+04 e-" of a bright-field Auto-fit
                how = "not measurable from the recording"
                words = f"a constant noise of {sd:.3g} ADU s.d."
            self.status.value += (
                f"<br>Camera {how}: {words}, baseline {cam.baseline_adu:.4g} ADU (used by "
                "the preview and Export)"
            )
            said = None if self._camera_given else read_noise_note(cam)
            if said:
                self.status.value += f"<br>Note: {said}"
        if outcome.camera_check is not None:
            self.status.value += f"<br>Camera, model-free: {outcome.camera_check[0]}"
        if clipped is not None:
            self.status.value += f"<br>The recording's {clipped[3]}"
        if nan_terms:
            message = (
                f"Not computable (NaN): {', '.join(nan_terms)}; paint longer strokes of each "
                "class across the edges to get them"
            )
            self.status.value += f"<br>{message}"
            notify_warning(message)
        hint = f"see the layer '{FIT_RESIDUAL_LAYER}'; the Diagnose widget looks for it"
        problems = [p.removeprefix("warning: ") for p in fit_problems(result, residual_hint=hint)]
        if series is not None:  # the joint fit's own (the colony's are its frames')
            problems += [w for w in series.warnings if w not in problems]
        if outcome.camera_check is not None and outcome.camera_check[1] is not None:
            problems.append(outcome.camera_check[1])  # as in fit's report.txt
        if lens := lens_problem(result.render, self._fit_microscope):
            problems.append(lens)
        moves = tuple(getattr(result, "moves", ()) or ())
        lines = [f"{cells_counted(len(result.cells))} fitted"] + [simulated] * bool(simulated)
        if (gains := colony_gains_text(result)) is not None:
            lines.append(f"{gains[0].upper()}{gains[1:]} by Export")
        lines += [f"Moves: {'; '.join(moves)}"] if moves else []
        lines += [f"Problem: {problem}" for problem in problems]
        lines += [f"Note: {note}" for note in self._fit_notes]
        self.status.value += "".join(f"<br>{line}" for line in lines)
        if problems or self._fit_notes:
            notify_warning("Auto-fit: " + "; ".join([*problems, *self._fit_notes]))

    def _show_fit_layers(self, result) -> None:
        """The fitted synthetic image and the residual, over the real image (of every
        frame, for a joint fit of a time-lapse)."""
        reference = self.reference.value
        series = _series_of(result)
        if series is not None:
            synthetic = np.stack([frame.synthetic for frame in series.frames])
            residual = np.stack([frame.residual for frame in series.frames])
            axes = reference.ndim
        else:
            synthetic, residual, axes = result.synthetic, result.residual, 2
        kwargs = {
            "scale": tuple(reference.scale[-axes:]),
            "units": tuple(reference.units[-axes:]),
            "translate": tuple(reference.translate[-axes:]),
            "axis_labels": axis_labels(axes),
        }
        for name in (FIT_SYNTHETIC_LAYER, FIT_RESIDUAL_LAYER):
            if name in self.viewer.layers:
                self.viewer.layers.remove(name)
        self.viewer.add_image(
            np.asarray(synthetic),
            name=FIT_SYNTHETIC_LAYER,
            metadata=output_metadata("Auto-fit"),
            **kwargs,
        )
        add_residual_layer(
            self.viewer,
            np.asarray(residual),
            name=FIT_RESIDUAL_LAYER,
            visible=False,
            metadata=output_metadata("Auto-fit"),
            **kwargs,
        )
        # the fitted image in the real image's grey levels: compare them by eye
        self.viewer.layers[FIT_SYNTHETIC_LAYER].contrast_limits = reference.contrast_limits
        self._show_tracks(series, kwargs)

    def _show_tracks(self, series, placement: dict) -> None:
        """A joint fit's tracks as a Tracks layer over the recording, and every frame's
        fitted cells labelled by track id (hidden at first); a fit of one frame removes
        those of an earlier joint fit. Found as a user: after a joint fit the dock gave
        only counts ("22 tracks, 10 divisions"), nothing to see the links by."""
        from napari_symbac._widgets._tracks import replace_tracks

        for name in (FIT_TRACKS_LAYER, FIT_TRACK_MASKS_LAYER):
            if name in self.viewer.layers:
                self.viewer.layers.remove(name)
        if series is None or series.lineage is None:
            return
        lineage = series.lineage
        masks = lineage.track_masks(
            [frame.scene.camera_labels() for frame in series.frames],
            [frame.cells.ids for frame in series.frames],
        )
        metadata = output_metadata("Auto-fit")
        labels = self.viewer.add_labels(
            masks, name=FIT_TRACK_MASKS_LAYER, metadata=metadata, visible=False, **placement
        )
        data, graph = lineage.napari_tracks(masks)
        replace_tracks(
            self.viewer, FIT_TRACKS_LAYER, data, graph, labels, metadata=metadata,
            tail_length=len(series.frames), **placement,
        )  # fmt: skip

    def _on_fit_errored(self, err: BaseException) -> bool:
        from napari_symbac.fit import FitCancelled
        from napari_symbac.fit.start import FaintStartError, WideStartError

        if isinstance(err, FitCancelled):
            self._on_fit_cancelled()
            return True
        if isinstance(err, (WideStartError, FaintStartError)):
            # the start's refusal, with what to give: the status line and a warning, not
            # an error (found as a user: "Auto-fit failed" of a trench set to fluorescence)
            self.status.value = f"Not fitted: {err}"
            if isinstance(err, WideStartError):
                self.status.value += (
                    "; open the masks as a Labels layer and choose it as 'cell masks'"
                )
            else:
                self.status.value += (
                    " (open the masks as a Labels layer and choose it as 'cell masks', or "
                    "paint rough cell and media strokes in the Recording step)"
                )
            notify_warning(self.status.value)
            return True
        self.status.value = f"Fit failed: {err}"
        return False

    def _on_fit_cancelled(self) -> None:
        words = removed_words(self.fit_worker)
        self.status.value = f"Fit cancelled{words}: parameters unchanged"

    def _on_fit_finished(self) -> None:
        self.fit_worker = None
        self.fit_button.enabled = True
        self.cancel_fit_button.enabled = False
        if self.status.value.startswith(("Fitting", "Cancelling")):
            self.status.value = "Fit stopped"

    def _reference_frame(self, fit_shape: bool = True) -> np.ndarray | None:
        """The real frame shown, padded or cropped to the rendered frames' size."""
        reference = self.reference.value
        if reference is None:
            return None
        data = np.asarray(reference.data)
        frame = data[min(self._current_frame(), len(data) - 1)] if data.ndim == 3 else data
        source = self.source.value
        if fit_shape and source is not None and frame.shape != source.data.shape[-2:]:
            frame = _fit_to_shape(frame, source.data.shape[-2:])
        return frame

    def _match_noise(self, _value: Any = None) -> None:
        """Set Gaussian noise with the sd measured on the real image (SyMBac's match_noise)."""
        from napari_symbac.diagnose import estimate_noise_sd

        frame = self._reference_frame(fit_shape=False)
        if not self.match_noise.value or frame is None or self.preview is None:
            return
        try:
            sd = estimate_noise_sd(frame)
        except ValueError as err:
            self.status.value = f"Not applied: {err}"
            return
        slider = self.sliders["gaussian_noise_sd_adu"]
        self._loading = True
        try:
            self.noise_model.value = "gaussian"
            _set_slider(slider, sd)
        finally:
            self._loading = False
        self._on_parameter()
        self.status.value = f"Noise matched: Gaussian, sd {sd:.1f} ADU"

    def _on_step(self, _event=None) -> None:
        if self.preview is not None and self._preview_frame() in self._stale:
            self._show(self._preview_frame())


def _colony_drawn(
    settings, fit, shape: tuple[int, ...], microscope, cancelled: threading.Event
) -> tuple[Any, str]:
    """The layer's ``settings`` with the simulation a colony ``fit`` implies and its cells
    drawn as recorded (phase per drawn material, packing:
    :func:`~napari_symbac.fit.fitted_settings.colony_drawn`, as ``napari-symbac fit``'s
    settings.yaml), and ``""``; ``None`` and the reason when they would be invalid."""
    from napari_symbac.fit.fitted_settings import colony_drawn, fitted_simulation

    try:
        simulation = fitted_simulation(
            settings.simulation, fit, tuple(shape[-2:]), microscope.pixel_size_um
        )
        drawn = dataclasses.replace(settings, simulation=simulation, render=fit.render)
        return colony_drawn(drawn, fit, cancel=cancelled.is_set)[0], ""
    except ValueError as err:
        return None, str(err)


@dataclasses.dataclass(frozen=True)
class _FitOutcome:
    """What the Auto-fit worker hands back to the GUI thread.

    Attributes
    ----------
    result
        The fit (a joint fit of a time-lapse: every frame's).
    shown
        The frame shown when the fit started: its fit sets the sliders.
    clipped
        :func:`_clipped_background` of that frame, computed in the worker.
    camera_check
        :func:`_camera_check` of that frame (a measured camera), else ``None``.
    colony_drawn
        A colony fit's :func:`_colony_drawn`, computed in the worker.
    """

    result: Any
    shown: int
    clipped: tuple | None
    camera_check: tuple[str, str | None] | None
    colony_drawn: tuple[Any, str] | None = None


def _camera_check(result, frame: np.ndarray, advice: str) -> tuple[str, str | None] | None:
    """``napari-symbac fit``'s model-free check of a camera the fit measured
    (:func:`~napari_symbac.fit.report.model_free_camera_check`), run in the worker; None
    for a colony fit (Gaussian noise, no camera)."""
    from napari_symbac.fit import ColonyFit
    from napari_symbac.fit.report import model_free_camera_check

    if isinstance(result, ColonyFit) or result.camera is None:
        return None
    return model_free_camera_check(np.asarray(frame, np.float64), result.camera, advice)


def _clipped_background(result, frame: np.ndarray, microscope: Microscope) -> tuple | None:
    """A fluorescence recording's background clipped at 0 (background subtraction),
    fitted as censored (:mod:`napari_symbac.fit.clipped_background`, as ``napari-symbac
    fit`` and ``calibrate`` do).

    Runs in the Auto-fit worker (a dilation and a likelihood fit over the background).

    Parameters
    ----------
    result
        The fit of ``frame`` (of a time-lapse's joint fit: that frame's).
    frame
        The recorded frame shown when the fit started.
    microscope
        The recording's microscope (its modality).

    Returns
    -------
    tuple or None
        ``(render, camera, ClippedBackground, sentence)`` for the preview and Export, or
        None when the frame is not clipped, not fluorescence, or a colony fit.
    """
    from napari_symbac.fit import ColonyFit
    from napari_symbac.fit.camera_estimate import censored_pixels
    from napari_symbac.fit.clipped_background import clipped_background, clipped_render

    if isinstance(result, ColonyFit) or result.camera is None:
        return None
    if microscope.modality != "fluorescence":
        return None
    cells = result.scene.camera_labels() > 0
    clipped = clipped_background(frame, cells, censored_pixels(frame))
    if clipped is None:
        return None
    render, camera, sentence = clipped_render(result.render, result.camera, clipped)
    return render, camera, clipped, sentence


def _format(value: float) -> str:
    return f"{value:.4g}" if np.isfinite(value) else "NaN"


#: Sliders in ADU whose range follows the value set (:func:`_set_slider`).
INTENSITY_SLIDERS = ("cell_intensity", "media_intensity", "device_intensity")


def _set_slider(slider: FloatSlider, value: float) -> None:
    """Set ``slider`` to ``value``, widening its range (with room) when it lies outside:
    the slider rounds its limits, so a limit set to exactly ``value`` can reject it.
    An intensity far below its slider's range narrows the range to 4 x the value (found
    as a user: an 8-bit colony's 7.93 ADU sat at the left end of 0-20000 ADU, where
    the slider could not move it)."""
    if slider.name in INTENSITY_SLIDERS and 0 < 4 * value < slider.max:
        slider.max = 4 * value
    room = 0.25 * abs(value) + 1e-3
    if value > slider.max:
        slider.max = value + room
    if value < slider.min:
        slider.min = value - room
    slider.value = value


def _series_of(result):
    """``result`` when it is a time-lapse's joint fit (its ``frames`` one fit each), else
    ``None``."""
    from napari_symbac.fit import ColonySeriesFit, SeriesFit

    return result if isinstance(result, (SeriesFit, ColonySeriesFit)) else None


def _shown_fit(result, shown: int):
    """The fit of frame ``shown``: ``result`` itself, or that frame's of a joint fit."""
    series = _series_of(result)
    return result if series is None else series.frames[min(shown, len(series.frames) - 1)]


def _series_status(series, shown: int) -> str:
    """A joint fit of a time-lapse in a line or two: frames, shared optics, tracks."""
    shared = ", ".join(
        f"{name} {value:.4g} +- {se:.2g}" for name, (value, se) in series.shared().items()
    )
    lineage = series.lineage
    tracks = (
        ""
        if lineage is None
        else (
            f"; {len(lineage.tracks)} tracks, {len(lineage.divisions())} division(s) "
            f"(layers '{FIT_TRACKS_LAYER}' and '{FIT_TRACK_MASKS_LAYER}')"
        )
    )
    n_frames = len(series.frames)
    return (
        f"Fitted {n_frames} frames jointly (optics shared: {shared}){tracks}. The sliders "
        f"show frame {min(shown, n_frames - 1)}'s fit; the layers hold every frame"
    )
