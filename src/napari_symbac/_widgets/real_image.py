"""Dock widget: your recording: open it, give its pixel size and microscope, paint and
measure cell / media / device classes.

Headless equivalents: :func:`napari_symbac.io.read_recording` and
:func:`napari_symbac.fit.class_statistics`.
"""

from __future__ import annotations

import weakref
from typing import TYPE_CHECKING

import numpy as np
from magicgui.widgets import ComboBox, Container, FileEdit, Label, PushButton

from napari_symbac._widgets._forms import SettingsForm, hide_label, message_label
from napari_symbac._widgets._jobs import notify_warning
from napari_symbac._widgets._links import ViewerLinks
from napari_symbac._widgets._recording import (
    CAMERA_KEY,
    GUI_MODALITY_ADVICE,
    PIXEL_PROBLEM_KEY,
    axis_labels,
    check_recording_frame,
    first_frame,
    in_pixel_units,
    layer_axes,
    layer_pixel_size_um,
    pixel_size_problem,
    recording_camera,
    scale_pixel_um,
    watch_recordings,
)
from napari_symbac.fit import CLASS_VALUES, class_statistics
from napari_symbac.fit.preflight import camera_pixel_problem
from napari_symbac.io import micrometre_axes
from napari_symbac.settings import Camera, Microscope

if TYPE_CHECKING:
    import napari

__all__ = [
    "CAMERA_SOURCES",
    "CLASS_COLOURS",
    "RealImageWidget",
    "class_layer_name",
    "enter_pixel_size",
]

#: The start of the dock's warning that the steps will refuse the image as it is.
RECORDING_DOUBT = "Cannot be fitted as it is:"

#: The warnings last notified of each layer (by the dock's label that shows them), by
#: any Recording dock: the workflow's tab and the step docked alone say each once
#: (found as a user: two identical toasts).
_NOTIFIED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: The start of the dock's warning that the image contradicts the modality chosen.
MODALITY_DOUBT = "Modality doubt:"
#: How the fits know the recording's camera (the Recording step's *camera* choice).
MEASURED_CAMERA = "measured from the recording"
GIVEN_CAMERA = "given (data sheet)"
CAMERA_SOURCES = (MEASURED_CAMERA, GIVEN_CAMERA)

#: Colours of the painted classes (RGBA), shared by the layer and the legend.
CLASS_COLOURS = {"cell": "#ff5a36", "media": "#2e9bff", "device": "#b0b0b0"}


def class_layer_name(image_name: str) -> str:
    """Name of the class-labels layer painted on ``image_name``."""
    return f"{image_name} classes"


#: Layer metadata key of the file a recording was opened from by *or open* (or its
#: colour original's), where napari's own ``layer.source.path`` is not set.
SOURCE_PATH_KEY = "source_path"


def _source_path(layer) -> str | None:
    """The file ``layer`` came from: napari's ``layer.source.path`` (File > Open), else
    the one *or open* recorded; ``None`` for a layer from no file."""
    if layer is None:
        return None
    path = getattr(getattr(layer, "source", None), "path", None)
    return path or layer.metadata.get(SOURCE_PATH_KEY)


