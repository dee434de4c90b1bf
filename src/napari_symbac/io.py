"""Read a user's real recordings with their pixel size (no Qt, no napari import)."""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "AXIS_LABELS",
    "CAMERA_MAX_ADU",
    "NORMALISED_ADU_PER_UNIT",
    "NORMALISED_MAX_RANGE",
    "SYMBAC_METADATA_KEY",
    "ChannelsError",
    "CountsMapping",
    "Recording",
    "as_counts",
    "grey_channel",
    "layer_axes",
    "napari_get_reader",
    "read_image",
    "read_recording",
    "tiff_axes_and_pixel_size",
]

#: A floating-point image of fractional values spanning at most this much holds
#: normalised intensities (DeLTA's crops, an image divided by its maximum), not counts.
NORMALISED_MAX_RANGE = 16.0
#: ADU per unit of a normalised image read as counts (:func:`as_counts`).
NORMALISED_ADU_PER_UNIT = 10_000.0
#: The largest count a synthetic camera writes (16 bits, :class:`~napari_symbac.settings.
#: Camera`): an image beyond it is read divided down (:func:`as_counts`).
CAMERA_MAX_ADU = 65_535
#: The value an image beyond 16 bits is divided to at most, leaving its noise room.
SCALED_MAX_ADU = 50_000.0

#: Names of a layer's ``(frame, Y, X)`` axes, for napari (the reader's layers and the
#: docks'). napari's own are ``-3, -2, -1``, and its frame slider read "-3" (found as a
#: user, taken for the frame number).
AXIS_LABELS = ("frame", "y", "x")
#: Layer-metadata key under which rendered layers carry their settings (and, when the
#: layer shows a whole simulation, the simulation): the widgets tell synthetic layers
#: from recordings by it.
SYMBAC_METADATA_KEY = "symbac"

_TIFF_SUFFIXES = (".tif", ".tiff", ".ome.tif", ".ome.tiff")
_PNG_SUFFIXES = (".png",)
#: Length units as microscopy files spell them (ImageJ, OME, vendors), in um: the micro
#: sign (U+00B5), the Greek mu (U+03BC) and ImageJ's escaped micro sign alike.
_UNIT_TO_UM = {
    **dict.fromkeys(("um", "µm", "μm", "\\u00b5m", "micron", "microns"), 1.0),
    **dict.fromkeys(("micrometer", "micrometre", "micrometers", "micrometres"), 1.0),
    **dict.fromkeys(("nm", "nanometer", "nanometre", "nanometers", "nanometres"), 1e-3),
    **dict.fromkeys(("mm", "millimeter", "millimetre"), 1e3),
    **dict.fromkeys(("cm", "centimeter", "centimetre"), 1e4),
    **dict.fromkeys(("å", "angstrom", "ångström"), 1e-4),
}


def unit_um(unit: str) -> float | None:
    """Micrometres in one ``unit`` of length as a file spells it, or None for a unit
    that is no length a microscope image is measured in (``pixel``, ``inch``, unknown).

    Before, an OME unit the reader did not know was read as um, and ImageJ's "microns"
    or "micrometer" not at all. napari's units (pint's ``nanometer``) read alike.
    """
    return _UNIT_TO_UM.get(str(unit).strip().lower())


def scale_um(scale: float, unit: object) -> float | None:
    """A layer's pixel ``scale`` in um: converted from its ``unit`` of length; a scale in
    napari's default unit, the pixel, is taken for micrometres, as readers that set no
    units mean it; None for a unit that is no length (seconds).

    Before, an image another reader opened in nanometres (scale 65) was taken for 65 um
    pixels.
    """
    name = str(unit)
    if name == "pixel":
        return float(scale)
    factor = unit_um(name)
    return None if factor is None else float(scale) * factor


