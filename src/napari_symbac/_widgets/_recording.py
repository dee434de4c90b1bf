"""The user's recording as the widgets share it: kept in the real image layer's metadata.

A real image layer is "a recording" once the *Real image and classes* widget has set
its pixel size; the layer then carries

* ``pixel_size_um`` (and the layer's scale is set to it, so real and synthetic layers
  share physical coordinates),
* ``modality`` (``"phase"``, ``"fluorescence"`` or ``"brightfield"``),
* ``microscope``: the :class:`~napari_symbac.settings.Microscope` to simulate with,
* ``class_statistics`` once the painted classes were measured (eq. 2),
* ``camera``: the :class:`~napari_symbac.settings.Camera` the user gave (its data sheet
  or a photon-transfer measurement), absent or ``None`` when the fits measure it from
  the recording (:func:`given_camera`).

Simulate, Tune, Auto-fit and Export read these from the layer; no hidden state joins
the widgets. The metadata is replaced, never edited in place, so that the layer emits
``events.metadata``: :func:`watch_recordings` lets every widget that lists recordings
offer a recording the moment its pixel size is entered.
"""

from __future__ import annotations

import dataclasses
import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from napari_symbac.fit.preflight import (
    ModalityAdvice,
    check_pixel_size,
    default_geometry,
    looks_like_masks,
)
from napari_symbac.io import AXIS_LABELS, axis_labels, layer_axes
from napari_symbac.settings import Camera, Microscope, RenderSettings

if TYPE_CHECKING:
    from napari_symbac._widgets._links import ViewerLinks

__all__ = [
    "AXIS_LABELS",
    "GUI_CAMERA_FIX",
    "GUI_MODALITY_ADVICE",
    "PIXEL_PROBLEM_KEY",
    "RECORDING_STEP",
    "axis_labels",
    "check_recording_frame",
    "first_frame",
    "followed_layer",
    "given_camera",
    "holds_masks",
    "in_pixel_units",
    "is_real_image",
    "is_recording",
    "layer_axes",
    "layer_pixel_size_um",
    "modality_render",
    "pixel_size_problem",
    "recording_camera",
    "recording_class_means",
    "recording_microscope",
    "recordings",
    "waiting_problem",
    "watch_recordings",
]


#: Starting intensities of eq. 3 (ADU above the baseline) per modality when nothing was
#: measured: phase contrast shows dark cells on bright media, fluorescence bright cells
#: on a dark background (media and PDMS only autofluoresce), bright field cells barely
#: darker than the media (seen out of focus, by their lens term).
_DEFAULT_INTENSITIES = {
    "phase": {"cell_intensity": 1400.0, "media_intensity": 2600.0, "device_intensity": 900.0},
    "fluorescence": {"cell_intensity": 3000.0, "media_intensity": 150.0, "device_intensity": 60.0},
    # bright field: cells absorb a few % of the light, PDMS a little more
    "brightfield": {
        "cell_intensity": 2500.0,
        "media_intensity": 2600.0,
        "device_intensity": 2300.0,
    },
}


#: Where a recording is opened and its pixel size and modality entered, in the docks' words.
RECORDING_STEP = "the 1 Recording tab (or the Real image and classes dock)"
#: What to do when the recording's modality contradicts its image, in the docks' words
#: (:func:`~napari_symbac.fit.preflight.check_modality`; the commands name --modality).
GUI_MODALITY_ADVICE = ModalityAdvice(
    switch=f"Set its modality to {{other}} in {RECORDING_STEP}",
    paint="paint its cell and media classes there",
)
#: How a GUI user gives a camera the fits would otherwise measure, or cannot check.
GUI_CAMERA_FIX = (
    "give the camera in the Recording step (camera: given), from its data sheet or a "
    "photon-transfer measurement"
)


#: Each image layer's data and whether it holds masks: the docks ask on every layer
#: event, several times each, and on a 2048 x 2048 px recording the answer takes ~0.1 s
#: (14 asks, 1.6 s, when its pixel size was entered in the workflow dock).
_HOLDS_MASKS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def holds_masks(layer: Any) -> bool:
    """Whether an image layer holds masks, not a recording
    (:func:`~napari_symbac.fit.preflight.looks_like_masks`), worked out once per data
    array the layer holds."""
    data = layer.data
    seen = _HOLDS_MASKS.get(layer)
    if seen is None or seen[0] is not data:
        seen = (data, looks_like_masks(data))
        _HOLDS_MASKS[layer] = seen
    return seen[1]