class RealImageWidget(Container):
    """Your recording: its pixel size and microscope, rough class labels, their statistics.

    * **real image**: any image layer, or open a TIFF (pixel size and modality read
      from its metadata) or a grey PNG. A file without a pixel size shows a warning and
      asks for it; the value entered is remembered with the layer (``layer.metadata``)
      and sets the layer's scale, so real and synthetic layers share micrometre
      coordinates.
    * **microscope**: pixel size, objective, wavelength, condenser and modality; the
      other widgets simulate, tune, fit and export with it.
    * **camera**: measured from the recording (the default: Auto-fit, Diagnose and
      Calibrate measure gain and read noise by photon transfer), or given: offset, gain,
      read noise and bit depth from the camera's data sheet or a photon-transfer
      measurement, as ``napari-symbac fit --camera``.
    * **Paint classes**: adds a labels layer with the classes cell (1), media (2) and
      device (3), in fixed colours, in paint mode with the cell class selected.
    * **Measure**: mean and variance of each painted class (eq. 2), stored with the
      layer as the starting intensities of the simulation.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(name="symbac_real_image", scrollable=False)
        self.viewer = viewer
        self.image = ComboBox(
            name="image",
            label="real image",
            choices=self._image_layers,
            tooltip="The recording to match: an image layer (not a synthetic one).",
        )
        self.file = FileEdit(
            name="file",
            label="or open",
            filter="*.tif *.tiff *.png",
            mode="r",
            tooltip=(
                "Open a TIFF recording (its pixel size and modality are read if recorded) "
                "or a grey PNG (which records neither)."
            ),
        )
        self.microscope = SettingsForm(
            Microscope, name="microscope", label="microscope", title="microscope"
        )
        self.microscope.pixel_size_um.min = 0.0
        self.microscope.pixel_size_um.max = 100.0
        self.microscope.pixel_size_um.step = 0.001
        # taken when the editing is finished (Enter, leaving the field, the arrows), not
        # at each keystroke: retyping passed through 0 and warned "no pixel size"
        self.microscope.pixel_size_um.native.setKeyboardTracking(False)
        self.pixel_size = self.microscope.pixel_size_um
        self.modality = self.microscope.modality
        self.camera_source = ComboBox(
            name="camera_source",
            label="camera",
            choices=list(CAMERA_SOURCES),
            value=MEASURED_CAMERA,
            tooltip=(
                "How the fits know the camera: measured from the recording (photon "
                "transfer of its pixels), or given from the camera's data sheet or a "
                "photon-transfer measurement (as napari-symbac fit --camera)."
            ),
        )
        self.camera = SettingsForm(Camera, name="camera", title="camera (given)")
        self.camera.visible = False
        self.warning = message_label("warning", label="")
        self.warning.visible = False
        self.camera_warning = message_label("camera_warning", label="")
        self.camera_warning.visible = False
        self._warned: dict[str, str] = {}  # each warning label's last notified text
        self._quiet = False  # warnings shown in the dock only (a layer removed)
        self.paint_button = PushButton(
            name="paint",
            text="Paint classes",
            tooltip="Add a labels layer on the image: paint a few strokes of each class.",
        )
        self.measure_button = PushButton(
            name="measure",
            text="Measure classes",
            tooltip="Mean and spread of the image inside each painted class (eq. 2).",
        )
        legend = " ".join(
            f"<b style='color:{colour}'>{value} {name}</b>"
            for (name, colour), value in zip(CLASS_COLOURS.items(), CLASS_VALUES.values())
        )
        self.legend = Label(name="legend", value=legend)
        self.result = message_label("result")
        self.extend(
            [
                self.image,
                self.file,
                self.warning,
                self.microscope,
                self.camera_source,
                self.camera,
                self.camera_warning,
                self.paint_button,
                self.legend,
                self.measure_button,
                self.result,
            ]
        )
        hide_label(self.microscope)
        hide_label(self.camera)
        hide_label(self.warning)
        hide_label(self.camera_warning)
        hide_label(self.result)  # no row that reads just "result"
        self.file.changed.connect(self._open_file)
        self.image.changed.connect(self._load_layer)
        self.microscope.changed.connect(self._store)
        self.camera_source.changed.connect(self._show_camera)
        self.camera_source.changed.connect(self._store)
        self.camera.changed.connect(self._store)
        self.modality.changed.connect(self._show_condenser)
        self.modality.changed.connect(self._forget_guess)
        self._show_condenser()
        self.paint_button.changed.connect(self.paint)
        self.measure_button.changed.connect(self.measure)
        self._links = ViewerLinks(self.native)
        layers = viewer.layers.events
        for follow in (
            self._add_grey_channel,
            self._place_over_recording,
            self._follow_image_in_pixels,
            self.image.reset_choices,
            self._follow_opened,
        ):
            self._links.connect(layers.inserted, follow)
        self._links.connect(layers.removed, self._after_removal)
        watch_recordings(viewer, self._show_entered, self._links)
        self.statistics = None
        self._loading = False
        for layer in list(viewer.layers):
            self._add_grey_of(layer)
        self._load_layer()

    def _image_layers(self, _widget=None) -> list:
        from napari.layers import Image

        from napari_symbac._widgets._recording import holds_masks, made_here

        # never a masks image (found as a user: with the recording removed, napari's
        # masks image became the recording, "no pixel size")
        return [
            layer
            for layer in self.viewer.layers
            if isinstance(layer, Image)
            and not made_here(layer)
            and (layer.rgb or not holds_masks(layer))  # a colour image is said as such
        ]

    def _open_file(self) -> None:
        from napari_symbac.io import ChannelsError, read_image

        path = self.file.value
        if not path or str(path) in ("", "."):
            return
        if path.is_dir():  # typed or pasted (found as a user: the previous file's
            # "No such file" stayed under a folder's path)
            self.result.value = f"{path} is a folder: choose an image file in it (TIFF or PNG)"
            return
        if not path.is_file():  # said as it is typed (found as a user: a mistyped path
            self.result.value = f"No such file: {path}"  # did nothing, under an old message)
            return
        try:
            recording = read_image(path, "recording", counts=True)
            data = np.asarray(recording.data)
            # what the fit refuses, refused here (found as a user: an all-zero and a
            # negative-valued TIFF opened as recordings, and failed only at Auto-fit)
            check_recording_frame(data if data.ndim == 2 else data[0], path.name)
        except (ValueError, OSError) as err:
            reason = (  # one recording is one channel
                f"{err.cause}: open it with File > Open and the napari-symbac reader, "
                "which adds a layer per channel"
                if isinstance(err, ChannelsError)
                else err
            )
            message = f"Cannot open {path.name}: {reason}"
            self.result.value = message
            notify_warning(message)
            return
        # the image's own range: napari's default for 8 bits is 0-255, which shows an
        # 8-bit export of 19 grey levels (the Omnipose colonies) as black
        low, high = np.percentile(recording.data, (0.1, 99.9))
        kwargs = {"contrast_limits": (float(low), float(high))} if high > low else {}
        if recording.pixel_size_um:
            kwargs.update(layer_axes(recording.pixel_size_um, recording.data.ndim))
        else:
            kwargs["axis_labels"] = axis_labels(recording.data.ndim)
            _follow_pixels(self.viewer)  # before napari draws the image (and checks units)
        # its file recorded, so that *or open* shows it when the layer is chosen (napari's
        # File > Open records it as the layer's source, which only napari's readers set)
        name = recording.name
        if name in self.viewer.layers and path.parent.name:
            # found as a user: ColiCoords' fluorescence/00002.tif and brightfield/00002.tif
            # became "00002" and "00002 [1]", which neither names
            name = f"{name} ({path.parent.name})"
        layer = self.viewer.add_image(
            recording.data,
            name=name,
            metadata={
                "pixel_size_um": recording.pixel_size_um,
                "modality": recording.modality,
                SOURCE_PATH_KEY: str(path),
                **({"counts_mapping": recording.counts_mapping}
                   if recording.counts_mapping is not None else {}),
            },
            **kwargs,
        )
        self.image.value = layer

    def _show_source(self, layer) -> None:
        """*or open* shows the chosen recording's file (napari's ``layer.source.path``:
        opened here or with File > Open), empty for a layer from no file. Found as a
        user: a refused colour PNG's path stayed in the field after another recording
        was opened and chosen, as if that file were the recording."""
        path = _source_path(layer)
        with self.file.changed.blocked():  # shown, not opened again
            self.file.line_edit.value = str(path) if path else ""

    def _load_layer(self, _value=None) -> None:
        """Show the chosen layer's file, pixel size, modality and microscope (never
        another's)."""
        layer = self.image.value
        self._show_source(layer)
        if layer is None:
            return
        if getattr(layer, "rgb", False):
            self._use_grey_channel(layer)
            return
        meta = layer.metadata
        # not another layer's words (a refused file, its measures); a normalised image
        # read as counts says so (the reader's, or *or open*'s: io.as_counts)
        mapping = meta.get("counts_mapping")
        self.result.value = f"{layer.name}: {mapping.note}" if mapping is not None else ""
        if mapping is None:  # what the steps will refuse, said as it is chosen (found as a
            # user: DeLTA's normalised trench opened by napari's reader was simulated with
            # the built-in camera, thousands of ADU against its 0-1, before Auto-fit said)
            try:
                check_recording_frame(first_frame(layer), layer.name)
            except ValueError as err:
                self.result.value = f"{RECORDING_DOUBT} {err}"
        pixel = meta.get("pixel_size_um")
        if not pixel:  # a layer already scaled by its reader
            pixel = scale_pixel_um(layer)
        if "pixel_size_um" not in meta:  # opened by another reader: what its file says
            pixel = self._read_from_file(layer, pixel)
        self._loading = True
        try:
            if isinstance(meta.get("microscope"), Microscope):
                self.microscope.value = meta["microscope"]
            if meta.get("modality") in self.modality.choices:
                self.modality.value = meta["modality"]
            elif not isinstance(meta.get("microscope"), Microscope):
                self._guess_modality(layer)
            self.pixel_size.value = pixel or 0.0
            # each recording its own camera, never the form's last one (found as a user:
            # another recording's 1700 ADU offset was stored for the trench)
            camera = meta.get(CAMERA_KEY)
            given = isinstance(camera, Camera)
            self.camera.value = camera if given else Camera()
            self.camera_source.value = GIVEN_CAMERA if given else MEASURED_CAMERA
        finally:
            self._loading = False
        self._show_camera()
        self._store()

    def _read_from_file(self, layer, pixel: float | None) -> float | None:
        """For a layer another reader opened (napari's own keeps no pixel size and reads
        a TIFF's channels as one stack): the pixel size its file records when the layer
        has none, said, and a file of several channels warned of. Found as a user: such
        layers were said to come from files that "do not record" a pixel size, and a
        phase + fluorescence file was fitted as a time-lapse of 2 frames."""
        from napari_symbac.io import tiff_axes_and_pixel_size

        facts = tiff_axes_and_pixel_size(_source_path(layer))
        if facts is None:
            return pixel
        axes, recorded = facts
        said = [self.result.value] if self.result.value else []
        if "C" in axes:
            said.append(
                f"{RECORDING_DOUBT} {layer.name}: its file holds channels (axes {axes}), "
                "which napari's reader opened as one stack, frames to the steps: open it "
                "with File > Open and the napari-symbac reader, which adds a layer per channel"
            )
        if not pixel and recorded and not pixel_size_problem(recorded):
            pixel = recorded
            said.append(
                f"{layer.name}: pixel size {recorded:.4g} um read from its file (the reader "
                "that opened it does not read it)"
            )
        self.result.value = "<br>".join(said)
        return pixel

    def _show_entered(self, event=None) -> None:
        """Show a pixel size entered elsewhere for the layer shown (Calibrate's, derived
        from a cell width), so that the form never holds another value than the layer."""
        layer = self.image.value
        if self._loading or getattr(event, "type", "") != "metadata" or event.source is not layer:
            return
        entered = layer.metadata.get("pixel_size_um")
        if not entered or float(entered) == float(self.pixel_size.value):
            return
        self._loading = True  # shown, not stored again at the form's 4 decimals
        try:
            if isinstance(layer.metadata.get("microscope"), Microscope):
                self.microscope.value = layer.metadata["microscope"]
            self.pixel_size.value = float(entered)
        finally:
            self._loading = False
        self._warn(self.warning, layer, None)

    def _show_camera(self, _value=None) -> None:
        """The camera's form is shown when the camera is given."""
        self.camera.visible = self.camera_source.value == GIVEN_CAMERA

    def _given_camera(self, layer) -> tuple[Camera | None, str | None]:
        """The camera given in the form for ``layer`` (``None`` when measured), or the
        problem with it: settings it refuses, or a camera that cannot have recorded the
        layer (:func:`~napari_symbac.fit.preflight.camera_recording_problem`)."""
        from napari_symbac.fit.preflight import camera_recording_problem

        if self.camera_source.value != GIVEN_CAMERA:
            return None, None
        until = "(the fits measure it from the recording until then)"
        try:
            camera = self.camera.value
        except ValueError as err:
            return None, f"camera: {err} {until}"
        first = first_frame(layer)  # a time-lapse's first frame
        problem = camera_recording_problem(camera, first)
        if problem is not None:
            return None, f"camera: {problem} {until}"
        return camera, None

    def _show_condenser(self, _value=None) -> None:
        """The phase condenser (annulus) is a phase-contrast setting: hidden for
        fluorescence, where it is not used."""
        self.microscope.condenser.visible = self.modality.value == "phase"

    def _forget_guess(self, _value=None) -> None:
        """A modality chosen by the user: the guess said of it is no longer true, and a
        modality the image contradicts is warned of at once, in the fit's words (found
        as a user: phase chosen for a fluorescence field was said only by Auto-fit,
        after Simulate had grown a colony of 480 cells for the field's 7)."""
        from napari_symbac.fit.preflight import check_modality

        layer = self.image.value
        if self._loading or layer is None:
            return
        stale = (f"{layer.name} records no modality", MODALITY_DOUBT)
        said = [line for line in self.result.value.split("<br>") if not line.startswith(stale)]
        try:
            frame = first_frame(layer).astype(np.float64)
            check_modality(frame, self.modality.value, advice=GUI_MODALITY_ADVICE)
        except ValueError as err:
            said.append(f"{MODALITY_DOUBT} {layer.name}: {err}")
            notify_warning(said[-1])
        self.result.value = "<br>".join(filter(None, said))

    def _guess_modality(self, layer) -> None:
        """A recording that does not say its modality: fluorescence when it shows bright
        objects on a dark background and nothing darker, phase contrast when it shows
        dark ones (:func:`~napari_symbac.fit.preflight.image_polarity`, the fit's own
        check); an unclear image keeps the form's choice. Said in the dock, to change."""
        from napari_symbac.fit.preflight import image_polarity

        frame = first_frame(layer).astype(np.float64)
        guess = {"bright cells": "fluorescence", "dark cells": "phase"}.get(
            image_polarity(frame)
        )
        if guess is None:  # found as a user: a crop around one fluorescent cell, whose
            # glow is most of it, was taken for phase contrast without a word
            said = (
                f"{layer.name} records no modality, and its look does not settle it (a "
                f"crop around a few cells, or phase contrast): {self.modality.value} is "
                "assumed; choose the modality in the microscope form"
            )
        else:
            self.modality.value = guess
            shows = (
                "bright objects on a dark" if guess == "fluorescence" else "dark objects on a light"
            )
            other = "" if guess == "fluorescence" else " (bright field looks so too)"
            said = (
                f"{layer.name} records no modality: {guess}, as it shows {shows} background "
                f"(change it if wrong{other})"
            )
        # after what reading said (a normalised image read as counts)
        self.result.value = "<br>".join(filter(None, (self.result.value, said)))

    def _place_over_recording(self, event) -> None:
        """Labels added in pixels over a recording with a pixel size (masks opened from
        their file, which records none), and images that hold masks (napari's own reader
        opens a masks TIFF as an image: found as a user, it stayed in pixels, 12.5x the
        recording), are placed in its micrometres. (napari's canvas draws a new layer
        before any plugin hears of it, so it warns once that the layers' units differ;
        from then on they agree.)"""
        from napari.layers import Image, Labels

        from napari_symbac._widgets._recording import holds_masks

        layer = event.value
        masks = isinstance(layer, Labels) or (
            isinstance(layer, Image) and not layer.rgb and holds_masks(layer)
        )
        if not masks or not _in_pixels(layer):
            return
        for other in self.viewer.layers:
            pixel = other.metadata.get("pixel_size_um")
            if other is not layer and pixel and _camera_shape(other) == _camera_shape(layer):
                _place_in_micrometres(layer, float(pixel))
                if isinstance(layer, Image):  # once napari has drawn it (after its event)
                    from qtpy.QtCore import QTimer

                    QTimer.singleShot(0, lambda: _masks_as_labels(self.viewer, layer))
                return

    def _follow_image_in_pixels(self, event) -> None:
        """An image added in pixels by napari's *File > Open* (a TIFF without a pixel
        size) takes Simulate's layers into pixels with it. napari has drawn it and warned
        "Inconsistent units across layers" once by then (its canvas hears of a new layer
        before any plugin); *or open* moves them before adding the image, unwarned."""
        from napari.layers import Image

        layer = event.value
        if isinstance(layer, Image) and not _is_synthetic(layer) and in_pixel_units(layer):
            _follow_pixels(self.viewer)

    def _follow_opened(self, event) -> None:
        """An image the user opens (File > Open, drag and drop) without a pixel size
        becomes the one this dock shows, where its pixel size is asked for (found as a
        user: a second TIFF opened beside the trench got no "no pixel size" prompt and
        sat in pixels beside the layers in micrometres). One that has its pixel size
        leaves the dock's choice as it is (a sample of two channels: the first one
        chosen). A colour image is followed through its grey channel, added before it."""
        layer = event.value
        if getattr(layer, "rgb", False) or layer not in self.image.choices:
            return
        if layer_pixel_size_um(layer) is None:
            self.image.value = layer
            # in pixels it dwarfs the layers in micrometres: the view fits it (found as
            # a user: a second PNG opened after a calibrated one showed as a few grey
            # pixels filling the canvas)
            self.viewer.reset_view()

    def _add_grey_channel(self, event) -> None:
        """A grey image saved as colour (equal red, green and blue: the Omnipose and
        Cellpose datasets' PNGs, which napari opens as RGBA) gets its grey channel as a
        layer ``"<name> grey"`` when it is added to the viewer; every step uses that."""
        self._add_grey_of(event.value)

    def _add_grey_of(self, layer) -> None:
        """:meth:`_add_grey_channel` of ``layer``; also run on the layers open before
        the dock (found as a user: a PNG opened with File > Open before the dock was
        said to have had its grey channel "removed", which was never made)."""
        if not getattr(layer, "rgb", False) or f"{layer.name} grey" in self.viewer.layers:
            return
        from napari_symbac.io import grey_channel

        grey = grey_channel(layer.data)
        if grey is not None:
            # the image's own range, as *or open* shows it (found as a user: the grey
            # channel of Sample000033.png opened with File > Open, 8-bit values 4-14,
            # was shown on napari's 0-255 as a black canvas)
            low, high = np.percentile(grey, (0.1, 99.9))
            kwargs = {"contrast_limits": (float(low), float(high))} if high > low else {}
            path = _source_path(layer)  # the colour image's file
            self.viewer.add_image(
                grey,
                name=f"{layer.name} grey",
                scale=layer.scale,
                units=layer.units,
                translate=layer.translate,
                metadata={SOURCE_PATH_KEY: path} if path else {},
                **kwargs,
            )

    def _use_grey_channel(self, layer) -> None:
        """A colour layer cannot be fitted: choose its grey-channel layer, or say why."""
        from napari_symbac.io import grey_channel

        name = f"{layer.name} grey"
        if name in self.viewer.layers:
            self.image.value = self.viewer.layers[name]  # its own words first, then ours
            said = (
                f"{layer.name} is a grey image saved as colour: its grey channel is the "
                f"layer '{name}', used from here on"
            )
            self.result.value = "<br>".join(filter(None, (said, self.result.value)))
            return
        message = (
            f"{layer.name} is a colour image {tuple(layer.data.shape)}: open one grey "
            "channel (the camera's raw frame) to match and fit"
        )
        removed = grey_channel(layer.data) is not None
        if removed:  # its grey layer was deleted (found as a user: the dock called it a
            # colour image and named the deleted layer; made again here, a viewer closing
            # would make it for ever)
            message = (
                f"{layer.name} is a grey image saved as colour, and its grey channel, the "
                f"layer '{name}', was removed: open the file again to use it"
            )
            self.result.value = ""
        self.warning.value = f"<b style='color:#ffb000'>&#9888; {message}</b>"
        self.warning.visible = True
        if not removed:  # a removed grey layer is said in the dock only: napari removes
            notify_warning(message)  # it first when the viewer closes

    def _store(self, _value=None) -> None:
        """Remember the form with the layer, or show why it cannot be used."""
        if self._loading:
            return
        layer = self.image.value
        if layer is None:
            return
        camera = self._store_camera(layer)
        pixel = float(self.pixel_size.value)
        problem = pixel_size_problem(pixel)
        if problem is None:
            try:
                microscope = self.microscope.value
            except ValueError as err:
                problem = str(err)
        if problem is not None:
            self._warn(self.warning, layer, problem)
            # the modality (and the camera) kept all the same: chosen again before the
            # pixel size is entered, the recording keeps the user's choice instead of a
            # new guess (found as a user: a camera given first was lost)
            layer.metadata = {
                **layer.metadata,
                "pixel_size_um": None,
                "modality": self.modality.value,
                CAMERA_KEY: camera,
                # what the other steps say of it (a value typed and refused, not none)
                PIXEL_PROBLEM_KEY: None if pixel == 0 else problem,
            }
            return
        # used all the same, as `fit` warns and fits (found as a user: 0.65 um at the
        # form's 100x, a 10x slip, was taken in silence, where `fit` says it)
        slip = camera_pixel_problem(microscope, where="the microscope form below")
        self._warn(self.warning, layer, slip)
        enter_pixel_size(self.viewer, layer, microscope)
        # after the pixel size: a metadata event before it would show the old one
        if CAMERA_KEY not in layer.metadata or layer.metadata[CAMERA_KEY] != camera:
            layer.metadata = {**layer.metadata, CAMERA_KEY: camera}

    def _store_camera(self, layer) -> Camera | None:
        """The camera to store with ``layer`` (:meth:`_given_camera`), its problem shown
        under the camera's form (found as a user: shown at the top of the step, far from
        the form, and cut short in the notification)."""
        camera, problem = self._given_camera(layer)
        self._warn(self.camera_warning, layer, problem)
        return camera

    def _after_removal(self, _event=None) -> None:
        """Offer the remaining images; one chosen in place of a removed recording says
        its problem in the dock only (found as a user: closing the viewer removed the
        recording, chose an image without a pixel size, and a 'no pixel size'
        notification came as the window closed)."""
        self._quiet = True
        try:
            self.image.reset_choices()
        finally:
            self._quiet = False
        if self.image.value is None:  # none left: nor its file and words (found as a
            # user: the removed recording's path stayed in *or open*, and choosing that
            # file again opened nothing, the field's value unchanged)
            self._show_source(None)
            self.result.value = ""

    def _warn(self, label, layer, problem: str | None) -> None:
        """Show ``problem`` of ``layer`` in ``label`` (and once as a notification), or
        clear the label when there is none."""
        if problem is None:
            label.value = ""
            label.visible = False
            self._warned.pop(label.name, None)
            _NOTIFIED.get(layer, {}).pop(label.name, None)
            return
        label.value = f"<b style='color:#ffb000'>&#9888; {layer.name}: {problem}</b>"
        label.visible = True
        message = f"{layer.name}: {problem}"
        new_here = label.value != self._warned.get(label.name)
        notified = _NOTIFIED.setdefault(layer, {})
        if new_here and not self._quiet and notified.get(label.name) != message:
            notify_warning(message)
            notified[label.name] = message
        self._warned[label.name] = label.value

    def paint(self) -> None:
        """Add (or select) the class-labels layer for the chosen image, ready to paint."""
        from napari.utils.colormaps import DirectLabelColormap

        layer = self.image.value
        if layer is None:
            self.result.value = "Open or choose an image first"
            return
        name = class_layer_name(layer.name)
        if name not in self.viewer.layers:
            colours = {None: "transparent", 0: "transparent"}
            colours.update({CLASS_VALUES[cls]: colour for cls, colour in CLASS_COLOURS.items()})
            labels = self.viewer.add_labels(
                np.zeros(layer.data.shape, np.uint8),
                name=name,
                scale=layer.scale,
                units=layer.units,
                translate=layer.translate,
                opacity=0.5,
                colormap=DirectLabelColormap(color_dict=colours),
            )
            labels.brush_size = 5
        labels = self.viewer.layers[name]
        labels.selected_label = CLASS_VALUES["cell"]
        labels.mode = "paint"
        self.viewer.layers.selection.active = labels

    def measure(self) -> None:
        """Mean and variance of each painted class (eq. 2), shown and kept with the layer."""
        layer = self.image.value
        if layer is None or class_layer_name(layer.name) not in self.viewer.layers:
            self.result.value = "Paint classes first"
            return
        labels = self.viewer.layers[class_layer_name(layer.name)].data
        try:
            self.statistics = class_statistics(layer.data, labels, required=("cell", "media"))
        except ValueError as err:
            self.result.value = str(err)
            notify_warning(str(err))
            return
        try:  # above the recording's own offset (an 8-bit one's is below 100 ADU)
            baseline = recording_camera(layer)[0].baseline_adu
        except ValueError:  # a frame the fits refuse: they say why when run
            baseline = Camera().baseline_adu
        layer.metadata = {
            **layer.metadata,
            "class_means_adu": {
                name: stat.mean - baseline for name, stat in self.statistics.items()
            },
        }
        self.result.value = "<br>".join(
            f"{name}: mean {stat.mean:.1f}, sd {np.sqrt(stat.variance):.1f} ({stat.n_pixels} px)"
            for name, stat in self.statistics.items()
        )