@dataclass(frozen=True)
class CountsMapping:
    """How a normalised image, or one beyond 16 bits, was read as counts
    (:func:`as_counts`): ``counts_adu = (value + shift) * adu_per_unit``.

    Attributes
    ----------
    shift
        Added to every normalised value first: minus the image's minimum when it has
        negative values, else 0.
    adu_per_unit
        ADU per unit of the shifted values (:data:`NORMALISED_ADU_PER_UNIT`; below 1,
        ``1 / n``, for an image beyond 16 bits).
    value_min, value_max
        The span of the image's normalised (finite) values, before the map.
    """

    shift: float
    adu_per_unit: float
    value_min: float
    value_max: float

    def counts_adu(self, values: np.ndarray) -> np.ndarray:
        """Normalised ``values`` as counts (ADU, float64)."""
        return (np.asarray(values, np.float64) + self.shift) * self.adu_per_unit

    def values(self, counts_adu: np.ndarray) -> np.ndarray:
        """Counts (ADU) back to the normalised values they were read from (float64)."""
        return np.asarray(counts_adu, np.float64) / self.adu_per_unit - self.shift

    def camera(self, camera: Any) -> Any:
        """A :class:`~napari_symbac.settings.Camera` of the file's values (a data sheet,
        ``--camera``) in the units the image was read in: its baseline mapped as a
        value, its gain scaled; the read noise, in electrons, is the same."""
        return dataclasses.replace(
            camera,
            baseline_adu=float(self.counts_adu(camera.baseline_adu)),
            sensitivity_adu_per_e=camera.sensitivity_adu_per_e * self.adu_per_unit,
        )

    @property
    def divides(self) -> bool:
        """Whether the map divides an image beyond 16 bits (else it scales a normalised
        one up)."""
        return self.adu_per_unit < 1

    @property
    def formula(self) -> str:
        """The map in words: ``(value + 0.02847) x 10000 ADU`` (``(value) x ...``
        unshifted), ``value / 3 ADU`` for an image beyond 16 bits."""
        if self.divides and not self.shift:
            return f"value / {1 / self.adu_per_unit:g} ADU"
        shifted = f" + {self.shift:.4g}" if self.shift else ""
        return f"(value{shifted}) x {self.adu_per_unit:g} ADU"

    @property
    def what(self) -> str:
        """The image the map read, in a few words."""
        if self.divides:
            return "image beyond 16 bits read divided"
        return "normalised image read as counts"

    @property
    def note(self) -> str:
        """What reading did, for a user: the values' span, the map, and what is in ADU."""
        if self.divides:
            return (
                f"values up to {self.value_max:.6g}, beyond the 16 bits ({CAMERA_MAX_ADU}) "
                f"of a synthetic camera: read as {self.formula}, a linear map that keeps "
                "the noise the fit measures; intensities and datasets are in those units"
            )
        return (
            f"normalised values ({self.value_min:.4g}..{self.value_max:.4g}, not camera "
            f"counts): read as {self.formula}, so that the fit can measure their noise; "
            "intensities and datasets are in those units"
        )


@dataclass(frozen=True)
class Recording:
    """A real image or time series with what its file says about it.

    Attributes
    ----------
    data
        ``(Y, X)`` or ``(T, Y, X)`` array as stored.
    pixel_size_um
        Pixel size from the file's OME or ImageJ metadata, or ``None`` if absent.
    name
        File stem, for layer names.
    modality
        ``"phase"``, ``"fluorescence"`` or ``"brightfield"`` as the file's OME metadata
        says it of the channel read (:func:`_channel_modality`), or ``None`` if it does
        not say.
    kind
        ``"labels"`` for instance masks (marked ``napari_symbac=labels`` in the file's
        metadata by the dataset writers, or named like a mask: ``*_masks.tif``,
        ``man_seg*.tif``, ``man_track*.tif``, or in a ``labels/`` or ``masks/`` folder),
        ``"semantic"`` for semantic masks, else ``"image"``.
    counts_mapping
        How ``data`` was mapped to counts when it was a normalised image read as counts
        (:func:`as_counts`), else ``None``.
    planes_note
        How the planes of an ImageJ stack that may hold frames or channels were read
        (:func:`_series_axes`), else ``None``.
    frame_interval_s
        Time between frames from the file's ImageJ (``finterval``, in its ``tunit``) or
        OME (``TimeIncrement``) metadata, or ``None`` if absent.
    channel_modalities
        The modality of each of the file's channels, as its OME metadata says
        (``None`` each where it does not); ``()`` for a file without OME metadata.
    """

    data: np.ndarray
    pixel_size_um: float | None
    name: str
    modality: str | None = None
    kind: str = "image"
    counts_mapping: CountsMapping | None = None
    planes_note: str | None = None
    frame_interval_s: float | None = None
    channel_modalities: tuple[str | None, ...] = ()

    @property
    def note(self) -> str | None:
        """What reading did, in words, if anything: the planes read as frames
        (``planes_note``) and the values mapped to counts (``counts_mapping``'s note)."""
        counts = None if self.counts_mapping is None else self.counts_mapping.note
        return "; ".join(note for note in (self.planes_note, counts) if note) or None


