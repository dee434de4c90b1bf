"""The microscope file of ``fit``, ``calibrate`` and ``diagnose`` (issue 11's keys)."""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path

from napari_symbac.settings import (
    Camera,
    Microscope,
    SimulationSettings,
    from_dict,
    read_settings_mapping,
    refuse_another_kind,
)

__all__ = [
    "DEFAULT_OPTICS_NOTE",
    "NO_CAMERA_NOTE",
    "DiagnoseConfig",
    "load_microscope_file",
    "parse_microscope",
]

REQUIRED = ("modality", "pixel_size_um", "NA", "refractive_index", "wavelength_um")
OPTIONAL = (
    "condenser",
    "trench_width_um",
    "objective",
    "magnification",
    "camera",
    "frame_interval_s",
)
#: The :class:`~napari_symbac.settings.Microscope` field names (what ``napari-symbac
#: defaults microscope`` writes) for the keys this file names otherwise.
ALIASES = {"numerical_aperture": "NA"}
CAMERA_KEYS = ("baseline_adu", "sensitivity_adu_per_e", "dark_noise_e")
#: What ``diagnose`` says of a microscope file without a camera.
NO_CAMERA_NOTE = (
    "no camera given: its gain and read noise are measured from the recording (add "
    "camera: {baseline_adu, sensitivity_adu_per_e, dark_noise_e} to give it)"
)


@dataclass(frozen=True)
class DiagnoseConfig:
    """Microscope and camera of the recording, plus optional trench width and frame interval.

    ``camera`` is ``None`` when the file gives none: the command then measures it from
    the recording (as ``napari-symbac fit`` does).
    """

    microscope: Microscope
    camera: Camera | None
    trench_width_um: float | None = None
    frame_interval_s: float | None = None
    notes: tuple[str, ...] = ()
    #: No file was given: :class:`Microscope`'s defaults stand in for it.
    defaulted: bool = False

    def notes_for(self, modality: str) -> tuple[str, ...]:
        """:attr:`notes`, and when :attr:`defaulted` a note naming the default optics
        that image a recording of ``modality`` (the condenser only for phase contrast:
        found as a user, a fluorescence fit was told of a Ph3 condenser)."""
        if not self.defaulted:
            return self.notes
        scope = self.microscope
        condenser = f", condenser {scope.condenser}" if modality == "phase" else ""
        note = DEFAULT_OPTICS_NOTE.format(
            na=scope.numerical_aperture, wavelength=scope.wavelength_um,
            n=scope.refractive_index, condenser=condenser,
        )  # fmt: skip
        return (*self.notes, note)

    def timed(
        self, simulation: SimulationSettings, recorded_s: float | None = None
    ) -> SimulationSettings:
        """``simulation`` at the recording's frame interval: this file's
        ``frame_interval_s``, else ``recorded_s`` (the image file's own,
        :attr:`~napari_symbac.io.Recording.frame_interval_s`), else as it is. Found as a
        user: ``frame_interval_s`` was read and ignored, and a fit's settings.yaml drew its
        time series 3 min apart whatever the recording's interval (its cells then grow
        three times as much per frame as a 1-min recording's)."""
        interval_s = self.frame_interval_s if self.frame_interval_s is not None else recorded_s
        if interval_s is None:
            return simulation
        return dataclasses.replace(simulation, frame_interval_min=interval_s / 60)


def _number(data: dict, key: str, where: str) -> float:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)