def _masks_as_labels(viewer, layer) -> None:
    """An image layer that holds masks, over a recording, made a Labels layer in its
    place: found as a user, a masks TIFF opened with napari's own reader (File > Open
    offers it as well as this plugin's) lay as an opaque grey image over the recording,
    hiding it, while this plugin's reader gives a Labels layer."""
    from napari.layers import Labels

    if layer not in viewer.layers:
        return
    index = list(viewer.layers).index(layer)
    data = np.asarray(layer.data)
    if data.dtype.kind not in "iu":
        data = data.astype(np.int32)
    labels = Labels(
        data,
        name=layer.name,
        scale=layer.scale,
        units=layer.units,
        translate=layer.translate,
        axis_labels=layer.axis_labels,
        metadata=dict(layer.metadata),
    )
    viewer.layers.remove(layer)
    viewer.layers.insert(index, labels)


def enter_pixel_size(viewer, layer, microscope: Microscope) -> None:
    """Give a recording its pixel size: ``microscope`` (whose ``pixel_size_um`` and
    ``modality`` are the recording's) into its metadata, where every step reads them, and
    the recording, the layers that overlay it and Simulate's layers into micrometres.

    What entering the pixel size in *Real image and classes* does; Calibrate does it too
    with the pixel size it derives from a cell width (found as a user: a PNG calibrated
    that way stayed in pixels beside its synthetic layers in micrometres, and napari
    warned "Inconsistent units across layers").
    """
    pixel = float(microscope.pixel_size_um)
    was_in_pixels = _in_pixels(layer)
    shown_um = float(layer.scale[-1])
    layer.metadata = {
        **{key: value for key, value in layer.metadata.items() if key != PIXEL_PROBLEM_KEY},
        "pixel_size_um": pixel,
        "modality": microscope.modality,
        "microscope": microscope,
    }
    for target in [layer, *_overlays(viewer, layer)]:
        _place_in_micrometres(target, pixel)
    _move_simulation(viewer, to_micrometres=True)
    # from pixels into micrometres everything shrinks some 15 times: the view follows
    # (found as a user: after Simulate, entering the pixel size left a speck in a corner
    # of a black canvas), as it does when a slip is corrected (0.65 -> 0.065 um, found
    # as a user); a pixel size refined by less than 2x moves little, and the view stays
    rescaled = max(shown_um, pixel) / min(shown_um, pixel) > 2
    if was_in_pixels or rescaled or not any(_is_synthetic(o) for o in viewer.layers):
        viewer.reset_view()