def _pixel_size_um(tif) -> float | None:
    if tif.is_ome and tif.ome_metadata:
        import re

        match = re.search(r'PhysicalSizeX="([0-9.eE+-]+)"', tif.ome_metadata)
        unit = re.search(r'PhysicalSizeXUnit="([^"]+)"', tif.ome_metadata)
        factor = unit_um(unit.group(1)) if unit else 1.0  # OME's default unit is um
        if match and factor is not None:
            return float(match.group(1)) * factor
    page = tif.pages[0]
    tag = page.tags.get("XResolution")
    if tag is None:
        return None
    numerator, denominator = tag.value
    if not numerator:
        return None
    pixels_per_unit = numerator / denominator
    factor = unit_um((tif.imagej_metadata or {}).get("unit", ""))
    if tif.is_imagej and factor is not None:
        return factor / pixels_per_unit
    resolution_unit = page.tags.get("ResolutionUnit")
    if resolution_unit is not None and int(resolution_unit.value) == 3:  # centimetre
        return 1e4 / pixels_per_unit
    return None


#: Seconds per unit of time, as ImageJ (``tunit``) and OME (``TimeIncrementUnit``) spell it.
_SECONDS = {"s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0, "ms": 1e-3, "min": 60.0,
            "minute": 60.0, "minutes": 60.0, "h": 3600.0, "hr": 3600.0, "hour": 3600.0,
            "hours": 3600.0}  # fmt: skip


def _frame_interval_s(tif) -> float | None:
    """The time between frames the file records (ImageJ ``finterval`` in ``tunit``,
    seconds when unsaid; OME ``TimeIncrement``), or ``None``."""
    if tif.is_ome and tif.ome_metadata:
        match = re.search(r'TimeIncrement="([0-9.eE+-]+)"', tif.ome_metadata)
        unit = re.search(r'TimeIncrementUnit="([^"]+)"', tif.ome_metadata)
        factor = _SECONDS.get(unit.group(1).lower() if unit else "s")
        if match and factor is not None and float(match.group(1)) > 0:
            return float(match.group(1)) * factor
    meta = tif.imagej_metadata or {}
    interval = meta.get("finterval")
    factor = _SECONDS.get(str(meta.get("tunit", "sec")).lower())
    if isinstance(interval, (int, float)) and interval > 0 and factor is not None:
        return float(interval) * factor
    return None


_CONTRAST_METHODS = {"Phase": "phase", "Fluorescence": "fluorescence", "Brightfield": "brightfield"}

#: Words of an OME channel's name that say its modality, where its ``ContrastMethod``
#: does not (found as a user: channels named BF and GFP were both guessed phase).
_CHANNEL_NAME_WORDS = {
    "phase": {"phase", "ph", "ph1", "ph2", "ph3", "pc", "phc", "phasecontrast"},
    "brightfield": {"bf", "brightfield", "transmitted", "trans"},
    "fluorescence": {
        "fluorescence", "fluo", "gfp", "egfp", "sfgfp", "yfp", "eyfp", "cfp", "rfp",
        "mcherry", "mscarlet", "mkate", "mkate2", "tdtomato", "venus", "mvenus",
        "mneongreen", "mturquoise", "dapi", "hoechst", "fitc", "tritc", "cy3", "cy5",
        "sytox", "fm4", "alexa", "mrfp", "tagrfp",
    },
}  # fmt: skip


def _channel_modality(attributes: str) -> str | None:
    """The modality an OME ``<Channel ...>`` element's attributes say: its
    ``ContrastMethod``, an ``IlluminationType`` of epifluorescence or a ``Fluor``, else
    a word of its ``Name`` (:data:`_CHANNEL_NAME_WORDS`); ``None`` if none does."""

    def attribute(key: str) -> str:
        found = re.search(rf'\b{key}="([^"]*)"', attributes)
        return found.group(1).strip() if found else ""

    if attribute("ContrastMethod") in _CONTRAST_METHODS:
        return _CONTRAST_METHODS[attribute("ContrastMethod")]
    if attribute("IlluminationType") == "Epifluorescence" or attribute("Fluor"):
        return "fluorescence"
    words = set(re.split(r"[^a-z0-9]+", attribute("Name").lower()))
    for modality, named in _CHANNEL_NAME_WORDS.items():
        if words & named:
            return modality
    return None