def parse_microscope(data: object, where: str = "microscope file") -> DiagnoseConfig:
    """Validate the mapping of issue 11 and build the settings.

    Required: ``modality`` ("phase" | "fluorescence" | "brightfield"), ``pixel_size_um``, ``NA``,
    ``refractive_index``, ``wavelength_um``. Optional: ``condenser``,
    ``trench_width_um``, ``objective`` (e.g. "100x oil": its magnification is read),
    ``magnification``, ``camera`` {``baseline_adu``, ``sensitivity_adu_per_e``,
    ``dark_noise_e``}, ``frame_interval_s``. The microscope file that ``napari-symbac
    defaults microscope`` writes (``numerical_aperture`` for ``NA``) is read as well, so
    that one file serves every command. Unknown keys are ignored with a note.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a mapping of keys to values, got {type(data).__name__}")
    for alias, key in ALIASES.items():
        if alias in data:
            if key in data and data[key] != data[alias]:
                raise ValueError(
                    f"{where} gives both {key} ({data[key]!r}) and {alias} ({data[alias]!r}): "
                    "keep one"
                )
            data = {key if k == alias else k: v for k, v in data.items()}
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ValueError(
            f"{where} lacks the required key(s) {', '.join(missing)}; it needs "
            f"{', '.join(REQUIRED)} (e.g. modality: phase, pixel_size_um: 0.065, NA: 1.45, "
            "refractive_index: 1.518, wavelength_um: 0.65), or write one with "
            "`napari-symbac defaults microscope --out FILE`"
        )
    notes = [f"unknown key {k!r} ignored" for k in data if k not in REQUIRED + OPTIONAL]
    modality = data["modality"]
    if modality not in ("phase", "fluorescence", "brightfield"):
        raise ValueError(
            f"{where}: modality must be 'phase', 'fluorescence' or 'brightfield', got "
            f"{modality!r}"
        )
    kwargs: dict = {
        "modality": modality,
        "pixel_size_um": _number(data, "pixel_size_um", where),
        "numerical_aperture": _number(data, "NA", where),
        "refractive_index": _number(data, "refractive_index", where),
        "wavelength_um": _number(data, "wavelength_um", where),
    }
    if "condenser" in data:
        kwargs["condenser"] = str(data["condenser"])
    if "magnification" in data:
        kwargs["magnification"] = _number(data, "magnification", where)
    if "objective" in data:
        match = re.search(r"(\d+(?:\.\d+)?)\s*[xX]", str(data["objective"]))
        if match:
            kwargs["magnification"] = float(match.group(1))
        else:
            notes.append(
                f"objective {data['objective']!r}: no magnification found (e.g. '100x oil')"
            )
    return _with_extras(Microscope(**kwargs), data, where, notes)


def _with_extras(
    microscope: Microscope, data: dict, where: str, notes: list[str]
) -> DiagnoseConfig:
    """``microscope`` with the keys of :data:`DIAGNOSE_KEYS` read from ``data``."""
    camera = None
    if "camera" in data:
        cam = data["camera"]
        if not isinstance(cam, dict):
            raise ValueError(f"{where}: camera must be a mapping with {', '.join(CAMERA_KEYS)}")
        unknown = [k for k in cam if k not in CAMERA_KEYS]
        if unknown:  # found as a user: `baseline:` was ignored with a note, exit 0
            raise ValueError(
                f"{where}: unknown camera key(s) {', '.join(map(repr, unknown))}; the camera "
                f"takes {', '.join(CAMERA_KEYS)}"
            )
        camera = Camera(**{k: _number(cam, k, f"{where} camera") for k in CAMERA_KEYS if k in cam})
    width = _number(data, "trench_width_um", where) if "trench_width_um" in data else None
    if width is not None:  # found as a user: read, and used by no command
        notes.append("trench_width_um is not used: the trench's width is fitted from the image")
    interval = _number(data, "frame_interval_s", where) if "frame_interval_s" in data else None
    return DiagnoseConfig(microscope, camera, width, interval, tuple(notes))


#: Keys of the diagnose microscope file beside the :class:`Microscope` fields.
DIAGNOSE_KEYS = ("camera", "trench_width_um", "frame_interval_s")


#: What fit, calibrate and diagnose say when no microscope file is given.
DEFAULT_OPTICS_NOTE = (
    "no --microscope: the default optics (NA {na:g}, wavelength {wavelength:g} um, "
    "refractive index {n:g}{condenser}); give yours in a file, which "
    "`napari-symbac defaults microscope --out M.yaml` writes to edit"
)


def load_microscope_file(path: str | Path | None) -> DiagnoseConfig:
    """Read a JSON or YAML microscope file (``--microscope`` of fit, calibrate and
    diagnose) and its camera section; without one (``None``), :class:`Microscope`'s
    defaults, no camera and :attr:`DiagnoseConfig.defaulted` (its notes then say so;
    found as a user: a pixel size given with ``--pixel-size-um`` still needed a file
    written first).

    Either :class:`~napari_symbac.settings.Microscope` fields as ``fit`` reads them (any
    may be left out and takes its default; an unknown key is named) plus the keys of
    :data:`DIAGNOSE_KEYS`, or diagnose's own spelling (``NA``, ...; :func:`parse_microscope`).
    """
    if path is None:
        return DiagnoseConfig(Microscope(), None, defaulted=True)
    data = read_settings_mapping(path)
    if isinstance(data, dict) and "NA" in data:
        return parse_microscope(data, str(path))
    if not isinstance(data, dict):
        raise ValueError(
            f"microscope file {path} must be a mapping of keys to values, got "
            f"{type(data).__name__}"
        )
    extras = {key: data[key] for key in DIAGNOSE_KEYS if key in data}
    refuse_another_kind({k: v for k, v in data.items() if k not in extras}, path, Microscope)
    try:
        microscope = from_dict(Microscope, {k: v for k, v in data.items() if k not in extras})
    except ValueError as err:
        unknown = str(err).startswith("unknown field")
        keys = f"; beside them the file may hold {', '.join(DIAGNOSE_KEYS)}" if unknown else ""
        raise ValueError(f"settings file {path}: {err}{keys}") from None
    return _with_extras(microscope, extras, str(path), [])