def _overlays(viewer, recording) -> list:
    """Layers that follow ``recording``'s placement: labels over its camera pixels (its
    painted classes, a masks file opened beside it) and the colour original of its
    grey channel, placed as it is or still in pixels (a masks file records no pixel
    size; one opened with napari's own reader is an image that holds masks). They take
    its pixel size with it, so they keep overlaying it when the pixel size is entered
    or corrected, and napari's units agree across the layers (mixed, napari warns and
    drops them; found as a user: such a masks image stayed in pixels when Calibrate
    entered a cell width's pixel size, and the recording shrank to a corner of the
    canvas). Another grey image of the same size is left alone: it may come from
    another microscope."""
    from napari.layers import Image, Labels

    from napari_symbac._widgets._recording import holds_masks

    source = recording.name.removesuffix(" grey")
    placed = (tuple(recording.scale[-2:]), tuple(recording.units[-2:]))

    def overlays(other) -> bool:
        if getattr(other, "rgb", False):
            return other.name == source
        return isinstance(other, Labels) or (isinstance(other, Image) and holds_masks(other))

    return [
        other
        for other in viewer.layers
        if other is not recording
        and overlays(other)
        and _camera_shape(other) == _camera_shape(recording)
        and (_in_pixels(other) or (tuple(other.scale[-2:]), tuple(other.units[-2:])) == placed)
    ]