def _channel_modalities(tif) -> tuple[str | None, ...]:
    """The modality of each channel an OME-TIFF describes (:func:`_channel_modality`),
    in order; ``()`` for any other file."""
    if not (tif.is_ome and tif.ome_metadata):
        return ()
    return tuple(
        _channel_modality(attributes)
        for attributes in re.findall(r"<Channel\b([^>]*)>", tif.ome_metadata)
    )


#: Words that name a file (its last word: ``cell_mask.tif``, ``Sample_cp_masks.tif``,
#: ColiCoords' ``binary.tif``) or its folder (``binary/00001.tif``) as masks.
_MASK_WORDS = ("binary", "label", "labels", "mask", "masks", "seg", "segmentation")


def _kind(tif, path: Path) -> str:
    from napari_symbac.export.atomic import TIFF_KIND_KEY, TIFF_KINDS

    for metadata in (tif.imagej_metadata, *(tif.shaped_metadata or ())):
        if metadata and metadata.get(TIFF_KIND_KEY) in TIFF_KINDS:
            return str(metadata[TIFF_KIND_KEY])
    name = path.name.lower()
    words = re.split(r"[\s_.-]+", name.split(".")[0])
    if (
        words[-1] in _MASK_WORDS
        or name.startswith(("man_seg", "man_track"))
        or path.parent.name.lower() in _MASK_WORDS
    ):
        return "labels"
    return "image"


def _check_complete(tif, path: Path) -> None:
    """Refuse a file that ends before its image data does (a truncated copy or download).

    tifffile reads what it can of such a file and only logs a warning, which would
    silently give fewer frames than the file holds.
    """
    size = tif.filehandle.size
    expected_pages = (tif.imagej_metadata or {}).get("images")
    ends = [
        offset + count
        for page in tif.pages
        for offset, count in zip(page.dataoffsets, page.databytecounts)
    ]
    if max(ends, default=0) > size or (
        isinstance(expected_pages, int) and expected_pages > len(tif.pages)
    ):
        raise ValueError(
            f"{path} is truncated: the file ends ({size} bytes) before its image data "
            "does; copy or download it again"
        )


class ChannelsError(ValueError):
    """A TIFF of several channels read without the channel to take
    (:func:`read_recording`'s ``channel``). ``cause`` says what the file holds and
    ``n_channels`` how many; the message adds the fix of the Python API, each other
    interface words its own (``--channel``, a layer per channel)."""

    def __init__(self, name: str, n_channels: int, axes: str, shape: tuple[int, ...]) -> None:
        self.n_channels = n_channels
        self.cause = f"{name} holds {n_channels} channels (axes {axes}, shape {shape})"
        super().__init__(
            f"{self.cause}, and a recording is one channel: pass channel=K (0..{n_channels - 1})"
        )


#: Axes of a TIFF series (tifffile's codes) read as the frames of a recording: time, and
#: the image sequences of files that do not say what their pages are.
_FRAME_AXES = "TIQ"
#: What the other axes of more than one plane hold, in a refusal's words.
_AXIS_WORDS = {"Z": "focal planes", "P": "stage positions", "R": "tiles", "E": "wavelengths"}


#: The axis letter of :func:`_series_axes` for an ImageJ stack's channels in grey mode:
#: frames, unless a channel is asked for.
_FRAMES_OR_CHANNELS = "c"


def _series_axes(tif) -> str:
    """tifffile's axes of the file's first series, where its ``C`` holds channels only
    when the file says so: OME metadata, an ImageJ hyperstack shown as composite or
    colour (Fiji's channels), or tifffile's own record of the axes it was given. The
    channels of an ImageJ stack in grey mode are :data:`_FRAMES_OR_CHANNELS`: read as
    frames, since tifffile writes ``imwrite(path, stack, imagej=True)`` of a time series,
    axes unsaid, as channels, and as channels when one is asked for (found as a user: a
    2-channel ImageJ TIFF was read as 2 frames, and ``--channel 1`` was refused)."""
    axes = tif.series[0].axes
    plain_imagej = tif.is_imagej and not tif.is_ome
    if "Z" in axes and plain_imagej and not (tif.imagej_metadata or {}).get("hyperstack"):
        # an ImageJ stack that is no hyperstack records its pages as slices (Z), a time
        # series as often as a z-stack: they are the frames unless frames are named too;
        # a Z that OME, a hyperstack or tifffile's own record names is focal planes
        # (found as a user: an OME z-stack was read as a time-lapse)
        axes = axes if any(a in axes for a in _FRAME_AXES) else axes.replace("Z", "Q")
    if "C" in axes and plain_imagej:
        mode = (tif.imagej_metadata or {}).get("mode")
        if mode not in ("composite", "color"):
            axes = axes.replace("C", _FRAMES_OR_CHANNELS)
    return axes