def in_pixel_units(layer: Any) -> bool:
    """Whether a layer's ``Y`` and ``X`` axes are in napari's default unit, the pixel (an
    image opened without a pixel size), whatever its scale."""
    return all(str(unit) == "pixel" for unit in layer.units[-2:])


def scale_pixel_um(layer: Any) -> float | None:
    """The pixel size, in um, that a layer's own scale gives (:func:`~napari_symbac.io.
    scale_um`: its unit of length converted, napari's pixel unit taken for um), or None
    for an unscaled layer or a scale that is no length."""
    from napari_symbac.io import scale_um

    if float(layer.scale[-1]) == 1 and in_pixel_units(layer):
        return None
    return scale_um(float(layer.scale[-1]), layer.units[-1])


def check_recording_frame(frame: Any, name: str) -> None:
    """Refuse, as ``napari-symbac fit`` does, a frame the fit cannot use: negative or
    normalised values (:func:`~napari_symbac.fit.preflight.check_fit_image`) or a
    constant image; said in the docks' words.

    Raises
    ------
    ValueError
        Naming the recording, the problem and what to open instead.
    """
    import numpy as np

    from napari_symbac.fit.preflight import check_fit_image, refuse_constant

    frame = np.asarray(frame)
    refuse_constant(frame, name, what="")
    check_fit_image(frame, name, camera_hint="in the Recording step's camera (camera: given)")


def pixel_size_problem(pixel_size_um: float | None) -> str | None:
    """Why ``pixel_size_um`` cannot be used as it is, or ``None`` when it is plausible
    (:func:`~napari_symbac.fit.preflight.check_pixel_size`, as fit and diagnose)."""
    if not pixel_size_um:
        return (
            "no pixel size: the file does not record one. Enter it (camera pixel / "
            "magnification, e.g. 6.5 um / 100x = 0.065 um)"
        )
    try:
        check_pixel_size(pixel_size_um, "entered")
    except ValueError as err:
        return str(err)
    return None


#: Metadata key of the layers a step shows its results in without settings of their own
#: (Auto-fit's synthetic and residual, Diagnose's residual after and effect maps).
OUTPUT_KEY = "napari_symbac_output"

#: Layer metadata key of why the pixel size entered for a recording was refused (found
#: as a user: 65 typed for 0.065 um was warned of in the Recording step, and the other
#: steps then said "no pixel size yet" while the field showed 65).
PIXEL_PROBLEM_KEY = "pixel_size_problem"

#: Layer metadata key of the camera given in the Recording step (:func:`given_camera`).
CAMERA_KEY = "camera"


def given_camera(layer: Any) -> Camera | None:
    """The camera the user gave for recording ``layer`` in the Recording step, or
    ``None``: Auto-fit, Diagnose and Calibrate then measure it from the recording, as
    ``napari-symbac fit`` does without ``--camera``."""
    camera = None if layer is None else layer.metadata.get(CAMERA_KEY)
    return camera if isinstance(camera, Camera) else None


def output_metadata(step: str) -> dict:
    """Metadata that marks a layer as ``step``'s output (:func:`made_here`)."""
    return {OUTPUT_KEY: step}


def made_here(layer: Any) -> bool:
    """Whether the plugin made ``layer`` (a simulation, a calibrated or fitted image, a
    residual, an effect map): never a recording nor a recording's masks. Found as a
    user: after Auto-fit, Calibrate chose "auto-fit residual" as its recording and
    refused it for its negative values."""
    from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY

    return SYMBAC_METADATA_KEY in layer.metadata or OUTPUT_KEY in layer.metadata


def is_real_image(layer: Any) -> bool:
    """A grey image layer the plugin did not make and that holds no masks: a recording,
    or one still waiting for its pixel size."""
    from napari.layers import Image

    return (
        isinstance(layer, Image)
        and not layer.rgb
        and not made_here(layer)
        and not holds_masks(layer)
    )


def layer_pixel_size_um(layer: Any) -> float | None:
    """A recording's pixel size in um, or ``None``: the one entered in the Recording
    step or read from the file by this plugin's reader (``None`` there: none, or an
    implausible one entered); for a layer neither has seen, the one its reader set as
    the layer's scale (:func:`scale_pixel_um`). Found as a user: a TIFF opened by
    napari's own reader and scaled to 0.065 um was "no pixel size yet" to Diagnose and
    Simulate, and Auto-fit fitted an image without one at the simulation's."""
    if "pixel_size_um" in layer.metadata:
        pixel = layer.metadata["pixel_size_um"]
        return float(pixel) if pixel else None
    return scale_pixel_um(layer)


def is_recording(layer: Any) -> bool:
    """A real image layer (:func:`is_real_image`) with a usable pixel size."""
    return is_real_image(layer) and pixel_size_problem(layer_pixel_size_um(layer)) is None