def _is_synthetic(layer) -> bool:
    from napari_symbac._widgets.simulate import DRAWN_PIXEL_KEY, SYMBAC_METADATA_KEY

    return SYMBAC_METADATA_KEY in layer.metadata or DRAWN_PIXEL_KEY in layer.metadata


def _drawn_pixel_um(layer) -> float | None:
    """The pixel size a layer of Simulate's was drawn at, or ``None`` for other layers
    (Diagnose's and Tune's are placed over the recording, not by their own pixels)."""
    from napari_symbac._widgets.simulate import DRAWN_PIXEL_KEY, SYMBAC_METADATA_KEY

    if DRAWN_PIXEL_KEY in layer.metadata:  # Simulate's tracks
        return float(layer.metadata[DRAWN_PIXEL_KEY])
    meta = layer.metadata.get(SYMBAC_METADATA_KEY) or {}
    settings = meta.get("settings") if "simulation" in meta else None
    microscope = getattr(settings, "microscope", None)
    return getattr(microscope, "pixel_size_um", None)


def _move_simulation(viewer, to_micrometres: bool) -> None:
    """Move Simulate's layers into micrometres (each by the pixel size it was drawn at)
    or back into pixels: scale and translate together, so that the optical path
    length's render pixels stay over the camera pixels."""
    for layer in viewer.layers:
        pixel = _drawn_pixel_um(layer)
        if not pixel or in_pixel_units(layer) != to_micrometres:
            continue
        factor = pixel if to_micrometres else 1.0 / pixel
        lead = layer.ndim - 2
        unit = "um" if to_micrometres else "pixel"
        layer.scale = (*layer.scale[:lead], *(float(s) * factor for s in layer.scale[lead:]))
        layer.translate = (
            *layer.translate[:lead],
            *(float(t) * factor for t in layer.translate[lead:]),
        )
        layer.units = (*layer.units[:lead], unit, unit)