def _one_channel(
    data: np.ndarray, axes: str, name: str, channel: int | None
) -> np.ndarray:
    """``data`` (a TIFF series with tifffile's ``axes``, singleton axes squeezed) as
    ``([frames,] Y, X)`` or colour ``(..., S)``: channel ``channel`` of a channel axis,
    other axes of several planes refused by name (focal planes beside frames)."""
    shape = tuple(int(n) for n in data.shape)
    for axis in axes:
        if axis not in _FRAME_AXES + "CYXS":
            what = _AXIS_WORDS.get(axis, f"planes along its axis {axis}")
            raise ValueError(
                f"{name} holds {shape[axes.index(axis)]} {what} (axes {axes}, shape {shape}): "
                "a recording is (frames, Y, X) of one plane; save the plane to read as its "
                "own TIFF (in Fiji: Image > Stacks > Tools > Make Substack)"
            )
    if "C" not in axes and "S" in axes and channel is not None:  # colour samples (RGB):
        # the one asked for (found as a user: --channel 1 of an RGB TIFF was refused)
        n_samples = shape[axes.index("S")]
        if not 0 <= channel < n_samples:
            raise ValueError(
                f"channel {channel}: {name} is a colour image of channels 0..{n_samples - 1}"
            )
        return np.take(data, channel, axis=axes.index("S"))
    if "C" not in axes:
        if channel not in (None, 0):
            raise ValueError(f"{name} holds one channel (axes {axes}): leave the channel out")
        return data
    n_channels = shape[axes.index("C")]
    if channel is None:
        raise ChannelsError(name, n_channels, axes, shape)
    if not 0 <= channel < n_channels:
        raise ValueError(f"channel {channel}: {name} has channels 0..{n_channels - 1}")
    return np.take(data, channel, axis=axes.index("C"))


def tiff_axes_and_pixel_size(path: str | Path | None) -> tuple[str, float | None] | None:
    """The axes of a TIFF's first series (``C`` only where the file says channels, as
    :func:`read_recording` reads them) and the pixel size it records (um, or ``None``),
    read from its metadata alone; ``None`` for no path or a file that is no readable TIFF.
    For a layer another reader opened (napari's own keeps neither)."""
    import tifffile

    if path is None or _file_kind(Path(path)) != "tiff":
        return None
    try:
        with tifffile.TiffFile(path) as tif:
            return _series_axes(tif), _pixel_size_um(tif)
    except (OSError, ValueError, IndexError, tifffile.TiffFileError):
        return None


def read_recording(path: str | Path, channel: int | None = None) -> Recording:
    """Read a TIFF recording, its pixel size and whether it holds an image or masks.

    Parameters
    ----------
    path
        The TIFF.
    channel
        The channel to read of a TIFF of several (an ImageJ hyperstack or OME-TIFF with
        a channel axis); ``None`` for a file of one channel.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ChannelsError
        If the file holds several channels and ``channel`` is ``None``.
    ValueError
        If the file is not a TIFF, is truncated or corrupt, holds several focal planes
        (or other planes than frames and channels), or has no channel ``channel`` (the
        message names the file).
    """
    path = Path(path)
    return _channel_of(*_read_tiff(path), path.name, channel)


def _channel_of(recording: Recording, axes: str, name: str, channel: int | None) -> Recording:
    """``recording`` (as :func:`_read_tiff` read it) with its channel ``channel`` only
    (:func:`_one_channel`); an ImageJ stack's planes that may be frames or channels
    (:data:`_FRAMES_OR_CHANNELS`) are frames without ``channel``, said in its note."""
    note = None
    if _FRAMES_OR_CHANNELS in axes:
        n_planes = int(np.shape(recording.data)[axes.index(_FRAMES_OR_CHANNELS)])
        axes = axes.replace(_FRAMES_OR_CHANNELS, "Q" if channel is None else "C")
        if channel is None and n_planes > 1:
            note = (
                f"its {n_planes} planes, ImageJ channels in grey mode (as tifffile writes a "
                "stack whose axes were not given), are read as frames; if they are "
                f"channels, choose one (--channel K, K in 0..{n_planes - 1})"
            )
    data = _one_channel(recording.data, axes, name, channel)
    said = recording.channel_modalities
    modality = said[channel or 0] if len(said) > (channel or 0) else recording.modality
    return dataclasses.replace(recording, data=data, planes_note=note, modality=modality)