def recordings(viewer: Any) -> list:
    """The recordings among the viewer's layers."""
    return [layer for layer in viewer.layers if is_recording(layer)]


def real_images(viewer: Any) -> list:
    """The viewer's grey images that the simulation did not make (a recording, or one
    still waiting for its pixel size)."""
    return [layer for layer in viewer.layers if is_real_image(layer)]


def mask_layers(viewer: Any) -> list:
    """The viewer's layers that can be a recording's cell masks: labels layers, and
    images that hold masks (a masks TIFF opened with napari's own reader,
    :func:`~napari_symbac.fit.preflight.looks_like_masks`); neither made by the
    simulation nor painted classes."""
    from napari.layers import Image, Labels

    from napari_symbac._widgets.real_image import class_layer_name

    return [
        layer
        for layer in viewer.layers
        if (
            isinstance(layer, Labels)
            or (isinstance(layer, Image) and not layer.rgb and holds_masks(layer))
        )
        and not made_here(layer)
        and not layer.name.endswith(class_layer_name(""))
    ]


def newest_masks(viewer: Any, recording: Any, only: Any = None) -> Any:
    """The newest of :func:`mask_layers` of ``recording``'s frame size with cells in it
    (``only``: the one layer to consider, one just added), or ``None``."""
    import numpy as np

    shape = tuple(recording.data.shape[-2:])
    matching = [
        layer
        for layer in mask_layers(viewer)
        if (only is None or layer is only)
        and tuple(layer.data.shape[-2:]) == shape
        and np.asarray(layer.data).any()
    ]
    return matching[-1] if matching else None


def choose_masks(box: Any, viewer: Any, recording: Any, only: Any = None) -> None:
    """With no cell masks chosen in the combo ``box``, choose :func:`newest_masks` of
    ``recording`` (``only``: the layer just added, the one to consider), as Tune's
    Auto-fit and Diagnose do."""
    if box.value is not None or recording is None:
        return
    box.reset_choices()
    masks = newest_masks(viewer, recording, only)
    if masks is not None:
        box.value = masks


def shown_frame(viewer: Any, data: Any) -> Any:
    """The frame of ``data`` on screen: of a ``(T, Y, X)`` layer the viewer's current
    time step (its last frame beyond), a 2D layer itself (every frame's)."""
    if data.ndim != 3:
        return data
    return data[min(int(viewer.dims.current_step[0]), len(data) - 1)]


def no_recording_message(viewer: Any, then: str) -> str:
    """Why no recording can be chosen, and what to do, ending with ``then``.

    Found as a user: with the trench opened but its pixel size not yet entered, Diagnose
    said "No recording: open your image and set its pixel size in Real image and
    classes": the image was open, and the workflow dock names that step *1 Recording*.
    An image that waits for its pixel size is now named, with the step to enter it in.
    """
    step = RECORDING_STEP
    waiting = [layer for layer in real_images(viewer) if not is_recording(layer)]
    if waiting:
        layer = waiting[-1]
        problem = waiting_problem(layer)
        if problem.startswith("no pixel size"):
            return f"{layer.name} has no pixel size yet: enter it in {step}, then {then}"
        return f"{layer.name}: {problem}; correct it in {step}, then {then}"
    return f"No recording: open your image in {step} and set its pixel size, then {then}"


def waiting_problem(layer: Any) -> str:
    """Why image ``layer`` is not yet a recording: the pixel size entered and refused
    (:data:`PIXEL_PROBLEM_KEY`), else none given; ``""`` for a recording."""
    refused = layer.metadata.get(PIXEL_PROBLEM_KEY)
    return refused or pixel_size_problem(layer_pixel_size_um(layer)) or ""


def followed_layer(event: Any, choices: list, busy: bool = False) -> Any:
    """The layer a :func:`watch_recordings` event is about when it is one of ``choices``:
    one just added to the viewer, or one whose metadata was replaced (its pixel size
    entered); else ``None``. The widgets choose it, so they work on the recording the
    user opened last (found as a user: Calibrate kept a trench chosen after a colony PNG
    was opened beside it, and refused the trench). ``None`` while the widget's job runs
    (``busy``): a running step keeps its recording in the dock (found as a user: a
    field opened during Calibrate became its recording above the report of another)."""
    if busy:
        return None
    kind = getattr(event, "type", "")
    layer = event.value if kind == "inserted" else event.source if kind == "metadata" else None
    return next((c for c in choices if c is not None and c is layer), None)


