"""Dock widget: tune PSF, intensities and noise live on a rendered simulation.

Headless equivalent: :class:`napari_symbac.fit.live.LivePreview`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FloatSlider,
    Image,
    Label,
    PushButton,
    Table,
)

from napari_symbac._widgets.real_image import class_layer_name
from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY

if TYPE_CHECKING:
    import napari

__all__ = ["SLIDERS", "TuneWidget", "terms_plot"]

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
}


def terms_plot(terms: dict[str, tuple[float, float]], width: int = 240) -> np.ndarray:
    """A small RGB bar chart of objective terms: grey before, orange after (per term).

    Each pair of bars is scaled to the larger of the two, so every term shows how
    much the fit reduced it.
    """
    bar, gap = 7, 5
    height = max(1, len(terms)) * (2 * bar + gap) + gap
    image = np.full((height, width, 3), 40, np.uint8)
    for row, (before, after) in enumerate(terms.values()):
        top = gap + row * (2 * bar + gap)
        scale = max(abs(before), abs(after)) or 1.0
        for offset, value, colour in ((0, before, (150, 150, 150)), (bar, after, (255, 150, 40))):
            length = round((width - 2) * abs(value) / scale)
            image[top + offset : top + offset + bar - 1, 1 : 1 + length] = colour
    return image


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
        self.modality = ComboBox(
            name="modality", label="modality", choices=["phase", "fluorescence"]
        )
        self.noise_model = ComboBox(
            name="noise_model", label="noise", choices=["camera", "gaussian", "none"]
        )
        self.sliders = {
            name: FloatSlider(name=name, label=label, min=low, max=high, readout=True)
            for name, (label, low, high) in SLIDERS.items()
        }
        self.match_fourier = CheckBox(name="match_fourier", text="match Fourier spectrum")
        self.match_histogram = CheckBox(name="match_histogram", text="match histogram")
        self.match_noise = CheckBox(
            name="match_noise", text="match noise (Gaussian, sd measured on the real image)"
        )
        self.status = Label(name="status", value="")
        self.fit_button = PushButton(name="fit", text="Auto-fit to the real image")
        self.cancel_fit_button = PushButton(name="cancel_fit", text="Cancel fit", enabled=False)
        self.terms_table = Table(name="terms", label="objective terms")
        self.terms_image = Image(name="terms_plot", label="before / after")
        self.extend(
            [
                self.source,
                self.reference,
                self.modality,
                self.noise_model,
                *self.sliders.values(),
                self.match_fourier,
                self.match_histogram,
                self.match_noise,
                self.fit_button,
                self.cancel_fit_button,
                self.status,
                self.terms_table,
                self.terms_image,
            ]
        )
        self.terms_image.visible = False
        self.fit_button.changed.connect(self.auto_fit)
        self.cancel_fit_button.changed.connect(self.cancel_fit)
        self.fit_worker = None
        self.fit_result = None
        self._fit_cancelled = False
        self.preview = None
        self._stale: set[int] = set()
        self._loading = False
        self.source.changed.connect(self._load_source)
        for widget in (*self.sliders.values(), self.modality, self.noise_model):
            widget.changed.connect(self._on_parameter)
        for widget in (self.reference, self.match_fourier, self.match_histogram):
            widget.changed.connect(self._on_matching)
        self.reference.changed.connect(self._match_noise)
        self.match_noise.changed.connect(self._match_noise)
        viewer.dims.events.current_step.connect(self._on_step)
        for event in (viewer.layers.events.inserted, viewer.layers.events.removed):
            event.connect(self._refresh_choices)
        self._load_source()

    # -- choices --------------------------------------------------------------------------

    def _rendered(self, _widget=None) -> list:
        return [
            layer
            for layer in self.viewer.layers
            if SYMBAC_METADATA_KEY in layer.metadata
            and layer.data.ndim == 3
            and not hasattr(layer, "selected_label")
        ]

    def _references(self, _widget=None) -> list:
        from napari.layers import Image

        return [
            layer
            for layer in self.viewer.layers
            if isinstance(layer, Image) and SYMBAC_METADATA_KEY not in layer.metadata
        ]

    def _refresh_choices(self, _event=None) -> None:
        previous = self.source.value
        self.source.reset_choices()
        self.reference.reset_choices()
        if self.source.value is not previous:
            self._load_source()

    # -- state ----------------------------------------------------------------------------

    def _load_source(self, _value=None) -> None:
        from napari_symbac.fit.live import LivePreview
        from napari_symbac.pipeline import draw_frame

        layer = self.source.value
        if layer is None:
            self.preview = None
            self.status.value = "Render a simulation first (Simulate and render)"
            return
        simulation = layer.metadata[SYMBAC_METADATA_KEY]["simulation"]
        settings = layer.metadata[SYMBAC_METADATA_KEY]["settings"]
        self.preview = LivePreview(
            lambda index: draw_frame(simulation, settings, index),
            settings.microscope,
            settings.render,
            settings.camera,
            n_frames=len(simulation.frames),
            seed=settings.simulation.seed,
        )
        self._loading = True
        try:
            for name, slider in self.sliders.items():
                slider.value = getattr(settings.render, name)
            self.sliders["apodisation_sigma_um"].min = round(
                settings.microscope.min_apodisation_sigma_um, 3
            )
            self.modality.value = settings.microscope.modality
            self.noise_model.value = settings.render.noise_model
        finally:
            self._loading = False
        self._stale = set()
        self.status.value = ""

    def _current_frame(self) -> int:
        return int(self.viewer.dims.current_step[0]) if self.viewer.dims.ndim >= 3 else 0

    def _show(self, index: int) -> None:
        layer = self.source.value
        image = self.preview.frame(index)
        info = np.iinfo(layer.data.dtype) if layer.data.dtype.kind in "ui" else None
        if info is not None:
            image = np.clip(np.rint(image), info.min, info.max)
        layer.data[index] = image.astype(layer.data.dtype)
        self._stale.discard(index)
        layer.refresh()

    def _store_settings(self) -> None:
        layer = self.source.value
        meta = layer.metadata[SYMBAC_METADATA_KEY]
        meta["settings"] = dataclasses.replace(
            meta["settings"],
            microscope=self.preview.model.microscope,
            render=self.preview.render_settings,
        )

    # -- events ---------------------------------------------------------------------------

    def _on_parameter(self, _value: Any = None) -> None:
        if self._loading or self.preview is None:
            return
        if self.fit_worker is not None:
            self.status.value = "Fitting: wait for the fit or cancel it"
            return
        changes = {name: slider.value for name, slider in self.sliders.items()}
        changes["noise_model"] = self.noise_model.value
        changes["modality"] = self.modality.value
        try:
            self.preview.update(**changes)
        except ValueError as err:
            self.status.value = f"Not applied: {err}"
            return
        self.status.value = ""
        self._stale = set(range(self.preview.n_frames))
        self._show(self._current_frame())
        self._store_settings()

    def _on_matching(self, _value: Any = None) -> None:
        if self.preview is None:
            return
        frame = self._reference_frame()
        try:
            self.preview.set_reference(
                frame,
                fourier=self.match_fourier.value,
                histogram=self.match_histogram.value,
            )
            self._stale = set(range(self.preview.n_frames))
            self._show(self._current_frame())
        except ValueError as err:
            self.status.value = f"Not applied: {err}"

    # -- auto-fit -------------------------------------------------------------------------

    def auto_fit(self) -> None:
        """Fit the parameters to the chosen real image's painted classes, in a worker."""
        from napari.qt.threading import thread_worker

        from napari_symbac.fit import fit_parameters

        reference = self.reference.value
        if self.preview is None or reference is None:
            self.status.value = "Choose a rendered layer and a real image first"
            return
        if class_layer_name(reference.name) not in self.viewer.layers:
            self.status.value = (
                f"Paint classes on {reference.name} first (Real image and classes widget)"
            )
            return
        index = self._current_frame()
        real = np.asarray(reference.data)
        classes = np.asarray(self.viewer.layers[class_layer_name(reference.name)].data)
        if real.ndim == 3:
            real, classes = real[min(index, len(real) - 1)], classes[min(index, len(classes) - 1)]
        preview = self.preview
        scene = preview.scene(index)
        self._fit_cancelled = False

        @thread_worker(progress={"total": 0, "desc": "SyMBac auto-fit"})
        def work():
            return fit_parameters(
                real,
                classes,
                scene,
                preview.model.microscope,
                preview.render_settings,
                preview.model.camera,
                model=preview.model,
                cancel=lambda: self._fit_cancelled,
            )

        self.fit_worker = work()
        self.fit_worker.returned.connect(self._on_fit_returned)
        self.fit_worker.errored.connect(self._on_fit_errored)
        self.fit_worker.finished.connect(self._on_fit_finished)
        self.fit_button.enabled = False
        self.cancel_fit_button.enabled = True
        self.status.value = "Fitting..."
        self.fit_worker.start()

    def cancel_fit(self) -> None:
        """Stop the fit before its next render; the parameters stay as they were."""
        self._fit_cancelled = True

    def _on_fit_returned(self, result) -> None:
        self.fit_result = result
        fitted = {name: getattr(result.render, name) for name in SLIDERS}
        self._loading = True
        try:
            for name, value in fitted.items():
                slider = self.sliders[name]
                slider.max = max(slider.max, float(value))
                slider.value = float(value)
        finally:
            self._loading = False
        self.preview.update(**dataclasses.asdict(result.render))
        self._stale = set(range(self.preview.n_frames))
        self._show(self._current_frame())
        self._store_settings()
        self.terms_table.value = {
            "term": list(result.terms),
            "before": [f"{before:.4g}" for before, _ in result.terms.values()],
            "after": [f"{after:.4g}" for _, after in result.terms.values()],
        }
        self.terms_image.value = terms_plot(result.terms)
        self.terms_image.visible = True
        self.status.value = (
            f"Fitted in {result.n_evaluations} renders: objective "
            f"{result.objective_before:.4g} -> {result.objective_after:.4g}"
        )

    def _on_fit_errored(self, err: Exception) -> None:
        from napari_symbac.fit import FitCancelled

        if isinstance(err, FitCancelled):
            self.status.value = "Fit cancelled: parameters unchanged"
        else:
            self.status.value = f"Fit failed: {err}"

    def _on_fit_finished(self) -> None:
        self.fit_worker = None
        self.fit_button.enabled = True
        self.cancel_fit_button.enabled = False

    def _reference_frame(self) -> np.ndarray | None:
        reference = self.reference.value
        if reference is None:
            return None
        data = np.asarray(reference.data)
        return data[min(self._current_frame(), len(data) - 1)] if data.ndim == 3 else data

    def _match_noise(self, _value: Any = None) -> None:
        """Set Gaussian noise with the sd measured on the real image (SyMBac's match_noise)."""
        from napari_symbac.diagnose import estimate_noise_sd

        frame = self._reference_frame()
        if not self.match_noise.value or frame is None or self.preview is None:
            return
        try:
            sd = estimate_noise_sd(frame)
        except ValueError as err:
            self.status.value = f"Not applied: {err}"
            return
        slider = self.sliders["gaussian_noise_sd_adu"]
        slider.max = max(slider.max, sd)
        self._loading = True
        try:
            self.noise_model.value = "gaussian"
            slider.value = sd
        finally:
            self._loading = False
        self._on_parameter()
        self.status.value = f"Noise matched: Gaussian, sd {sd:.1f} ADU"

    def _on_step(self, _event=None) -> None:
        if self.preview is not None and self._current_frame() in self._stale:
            self._show(self._current_frame())