def _file_kind(path: Path) -> str | None:
    """``"tiff"`` or ``"png"`` from a file's first bytes (its signature), else ``None``.
    Found as a user: a TIFF saved without an extension was "not a TIFF or PNG file", a
    PNG named ``.tif`` "not a readable TIFF ... convert it to TIFF"."""
    try:
        with open(path, "rb") as file:
            head = file.read(8)
    except OSError:
        return None
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):  # TIFF, BigTIFF
        return "tiff"
    if head == b"\x89PNG\r\n\x1a\n":
        return "png"
    return None


def _read_tiff(path: Path) -> tuple[Recording, str]:
    """The TIFF at ``path`` as read (every channel), and its axes (:func:`_series_axes`);
    the refusals of :func:`read_recording` but those of its channels and planes."""
    import logging

    import tifffile

    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist")
    signature = _file_kind(path)
    if signature == "png":
        raise ValueError(f"{path.name} is a PNG file, not a TIFF: name it .png")
    if signature is None and not path.name.lower().endswith(_TIFF_SUFFIXES):
        raise ValueError(f"{path.name} is not a TIFF file (.tif/.tiff)")
    log = logging.getLogger("tifffile")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)  # corruption is reported below, with the file name
    try:
        with tifffile.TiffFile(path) as tif:
            _check_complete(tif, path)
            _refuse_images_of_several_sizes(tif, path)
            data, axes = tif.asarray(), _series_axes(tif)
            pixel = _pixel_size_um(tif)
            interval = _frame_interval_s(tif)
            modalities = _channel_modalities(tif)
            kind = _kind(tif, path)
    except (tifffile.TiffFileError, ValueError, EOFError, struct.error, IndexError) as err:
        if str(path) in str(err):
            raise ValueError(str(err)) from err
        raise ValueError(
            f"{path} is not a readable TIFF ({err}): it may be truncated or not a TIFF; "
            "copy it again or convert it to TIFF"
        ) from err
    finally:
        log.setLevel(level)
    name = path.name
    for suffix in _TIFF_SUFFIXES:
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    recording = Recording(
        data=data, pixel_size_um=pixel, name=name, kind=kind, frame_interval_s=interval,
        channel_modalities=modalities,
    )  # fmt: skip
    return recording, axes


def _refuse_images_of_several_sizes(tif, path: Path) -> None:
    """Refuse a TIFF of several images (tifffile's series: pages of different sizes, or
    stacks written one after another), of which only the first would be read: found as
    a user, pages of 200 x 200 and 180 x 220 px were read as one frame without a word.
    Reduced-resolution pages (thumbnails, a pyramid's levels) are not images of their
    own."""
    shapes = [
        tuple(series.shape)
        for series in tif.series
        if not getattr(series.pages[0], "is_reduced", False)
    ]
    if len(shapes) > 1:
        sizes = ", ".join(" x ".join(map(str, shape)) for shape in shapes[:4])
        same = len(set(shapes)) == 1
        raise ValueError(
            f"{path} holds {len(shapes)} separate images ({sizes}{', ...' * (len(shapes) > 4)})"
            " and only the first would be read: a recording is one image or one stack of "
            + (
                "frames; save them as one stack (e.g. tifffile.imwrite(path, np.stack(frames)))"
                if same
                else "frames of one size; save each image as its own TIFF"
            )
        )