def watch_recordings(viewer: Any, refresh: Callable[..., None], links: ViewerLinks) -> None:
    """Call ``refresh`` whenever the viewer's recordings may have changed.

    That is when a layer is added or removed, and when an image layer's metadata is
    replaced (its pixel size entered or cleared in *Real image and classes*): without
    the latter a recording opened without a pixel size would stay missing from the
    other widgets' lists until some layer happened to be added. Connected through the
    step's ``links``, which its closed panel lets go.
    """
    from napari.layers import Image

    def watch(layer: Any) -> None:
        if isinstance(layer, Image):
            links.connect(layer.events.metadata, refresh)

    def inserted(event: Any) -> None:
        watch(event.value)
        refresh(event)

    for layer in viewer.layers:
        watch(layer)
    links.connect(viewer.layers.events.inserted, inserted)
    links.connect(viewer.layers.events.removed, refresh)


def recording_microscope(layer: Any, base: Microscope | None = None) -> Microscope:
    """The microscope of a recording layer: its stored one, with its pixel size and modality."""
    meta = layer.metadata
    microscope = meta.get("microscope") or base or Microscope()
    return dataclasses.replace(
        microscope,
        pixel_size_um=float(layer_pixel_size_um(layer)),
        modality=meta.get("modality") or microscope.modality,
    )


def modality_render(
    render: RenderSettings, modality: str, statistics: dict | None = None
) -> RenderSettings:
    """``render`` with intensities for ``modality``: measured class means when given.

    The class means of the recording (eq. 2, baseline subtracted with the camera's:
    :func:`recording_class_means`) start eq. 3's intensities, a class not among them its
    default scaled as the measured media is; otherwise the modality's defaults, which have
    the right polarity (fluorescence: bright cells on a dark background). Phase-only
    kernel terms (phase ring, offset) are switched off for fluorescence and bright field.
    """
    changes: dict[str, float] = dict(_DEFAULT_INTENSITIES[modality])
    if modality != "phase":
        changes.update(ring_contrast=0.0, psf_offset=0.0)
    if statistics:
        # a class not measured: its default in proportion to the measured media (an
        # 8-bit recording's tens of ADU were drawn beside PDMS at 900 ADU)
        scale = None
        if "media" in statistics:
            scale = max(float(statistics["media"]), 0.0) / changes["media_intensity"]
        for cls in ("cell", "media", "device"):
            key = f"{cls}_intensity"
            if cls in statistics:
                changes[key] = max(float(statistics[cls]), 0.0)
            elif scale is not None:
                changes[key] = changes[key] * scale
    return dataclasses.replace(render, **changes)


def first_frame(layer: Any) -> Any:
    """A recording layer's first frame (its only one for a single image), as an array."""
    import numpy as np

    return np.asarray(layer.data[(0,) * (layer.data.ndim - 2)])


def recording_camera(layer: Any) -> tuple[Camera, str]:
    """The camera of recording ``layer`` and where it comes from: the one given in the
    Recording step, else measured from its first frame as ``napari-symbac fit`` measures
    it without ``--camera`` (:func:`~napari_symbac.fit.scene_fit.recording_camera`: an
    8-bit recording gets an 8-bit camera and its own offset and noise).

    Raises
    ------
    ValueError
        For a frame the fit refuses (:func:`check_recording_frame`), in its words.
    """
    from napari_symbac.fit.report import unmeasured_noise_adu
    from napari_symbac.fit.scene_fit import recording_camera as measured_camera

    given = given_camera(layer)
    if given is not None:
        return given, "given in the Recording step"
    frame = first_frame(layer)
    check_recording_frame(frame, layer.name)
    camera = measured_camera(frame)
    if (sd := unmeasured_noise_adu(camera)) is not None:
        return camera, f"without a gain measurable from it: its pixel noise, {sd:.3g} ADU s.d."
    return camera, "measured from it"


def recording_class_means(
    layer: Any, modality: str, baseline_adu: float
) -> tuple[dict[str, float], str]:
    """The class means (ADU above the camera's ``baseline_adu``) that start eq. 3's
    intensities for recording ``layer``, and where they come from: its painted classes
    measured in the Recording step, else a rough split of its first frame into cells and
    background (:func:`~napari_symbac.fit.intensities.rough_class_means`)."""
    from napari_symbac.fit.intensities import rough_class_means

    painted = layer.metadata.get("class_means_adu")
    if painted:
        return dict(painted), "its painted classes"
    frame = first_frame(layer)
    field = default_geometry(frame.shape, modality) == "field"
    rough = rough_class_means(frame, modality, field=field)
    means = {cls: mean - baseline_adu for cls, mean in rough.items()}
    return means, "a rough split of it into cells and background"