def _follow_pixels(viewer) -> None:
    """Simulate's layers into pixels, when no layer of the user's is in micrometres:
    beside an image that is still in pixels, and nothing else to overlay."""
    users = [layer for layer in viewer.layers if not _is_synthetic(layer)]
    if all(in_pixel_units(layer) for layer in users):
        _move_simulation(viewer, to_micrometres=False)


def _camera_shape(layer) -> tuple[int, ...]:
    """The ``(Y, X)`` pixels a layer covers (a colour image's last axis is its channels)."""
    shape = tuple(layer.data.shape)
    return shape[-3:-1] if getattr(layer, "rgb", False) else shape[-2:]


def _in_pixels(layer) -> bool:
    """Whether a layer is still at napari's default placement: 1 unit per pixel."""
    return all(float(s) == 1.0 for s in layer.scale[-2:]) and all(
        str(u) == "pixel" for u in layer.units[-2:]
    )


def _place_in_micrometres(layer, pixel_um: float) -> None:
    """Scale a layer's last two axes to ``pixel_um`` and give them um as their unit."""
    axes = micrometre_axes(pixel_um, layer.ndim)
    scale = (*layer.scale[:-2], *axes["scale"][-2:])
    if tuple(layer.scale) != scale:
        layer.scale = scale
    if tuple(str(u) for u in layer.units[-2:]) != ("micrometer", "micrometer"):
        layer.units = (*layer.units[:-2], *axes["units"][-2:])