def as_counts(data: np.ndarray) -> tuple[np.ndarray, CountsMapping | None]:
    """A normalised image, or one beyond 16 bits, as counts the model can render, and
    how it was mapped; other images as they are, and ``None``.

    An image of non-negative values above :data:`CAMERA_MAX_ADU` (a sum projection, a
    32-bit camera, a rescaled float) is divided by the smallest whole number that brings
    it within :data:`SCALED_MAX_ADU`: a synthetic camera writes 16 bits, and read as it
    was it gave a dataset clipped at 65535 over a fifth of its pixels, unsaid (found as
    a user).

    A normalised image (floating point, fractional values spanning at most
    :data:`NORMALISED_MAX_RANGE`) has no camera counts: its noise and intensities are
    a camera's divided by some constant. Read as they are, its dataset holds only the
    integers 0 and 1 (found as a user on DeLTA's normalised trench). It is shifted so
    that its minimum is 0 when it has negative values and scaled by
    :data:`NORMALISED_ADU_PER_UNIT`: a linear map, which keeps the photon-transfer
    line from which the fit measures the camera.
    """
    array = np.asarray(data)
    numeric = np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)
    if not numeric or array.size == 0:
        return data, None
    finite = array[np.isfinite(array)]
    if finite.size == 0:
        return data, None
    if finite.max() > CAMERA_MAX_ADU and finite.min() >= 0:
        divisor = math.ceil(float(finite.max()) / SCALED_MAX_ADU)
        scaled = CountsMapping(
            shift=0.0,
            adu_per_unit=1.0 / divisor,
            value_min=float(finite.min()),
            value_max=float(finite.max()),
        )
        return scaled.counts_adu(array), scaled
    if not np.issubdtype(array.dtype, np.floating) or np.ptp(finite) > NORMALISED_MAX_RANGE:
        return data, None
    if np.all(finite == np.round(finite)):
        return data, None  # whole numbers: counts (or a mask) stored as floats
    low = float(finite.min())
    mapping = CountsMapping(
        shift=-low if low < 0 else 0.0,
        adu_per_unit=NORMALISED_ADU_PER_UNIT,
        value_min=low,
        value_max=float(finite.max()),
    )
    return mapping.counts_adu(array), mapping


def read_image(
    path: str | Path, what: str = "image", *, counts: bool = False, channel: int | None = None
) -> Recording:
    """Read a recording for the command line: a TIFF (:func:`read_recording`) or a PNG.

    A PNG records no pixel size or modality. An RGB(A) image whose colour channels are
    equal (a grey image saved as colour, as the Omnipose sample colonies are) is read as
    its grey channel; a colour image is refused, as napari's grey-channel layer is the
    only one the widgets take.

    Parameters
    ----------
    path
        ``.tif``/``.tiff``/``.ome.tif`` or ``.png`` file.
    what
        How messages name the file (``"IMAGE"``, ``"--masks"``, ...).
    counts
        Read a normalised image as counts (:func:`as_counts`; the recording's
        ``counts_mapping`` says how): for the recording to fit, not for masks or dark
        frames.
    channel
        The channel of a TIFF of several (:func:`read_recording`); a PNG has one.

    Raises
    ------
    ValueError
        If the file is missing or a folder, not a TIFF or PNG, unreadable, or in colour;
        the message names the file and what to do.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(
            f"{what} {path} is a folder: give the path of an image file (TIFF or PNG)"
        )
    if not path.is_file():
        raise ValueError(f"{what} {path} does not exist")
    lower = path.name.lower()
    kind = _file_kind(path) or ("png" if lower.endswith(_PNG_SUFFIXES) else None)
    if kind == "png":
        import imageio.v3 as iio

        try:
            data = np.asarray(iio.imread(path))
        except (OSError, ValueError) as err:
            raise ValueError(f"{what} {path.name} is not a readable PNG: {err}") from err
        if channel is not None and data.ndim == 3 and data.shape[-1] in (3, 4):
            if not 0 <= channel < data.shape[-1]:  # a colour PNG: the channel asked for
                raise ValueError(
                    f"channel {channel}: {what} {path.name} is a colour image of channels "
                    f"0..{data.shape[-1] - 1}"
                )
            data = data[..., channel]
        elif channel not in (None, 0):
            raise ValueError(f"{what} {path.name} is a PNG, one channel: leave the channel out")
        recording = Recording(data=data, pixel_size_um=None, name=path.stem)
    elif kind == "tiff" or lower.endswith(_TIFF_SUFFIXES):
        recording = read_recording(path, channel)
    else:
        raise ValueError(
            f"{what} {path.name} is not a TIFF or PNG file (neither its name nor its first "
            "bytes say so): convert it to TIFF"
        )
    data = recording.data
    if data.ndim == 3 and data.shape[-1] in (3, 4) and min(data.shape[:2]) > 4:
        grey = grey_channel(data)
        if grey is None:
            pick = ", or pick one with --channel K (0 red, 1 green, 2 blue)"
            pick = "" if what == "recording" else pick  # the Real image dock has no flag
            raise ValueError(
                f"{what} {path.name} is a colour image {data.shape}: save one grey channel "
                f"(the camera's raw frame){pick}"
            )
        recording = dataclasses.replace(recording, data=np.ascontiguousarray(grey))
    if counts:
        data, mapping = as_counts(recording.data)
        recording = dataclasses.replace(recording, data=data, counts_mapping=mapping)
    return recording


def grey_channel(rgb: np.ndarray) -> np.ndarray | None:
    """The grey channel of an RGB(A) ``(..., 3|4)`` array whose red, green and blue are
    equal (a grey image saved as colour), or ``None`` for a colour image."""
    colour = np.asarray(rgb)[..., :3]
    red = colour[..., 0]
    if np.array_equal(red, colour[..., 1]) and np.array_equal(red, colour[..., 2]):
        return red
    return None


def micrometre_axes(pixel_size_um: float, ndim: int) -> dict[str, tuple]:
    """Layer keyword arguments that place a ``(..., Y, X)`` layer in micrometres.

    The scale of the last two axes and their unit, so that napari's scale bar and the
    cursor's coordinates read um rather than "pixel" (the leading axes, frames, keep a
    step of 1 and napari's default unit).
    """
    lead = ndim - 2
    return {
        "scale": (1.0,) * lead + (float(pixel_size_um),) * 2,
        "units": ("pixel",) * lead + ("um", "um"),
    }


def axis_labels(ndim: int) -> tuple[str, ...]:
    """Names of the axes of an ``ndim``-axis ``(..., frame, Y, X)`` layer: ``y, x`` for a
    frame, ``frame, y, x`` for a time series (:data:`AXIS_LABELS`), any axis before those
    named by its position."""
    lead = tuple(f"axis {i}" for i in range(max(ndim - len(AXIS_LABELS), 0)))
    return lead + AXIS_LABELS[-min(ndim, len(AXIS_LABELS)) :]


def layer_axes(pixel_size_um: float, ndim: int) -> dict[str, tuple]:
    """Layer keyword arguments that place a ``(..., Y, X)`` layer in micrometres
    (:func:`micrometre_axes`) with its axes named (:func:`axis_labels`, as the plugin's
    reader names them)."""
    return {**micrometre_axes(pixel_size_um, ndim), "axis_labels": axis_labels(ndim)}


def napari_get_reader(path):
    """npe2 reader: a TIFF recording as an image layer scaled to micrometres."""
    if isinstance(path, list) or not str(path).lower().endswith(_TIFF_SUFFIXES):
        return None
    return _read_layers


def _read_layers(path) -> list[tuple]:
    """The recording's layer; one per channel of a TIFF of several (napari's way: the
    channel to fit is then chosen as a layer), named ``"NAME channel K"``. The file is
    read once."""
    path = Path(path)
    recording, axes = _read_tiff(path)
    try:
        return [_recording_layer(_channel_of(recording, axes, path.name, None))]
    except ChannelsError as err:
        names = _ome_channel_names(path)
        if len(names) != err.n_channels:
            names = [""] * err.n_channels
        return [
            _recording_layer(
                _channel_of(recording, axes, path.name, k), f" {names[k] or f'channel {k}'}"
            )
            for k in range(err.n_channels)
        ]


def _ome_channel_names(path: Path) -> list[str]:
    """The channels' names an OME-TIFF records (``<Channel Name="GFP">``), in order, ''
    for a channel without one; [] for any other file. Found as a user: an OME file of
    channels BF and GFP opened as "channel 0" and "channel 1"."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        if not (tif.is_ome and tif.ome_metadata):
            return []
        channels = re.findall(r"<Channel\b([^>]*)>", tif.ome_metadata)
    names = [re.search(r'\bName="([^"]*)"', attributes) for attributes in channels]
    return [name.group(1).strip() if name else "" for name in names]


def _recording_layer(recording: Recording, suffix: str = "") -> tuple:
    meta = {
        "name": recording.name + suffix,
        "metadata": {"pixel_size_um": recording.pixel_size_um, "modality": recording.modality},
        "axis_labels": axis_labels(recording.data.ndim),
    }
    if recording.pixel_size_um:
        meta.update(micrometre_axes(recording.pixel_size_um, recording.data.ndim))
    is_mask = recording.kind in ("labels", "semantic")
    if is_mask and np.issubdtype(recording.data.dtype, np.integer):
        return (recording.data, meta, "labels")
    data, mapping = as_counts(recording.data)  # as the Real image dock's *or open* reads it
    if mapping is not None:
        meta["metadata"]["counts_mapping"] = mapping
    return (data, meta, "image")
