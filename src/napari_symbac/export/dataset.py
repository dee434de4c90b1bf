"""Export settings and the item generator of the simulate -> draw -> render pipeline.

Seeding
-------
Every random draw of a dataset comes from ``ExportSettings.seed`` through
:class:`numpy.random.SeedSequence` spawn keys, so each item is a pure function of the
settings and its index and can be made in any order, on any worker:

========================  ==============================================================
``spawn_key=(0, i)``      unit ``i``: frame drawn, parameters drawn, then camera noise
``spawn_key=(1, s)``      simulation ``s`` (frames: ``s = i % n_simulations``; time
                          series: one simulation per series, ``s = i``)
``spawn_key=(2,)``        the train/validation split
========================  ==============================================================

``SeedSequence(seed, spawn_key=(0, i))`` is the ``i``-th child of
``SeedSequence(seed).spawn(n)[0]``'s family; see :func:`unit_rng`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np

from napari_symbac.export.formats import FORMATS, tracking_formats
from napari_symbac.export.item import ExportItem
from napari_symbac.export.visibility import (
    Visibility,
    camera_medium,
    contrast_to_noise,
    faint_cells,
)
from napari_symbac.settings import (
    PipelineSettings,
    SimulationSettings,
    from_dict,
    plain_numbers,
    to_dict,
)

__all__ = [
    "ExportSettings",
    "PipelineSource",
    "Randomisation",
    "Range",
    "export_of",
    "load_export_settings",
    "sequence_of",
    "split_of",
    "trench_filled_frame",
    "unit_rng",
]

Kind = Literal["frames", "timeseries"]


def _fail(message: str) -> None:
    raise ValueError(message)


@dataclass(frozen=True)
class Range:
    """A closed interval ``[low, high]`` that a parameter is drawn from, uniformly."""

    low: float
    high: float

    def __post_init__(self) -> None:
        plain_numbers(self)
        for name in ("low", "high"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not math.isfinite(value)
            ):
                _fail(f"Range.{name} must be a finite number, got {value!r}")
        if self.low > self.high:
            _fail(f"Range low={self.low} must not exceed high={self.high}")

    def draw(self, rng: np.random.Generator) -> float:
        """One uniform draw (always consumes one number, even when ``low == high``)."""
        u = rng.random()
        return float(self.low + (self.high - self.low) * u)


@dataclass(frozen=True)
class Randomisation:
    """How rendering parameters vary between items (SyMBac's training-data sweep).

    Scales multiply the value in :class:`~napari_symbac.settings.PipelineSettings`; a
    range with ``low == high == 1`` switches a variation off. Each item (or each time
    series, which keeps one set of parameters for all its frames) draws its own values,
    recorded in the manifest.

    Parameters
    ----------
    cell_intensity_scale, media_intensity_scale, device_intensity_scale
        Multipliers of ``render.cell_intensity``, ``media_intensity``, ``device_intensity``.
    apodisation_sigma_scale
        Multiplier of ``render.apodisation_sigma_um`` (the PSF width, eq. 11-12); the
        result never goes below the diffraction bound of eq. 13.
    defocus_sigma_um
        Range of ``render.defocus_sigma_um`` (eq. 14), absolute.
    noise_scale
        Multiplier of ``camera.dark_noise_e`` and ``render.gaussian_noise_sd_adu``.
    exposure_scale
        Multiplier of all the light together (cell, media and device intensities, eq. 3,
        on top of their own scales): the exposure time, lamp power or expression level
        of a field. The camera noise is not scaled, so the signal-to-noise of the item
        changes with it (as between the fields of one slide). Drawn log-uniformly
        (``low * (high / low) ** u``: as many images darker as brighter around the
        geometric mean), one number of the item's generator after the others, and only
        when ``low != high``: exports without it are unchanged bit for bit.
    """

    cell_intensity_scale: Range = field(default_factory=lambda: Range(0.85, 1.15))
    media_intensity_scale: Range = field(default_factory=lambda: Range(0.9, 1.1))
    device_intensity_scale: Range = field(default_factory=lambda: Range(0.85, 1.15))
    apodisation_sigma_scale: Range = field(default_factory=lambda: Range(1.0, 1.25))
    defocus_sigma_um: Range = field(default_factory=lambda: Range(0.0, 0.0))
    noise_scale: Range = field(default_factory=lambda: Range(0.8, 1.2))
    exposure_scale: Range = field(default_factory=lambda: Range(1.0, 1.0))

    def __post_init__(self) -> None:
        plain_numbers(self)
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            try:  # the field named (found as a user: "Range low=2.0 must not exceed
                # high=1.0" left the user to find which range)
                if isinstance(value, Mapping):
                    value = Range(**value)
                elif isinstance(value, (list, tuple)) and len(value) == 2:
                    value = Range(*value)
            except (TypeError, ValueError) as err:
                _fail(f"Randomisation.{f.name}: {err}")
            object.__setattr__(self, f.name, value)
            if not isinstance(value, Range):
                _fail(f"Randomisation.{f.name} must be a range {{low, high}}, got {value!r}")
            if value.low < 0:
                _fail(f"Randomisation.{f.name} must not be negative, got low={value.low}")
        if self.exposure_scale.low <= 0:
            _fail(
                "Randomisation.exposure_scale is drawn log-uniformly: low must be above 0, "
                f"got low={self.exposure_scale.low} (use e.g. {{low: 0.5, high: 2}})"
            )

    def draw(self, rng: np.random.Generator, pipeline: PipelineSettings) -> dict[str, float]:
        """Draw one item's parameters; keys are ``"render.FIELD"`` / ``"camera.FIELD"``."""
        render, camera = pipeline.render, pipeline.camera
        cell = self.cell_intensity_scale.draw(rng)
        media = self.media_intensity_scale.draw(rng)
        device = self.device_intensity_scale.draw(rng)
        sigma = self.apodisation_sigma_scale.draw(rng)
        defocus = self.defocus_sigma_um.draw(rng)
        noise = self.noise_scale.draw(rng)
        light = self.exposure_scale
        exposure = light.low
        if light.high > light.low:  # one more draw only when varied (streams unchanged)
            exposure = light.low * (light.high / light.low) ** float(rng.random())
        bound = pipeline.microscope.min_apodisation_sigma_um
        return {
            "render.cell_intensity": render.cell_intensity * cell * exposure,
            "render.media_intensity": render.media_intensity * media * exposure,
            "render.device_intensity": render.device_intensity * device * exposure,
            "render.apodisation_sigma_um": max(render.apodisation_sigma_um * sigma, bound),
            "render.defocus_sigma_um": defocus,
            "render.gaussian_noise_sd_adu": render.gaussian_noise_sd_adu * noise,
            "camera.dark_noise_e": camera.dark_noise_e * noise,
        }


def apply_params(pipeline: PipelineSettings, params: Mapping[str, Any]) -> PipelineSettings:
    """``pipeline`` with the ``"render.X"`` / ``"camera.X"`` values of ``params`` set."""
    changes: dict[str, dict[str, Any]] = {"render": {}, "camera": {}, "microscope": {}}
    for key, value in params.items():
        part, _, name = key.partition(".")
        if part in changes and name:
            changes[part][name] = value
    return dataclasses.replace(
        pipeline,
        **{
            part: dataclasses.replace(getattr(pipeline, part), **values)
            for part, values in changes.items()
            if values
        },
    )


def dark_fluorescence(pipeline: PipelineSettings) -> str | None:
    """Why a fluorescence pipeline with cells no brighter than the medium (phase-contrast
    intensities) cannot be drawn, or ``None`` (``export`` and ``render`` refuse it)."""
    render = pipeline.render
    if pipeline.microscope.modality != "fluorescence" or (
        render.cell_intensity > render.media_intensity
    ):
        return None
    return (
        "the pipeline is fluorescence but its cells are not brighter than the medium "
        f"(render.cell_intensity={render.cell_intensity:g} <= media_intensity="
        f"{render.media_intensity:g}, phase-contrast values?): a network trained on it "
        "would look for dark cells. Set cell_intensity above media_intensity (e.g. "
        "3000 and 150), or match them to a recording with `napari-symbac calibrate`"
    )


@dataclass(frozen=True)
class ExportSettings:
    """A dataset to export: how many items, which formats, how they vary.

    Parameters
    ----------
    n_items
        Number of images (``kind="frames"``) or of time series (``kind="timeseries"``).
    kind
        ``"frames"``: independent images, each a random frame of a simulation rendered
        with its own drawn parameters (segmentation training). ``"timeseries"``: every
        frame of ``n_items`` simulations, one set of drawn parameters per series, with
        lineage (tracking formats ``ctc`` and ``trackmate``).
    formats
        Format names of :data:`~napari_symbac.export.formats.FORMATS`: ``tiff``, ``png``,
        ``delta``, ``omnipose``, ``stardist``, ``coco``, ``ctc``, ``trackmate``,
        ``ome-zarr``.
    seed
        Seed of every random draw of the dataset (see the module notes).
    val_fraction
        Fraction of images (or series) put in the validation split, in ``[0, 1)``.
    n_simulations
        ``kind="frames"``: number of independent simulations images are drawn from
        (item ``i`` uses simulation ``i % n_simulations``).
    first_frame
        ``kind="frames"``: frames are drawn from ``[first_frame, n_frames)``, to skip a
        trench that is still filling.
    randomise
        Parameter variations between items.
    coco_segmentation
        ``"polygon"`` or ``"rle"`` for the COCO format.
    pipeline
        Simulation, microscope, render and camera settings.
    visibility
        What to do with cells the image barely shows (per-cell contrast-to-noise below
        a threshold): flag them in the manifest (default) or drop them from the masks;
        see :mod:`napari_symbac.export.visibility`.
    mask_dilation_um
        The masks' outline convention: every exported cell mask (instance labels and
        semantic mask) grown this far (um) into the background, after the faint cells
        are dropped; the image is unchanged. 0 (default): the model cell (eq. 4-5).
        ``napari-symbac calibrate --masks`` measures it from the user's masks
        (:mod:`napari_symbac.export.outline`).
    """

    n_items: int = 100
    kind: Kind = "frames"
    formats: list[str] = field(default_factory=lambda: ["tiff"])
    seed: int = 0
    val_fraction: float = 0.1
    n_simulations: int = 1
    first_frame: int = 0
    randomise: Randomisation = field(default_factory=Randomisation)
    coco_segmentation: Literal["polygon", "rle"] = "polygon"
    pipeline: PipelineSettings = field(default_factory=PipelineSettings)
    visibility: Visibility = field(default_factory=Visibility)
    mask_dilation_um: float = 0.0

    def __post_init__(self) -> None:
        plain_numbers(self)
        for name, cls in (
            ("pipeline", PipelineSettings),
            ("randomise", Randomisation),
            ("visibility", Visibility),
        ):
            value = getattr(self, name)
            if not isinstance(value, cls):
                raise TypeError(
                    f"ExportSettings.{name} must be a {cls.__name__}, got "
                    f"{type(value).__name__}: pass {cls.__name__}(...), or build the whole "
                    "settings from a mapping with export_settings_from_dict(...)"
                )
        if isinstance(self.n_items, bool) or not isinstance(self.n_items, int) or self.n_items < 1:
            _fail(f"ExportSettings.n_items must be an integer >= 1, got {self.n_items!r}")
        if self.kind not in ("frames", "timeseries"):
            _fail(f"ExportSettings.kind must be 'frames' or 'timeseries', got {self.kind!r}")
        formats = self.formats
        if isinstance(formats, str):
            formats = [f.strip() for f in formats.split(",") if f.strip()]
        formats = [str(f).lower() for f in formats]
        if not formats:
            _fail("ExportSettings.formats is empty: name at least one format")
        unknown = [f for f in formats if f not in FORMATS]
        if unknown:
            _fail(
                f"ExportSettings.formats has unknown format(s) {', '.join(unknown)}; known "
                f"formats: {', '.join(FORMATS)}"
            )
        if len(set(formats)) != len(formats):
            _fail(f"ExportSettings.formats lists a format twice: {formats}")
        tracking = tracking_formats(formats)
        if tracking and self.kind != "timeseries":
            _fail(
                f"format(s) {', '.join(tracking)} hold tracking ground truth: set "
                "ExportSettings.kind to 'timeseries' (`napari-symbac export --kind "
                "timeseries`)"
            )
        object.__setattr__(self, "formats", formats)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            _fail(f"ExportSettings.seed must be a non-negative integer, got {self.seed!r}")
        if not (isinstance(self.val_fraction, (int, float)) and 0 <= self.val_fraction < 1):
            _fail(f"ExportSettings.val_fraction must be in [0, 1), got {self.val_fraction!r}")
        dilation = self.mask_dilation_um
        if (
            isinstance(dilation, bool)
            or not isinstance(dilation, (int, float))
            or not 0 <= dilation < 5
        ):
            _fail(
                f"ExportSettings.mask_dilation_um must be a number in [0, 5) um, got "
                f"{dilation!r} (0: masks are the model cells)"
            )
        if not isinstance(self.n_simulations, int) or self.n_simulations < 1:
            _fail(
                f"ExportSettings.n_simulations must be an integer >= 1, got {self.n_simulations!r}"
            )
        n_frames = self.pipeline.simulation.n_frames
        if not isinstance(self.first_frame, int) or self.first_frame < 0:
            _fail(f"ExportSettings.first_frame must be an integer >= 0, got {self.first_frame!r}")
        # a time series holds every frame: first_frame is the frames kind's (found as a
        # user: a series shortened below the default's first_frame was refused for it)
        if self.kind == "frames" and self.first_frame >= n_frames:
            _fail(
                f"ExportSettings.first_frame={self.first_frame!r} must be in [0, n_frames="
                f"{n_frames}) of pipeline.simulation"
            )
        if self.kind == "timeseries" and n_frames < 2:
            _fail(  # found as a user: 1 frame wrote empty tracks and 0 DeLTA samples
                f"ExportSettings.kind='timeseries' needs pipeline.simulation.n_frames >= 2 "
                f"to track cells, got {n_frames}: simulate more frames (napari-symbac "
                "export --n-frames N), or export kind='frames'"
            )
        dark_cells = dark_fluorescence(self.pipeline)
        if dark_cells is not None:
            _fail(dark_cells)
        if self.visibility.action == "drop" and self.kind == "timeseries":
            _fail(
                "ExportSettings.visibility.action='drop' removes faint cells frame by frame, "
                "which would break their tracks: use 'flag' for kind='timeseries' (faint "
                "cells are listed in the manifest)"
            )
        if self.coco_segmentation not in ("polygon", "rle"):
            _fail(
                "ExportSettings.coco_segmentation must be 'polygon' or 'rle', got "
                f"{self.coco_segmentation!r}"
            )

    @property
    def n_images(self) -> int:
        """Number of images in the dataset."""
        if self.kind == "frames":
            return self.n_items
        return self.n_items * self.pipeline.simulation.n_frames


def load_export_settings(path: str | os.PathLike) -> ExportSettings:
    """Read :class:`ExportSettings` (with its nested pipeline settings) from YAML or JSON.

    Missing fields take their defaults; ``save_settings(export_settings, path)`` of
    :mod:`napari_symbac.settings` writes such a file. A :class:`PipelineSettings` file
    (the settings.yaml ``fit`` writes) is read as the pipeline of the default export,
    an export's ``manifest.json`` as the settings it records (found as a user: the
    advice "to resume it use its own settings (manifest.json records them)" could not
    be followed, the manifest's other fields were refused as unknown).
    """
    from napari_symbac.settings import load_settings_or_pipeline, read_settings_mapping

    data = read_settings_mapping(path)
    if isinstance(data, dict) and isinstance(data.get("settings"), dict) and "items" in data:
        try:
            return export_settings_from_dict(data["settings"])
        except (TypeError, ValueError) as err:
            raise ValueError(f"{path}: the export settings it records: {err}") from None
    loaded = load_settings_or_pipeline(path, ExportSettings)
    return loaded if isinstance(loaded, ExportSettings) else export_of(loaded)


#: Simulations the default export of a pad draws its images from (:func:`export_of`).
PAD_SIMULATIONS = 16


#: The light of a bright-field export's images, as a whole (log-uniform factors).
BRIGHTFIELD_EXPOSURE = (0.8, 1.25)
#: Range of the cells' bright-field transmission ``B = I_c / I_m`` drawn for each image
#: of a partially coherent phase export (:func:`default_randomisation`): the physical
#: part (``B <= 1``) of what the default intensity draws span.
PHASE_TRANSMISSION_SCALE = (0.77, 1.0)


def exposure_headroom(pipeline: PipelineSettings) -> float:
    """The factor on all the light that brings the media level to the camera's full scale
    (``2**bit_depth - 1`` minus the baseline, ADU): above it the background clips.
    ``inf`` for media that give no light."""
    camera = pipeline.camera
    full_adu = 2**camera.bit_depth - 1 - camera.baseline_adu
    media = pipeline.render.media_intensity
    return full_adu / media if media > 0 else math.inf


def default_randomisation(pipeline: PipelineSettings) -> Randomisation:
    """How the default export of ``pipeline`` varies its images: :class:`Randomisation`'s
    defaults at the pipeline's defocus (eq. 14, kept: a fitted defocus is the
    recording's). In bright field the light varies as a whole (exposure
    :data:`BRIGHTFIELD_EXPOSURE`) and the cells and media keep their ratio: a cell absorbs
    a few % of the light, and the default draws of each intensity by +-10-15 % alone
    would make it absorb up to 15 % more, or shine (found exporting ColiCoords' crop 01:
    cells 92 ADU darker than the media, drawn up to 1475 ADU darker or brighter). The
    brightest exposure stops at the camera's full scale (:func:`exposure_headroom`, at
    least 1: the recording's own light): found calibrating ColiCoords' ds1 bright field,
    whose background lies 45 ADU below 65535, where 1.25x turned every image white.

    With the partially coherent phase model (dense phase colonies) the cells' intensity
    over the media's is their bright-field transmission ``B`` (eq. 3), at most 1
    (nothing passes more light than the clear media). The default independent draws of
    the two (0.85-1.15 and 0.9-1.1) span ``B`` from 0.77 to 1.28; there only the cells'
    intensity is drawn, from :data:`PHASE_TRANSMISSION_SCALE` (``B`` 0.77-1: cells that
    lose up to as much light to absorption and to scattering out of the pupil as the
    default's darkest draw), and the media level is kept (a per-image normalisation
    removes it). Without any such draw the transfer benchmark's F1 fell
    (docs/rendering.md). (Found as a user: ``calibrate`` drew so, while a colony fit's
    settings.yaml, exported, drew the default's ``B`` up to 1.28.)"""
    defocus = Range(pipeline.render.defocus_sigma_um, pipeline.render.defocus_sigma_um)
    fixed = Range(1.0, 1.0)
    if (
        pipeline.microscope.modality == "phase"
        and pipeline.render.phase_model == "partially_coherent"
    ):
        return Randomisation(
            cell_intensity_scale=Range(*PHASE_TRANSMISSION_SCALE),
            media_intensity_scale=fixed,
            device_intensity_scale=fixed,
            defocus_sigma_um=defocus,
        )
    if pipeline.microscope.modality != "brightfield":
        return Randomisation(defocus_sigma_um=defocus)
    low, high = BRIGHTFIELD_EXPOSURE
    high = min(high, max(exposure_headroom(pipeline), 1.0))
    return Randomisation(
        cell_intensity_scale=fixed,
        media_intensity_scale=fixed,
        device_intensity_scale=fixed,
        defocus_sigma_um=defocus,
        exposure_scale=Range(min(low, high), high),
    )


def export_of(pipeline: PipelineSettings, **fields: Any) -> ExportSettings:
    """The default export of ``pipeline`` (``fields`` set the others).

    An agar pad or an outline is simulated ``min(n_items, PAD_SIMULATIONS)`` times, each
    with its own layout, and the images drawn from them in turn: a pad keeps its founders'
    places for the whole run, and the pad a fit lays out as a field of lone cells has one
    frame, so every image of one simulation showed the same cells (found exporting a
    ColiCoords fit: 3 items, 8 cells in the same places). A trench or chamber keeps one
    simulation, whose frames differ as it fills and divides, and its images are drawn
    from the frames after it has filled (:func:`trench_filled_frame`; found exporting a
    fit of the SyMBac trench, full of cells: a quarter of the images showed one or two
    cells in an empty trench). A pad's images are drawn from its colonies' last doubling
    (:func:`colony_grown_frame`; found exporting after Auto-fit of a 182-cell colony:
    images of 1, 21, 229 and 81 cells). Its images keep the pipeline's defocus (eq. 14;
    the default randomisation's absolute 0 threw away the defocus a fit measured: found
    exporting a bright-field fit of ColiCoords' crop, whose cells then lost their
    blurred, bright centres).
    """
    if "randomise" not in fields:
        fields = {"randomise": default_randomisation(pipeline), **fields}
    simulation = pipeline.simulation
    walled = simulation.geometry in ("trench", "chamber")
    fields = {"first_frame": default_first_frame(simulation), **fields}
    settings = ExportSettings(pipeline=pipeline, **fields)
    if "n_simulations" in fields or walled:
        return settings
    return dataclasses.replace(settings, n_simulations=min(settings.n_items, PAD_SIMULATIONS))


def default_first_frame(simulation: SimulationSettings) -> int:
    """The first frame the default export of ``simulation`` draws images from: the
    trench filled (:func:`trench_filled_frame`), the pad's colonies in their last
    doubling (:func:`colony_grown_frame`), else 0."""
    if simulation.geometry in ("trench", "chamber"):
        return trench_filled_frame(simulation)
    if simulation.geometry == "agar_pad":
        return colony_grown_frame(simulation)
    return 0


def trench_filled_frame(simulation: SimulationSettings, *, uncapped: bool = False) -> int:
    """The frame by which the founders' descendants fill the trench, at most half the run
    (``uncapped``: however long the run).

    A full trench holds ``length / mean length`` cells; the mean length of an
    asynchronous population dividing at ``L`` is ``L ln 2`` (the adder's ``L`` is twice
    the added length); the founders fill it in ``log2(capacity / founders)`` doublings
    of ``ln 2 / growth rate`` (the timer's interdivision time). On the defaults (a 16 um
    trench, cells dividing at 3.5 um) that is frame 23 of 60, where the simulation holds
    6 of the 6-7 cells it keeps from then on.
    """
    division_um = simulation.cell_max_length_um
    if simulation.growth_model == "adder":
        division_um = 2 * simulation.added_length_um
    doubling_min = math.log(2) / simulation.growth_rate_per_min
    if simulation.growth_model == "timer":
        doubling_min = simulation.interdivision_time_min
    capacity = simulation.trench.length_um / (division_um * math.log(2))
    doublings = math.log2(max(1.0, capacity / simulation.n_founders))
    frame = math.ceil(doublings * doubling_min / simulation.frame_interval_min)
    return frame if uncapped else min(frame, simulation.n_frames // 2)


def short_run_note(simulation: SimulationSettings, first_frame: int) -> str | None:
    """What to say when the frames an export draws from, ``[first_frame, n_frames)``,
    start before the trench is full because the run is too short to fill it (found as
    a user: ``--n-frames 10`` drew frames 5-9 of a 16 um trench, 2 cells each, unsaid);
    ``None`` when they start full or the geometry has no trench."""
    if simulation.geometry not in ("trench", "chamber"):
        return None
    filled = trench_filled_frame(simulation, uncapped=True)
    if first_frame >= filled:
        return None
    return (
        f"a run of {simulation.n_frames} frames does not fill the "
        f"{simulation.trench.length_um:g} um trench (its cells fill it by about frame "
        f"{filled}): images are drawn from frames {first_frame}-{simulation.n_frames - 1}, "
        f"with fewer cells than a full trench; --n-frames {2 * filled} or more draws "
        "them from full trenches"
    )


def colony_grown_frame(simulation: SimulationSettings) -> int:
    """The first frame of an agar pad's last doubling, where each colony holds at least
    about half the cells it ends with (``calibrate`` and a fit lay a pad out so that its
    colonies end the run at the recording's size).

    The doubling time is ``ln 2 / growth rate`` (the timer's interdivision time); a run
    shorter than one doubling gives frame 0.
    """
    doubling_min = math.log(2) / simulation.growth_rate_per_min
    if simulation.growth_model == "timer":
        doubling_min = simulation.interdivision_time_min
    frames = math.ceil(doubling_min / simulation.frame_interval_min)
    return max(0, simulation.n_frames - 1 - frames)


def export_settings_from_dict(data: Mapping[str, Any]) -> ExportSettings:
    """Build :class:`ExportSettings` from a plain mapping (e.g. a manifest's ``settings``)."""
    return from_dict(ExportSettings, dict(data))


def unit_rng(seed: int, unit: int) -> np.random.Generator:
    """The generator of unit ``unit`` (an image, or a time series) of a dataset."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0, unit)))


def _simulation_seed_sequence(seed: int, simulation: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed, spawn_key=(1, simulation))


@lru_cache(maxsize=8)
def _val_units(seed: int, n_units: int, val_fraction: float) -> frozenset[int]:
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2,)))
    n_val = round(val_fraction * n_units)
    return frozenset(int(u) for u in rng.permutation(n_units)[:n_val])


def no_validation_note(settings: ExportSettings) -> str | None:
    """Said when ``val_fraction`` asks for validation items and the count rounds to none
    (found as a user: 2 items at 0.1 wrote no ``val/`` folders and no
    ``instances_val.json``, without a word, and the docs' COCO loader failed on it)."""
    if settings.val_fraction <= 0 or round(settings.val_fraction * settings.n_items) > 0:
        return None
    coco = ", no instances_val.json" if "coco" in settings.formats else ""
    return (
        f"no validation items: val_fraction {settings.val_fraction:g} of "
        f"{settings.n_items} item(s) rounds to 0, so every item is in train (no val "
        f"folders{coco}); export more items or a larger val_fraction"
    )


def split_of(settings: ExportSettings, unit: int) -> str:
    """``"val"`` for the ``round(val_fraction * n_items)`` units drawn for validation."""
    val = _val_units(settings.seed, settings.n_items, float(settings.val_fraction))
    return "val" if unit in val else "train"


@lru_cache(maxsize=8)
def _sorted_val_units(seed: int, n_units: int, val_fraction: float) -> tuple[int, ...]:
    return tuple(sorted(_val_units(seed, n_units, val_fraction)))


def sequence_of(settings: ExportSettings, unit: int) -> int:
    """The number of unit ``unit`` among the units of its split (0, 1, ... per split)."""
    import bisect

    val = _sorted_val_units(settings.seed, settings.n_items, float(settings.val_fraction))
    before = bisect.bisect_left(val, unit)  # validation units before this one
    return before if split_of(settings, unit) == "val" else unit - before


_SIMULATIONS: dict[str, Any] = {}


def _simulation_key(pipeline: PipelineSettings, seed: int, index: int) -> str:
    import json

    return json.dumps([to_dict(pipeline.simulation), seed, index], sort_keys=True)


def _simulation(pipeline: PipelineSettings, seed: int, index: int):
    """Simulation ``index`` of a dataset, cached per process (workers simulate once)."""
    from napari_symbac.sim import simulate

    key = _simulation_key(pipeline, seed, index)
    if key not in _SIMULATIONS:
        seq = _simulation_seed_sequence(seed, index)
        sim_settings = dataclasses.replace(
            pipeline.simulation, seed=int(seq.generate_state(1)[0]), save_dir=None
        )
        if len(_SIMULATIONS) >= 4:
            _SIMULATIONS.pop(next(iter(_SIMULATIONS)))
        _SIMULATIONS[key] = simulate(sim_settings, np.random.default_rng(seq))
    return _SIMULATIONS[key]


def _curvature(simulation) -> dict[int, tuple[float, float, float]] | None:
    curvature = {
        int(cell_id): tuple(record.curvature)
        for cell_id, record in simulation.lineage.items()
        if any(record.curvature)
    }
    return curvature or None


class PipelineSource:
    """Items of an :class:`ExportSettings` dataset, made by simulate -> draw -> render.

    A unit is one image (``kind="frames"``) or one time series (``kind="timeseries"``).
    ``backend`` renders the frames (a name of
    :func:`~napari_symbac.optics.batched.resolve_backend`, resolved to its device):
    ``"scipy"`` (default), ``"torch:cpu"`` / ``"torch:cuda"`` (the frames of a time
    series in device batches; its own noise stream, so the manifest records it) or
    ``"cupy"``.
    """

    def __init__(self, settings: ExportSettings, backend: str = "scipy") -> None:
        from napari_symbac.diagnose.stages import drawn_stages
        from napari_symbac.optics import ForwardModel
        from napari_symbac.optics.batched import check_device_stages, resolve_backend

        self.settings = settings
        self.backend = resolve_backend(backend)
        if self.backend.startswith("torch"):  # before the manifest records the backend
            p = settings.pipeline
            model = ForwardModel(p.microscope, p.render, p.camera, extra_stages=drawn_stages(p))
            check_device_stages(model)

    def __getstate__(self) -> dict[str, Any]:
        """The settings, and the simulations of this dataset this process has made.

        A dask worker that receives the source then renders at once instead of running
        the same simulation again (each is a pure function of the settings and its
        index, so the items are the same bytes either way).
        """
        s = self.settings
        n = s.n_simulations if s.kind == "frames" else s.n_items
        keys = (_simulation_key(s.pipeline, s.seed, i) for i in range(n))
        made = {key: _SIMULATIONS[key] for key in keys if key in _SIMULATIONS}
        return {"settings": s, "backend": self.backend, "simulations": made}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.settings = state["settings"]
        self.backend = state["backend"]
        for key, simulation in state["simulations"].items():
            if key not in _SIMULATIONS and len(_SIMULATIONS) < 4:
                _SIMULATIONS[key] = simulation

    @property
    def n_units(self) -> int:
        return self.settings.n_items

    def _name_width(self) -> int:
        return max(6, len(str(self.settings.n_items - 1)))

    def unit_names(self, unit: int) -> list[str]:
        if self.settings.kind == "frames":
            return [f"{unit:0{self._name_width()}d}"]
        n_frames = self.settings.pipeline.simulation.n_frames
        width = max(4, len(str(n_frames - 1)))
        return [f"s{unit:04d}_t{t:0{width}d}" for t in range(n_frames)]

    def header(self) -> dict[str, Any]:
        backend = {} if self.backend == "scipy" else {"render_backend": self.backend}
        return {
            **backend,
            "kind": self.settings.kind,
            "seed": self.settings.seed,
            "n_items": self.settings.n_images,
            "settings": to_dict(self.settings),
            "seeding": (
                "unit i: numpy.random.default_rng(SeedSequence(seed, spawn_key=(0, i))); "
                "simulation s: SeedSequence(seed, spawn_key=(1, s)); split: "
                "SeedSequence(seed, spawn_key=(2,))"
            ),
        }

    def make_unit(self, unit: int) -> list[ExportItem]:
        from napari_symbac.diagnose.stages import drawn_stages
        from napari_symbac.export.outline import grow_masks
        from napari_symbac.optics import ForwardModel
        from napari_symbac.optics.batched import render_scenes
        from napari_symbac.pipeline import apply_cell_brightness, stain_cells
        from napari_symbac.scene import (
            add_debris,
            add_media_texture,
            draw_scene,
            field_of,
            semantic_from_labels,
        )

        s = self.settings
        pipeline = s.pipeline
        rng = unit_rng(s.seed, unit)
        split = split_of(s, unit)
        sim_index = unit % s.n_simulations if s.kind == "frames" else unit
        simulation = _simulation(pipeline, s.seed, sim_index)
        n_frames = len(simulation.frames)
        if s.kind == "frames":
            frames = [int(rng.integers(s.first_frame, n_frames))]
        else:
            frames = list(range(n_frames))
        params = s.randomise.draw(rng, pipeline)
        varied = apply_params(pipeline, params)
        model = ForwardModel(
            varied.microscope,
            varied.render,
            varied.camera,
            extra_stages=drawn_stages(varied),
        )
        curvature = _curvature(simulation)
        parents = {int(c): int(r.parent_id) for c, r in simulation.lineage.items()}
        max_label = max(parents, default=0)
        names = self.unit_names(unit)
        items = []
        # one draw of the unit's generator, only with debris (default streams unchanged);
        # the same particles on every frame of a series
        debris_seed = (
            int(rng.integers(2**63)) if varied.render.debris_density_per_100um2 > 0 else 0
        )

        def scenes():
            for frame in frames:
                scene = add_media_texture(
                    draw_scene(
                        simulation.frames[frame],
                        pipeline.simulation.trench,
                        varied.microscope,
                        varied.render,
                        curvature=curvature,
                        field=field_of(simulation),
                    ),
                    varied.render.texture_amplitude,
                    simulation.settings.seed,
                    varied.render.texture_scale_um,
                )
                scene = stain_cells(scene, varied.microscope, varied.render)
                scene = apply_cell_brightness(
                    scene,
                    varied.render.cell_brightness_cv,
                    simulation.settings.seed,
                    varied.render.cell_brightness_max_gain,
                )
                yield add_debris(scene, varied.render, np.random.default_rng(debris_seed))

        rendered = render_scenes(model, scenes(), rng, backend=self.backend)
        for k, (frame, (scene, image)) in enumerate(zip(frames, rendered)):
            labels, semantic = scene.camera_labels(), scene.semantic_mask()
            cnr, faint = self._visibility(image, labels, scene)
            if faint and s.visibility.action == "drop":
                semantic[np.isin(labels, faint)] = 0
                labels[np.isin(labels, faint)] = 0
            if s.mask_dilation_um > 0:  # the user's outline convention
                labels = grow_masks(
                    labels, s.mask_dilation_um / varied.microscope.pixel_size_um
                )
                semantic = semantic_from_labels(labels)
            present = np.unique(labels)
            item_params = {"simulation": sim_index, "frame": frame, **params}
            items.append(
                ExportItem(
                    name=names[k],
                    index=unit if s.kind == "frames" else unit * n_frames + frame,
                    image=image,
                    labels=labels,
                    semantic=semantic,
                    split=split,  # type: ignore[arg-type]
                    series=None if s.kind == "frames" else unit,
                    sequence=None if s.kind == "frames" else sequence_of(s, unit),
                    frame=None if s.kind == "frames" else frame,
                    n_frames=None if s.kind == "frames" else n_frames,
                    parents={int(c): parents.get(int(c), 0) for c in present if c},
                    max_label=max(max_label, int(labels.max()) if labels.size else 0),
                    pixel_size_um=pipeline.microscope.pixel_size_um,
                    frame_interval_min=pipeline.simulation.frame_interval_min,
                    params=item_params,
                    contrast_to_noise=cnr,
                    faint_cells=tuple(faint),
                )
            )
        return items

    def _visibility(self, image, labels, scene) -> tuple[dict[int, float], list[int]]:
        """Per-cell contrast-to-noise and the faint cells (none when not measured)."""
        rule = self.settings.visibility
        if rule.action == "keep":
            return {}, []
        cnr = contrast_to_noise(image, labels, rule.ring_px, medium=camera_medium(scene))
        return cnr, faint_cells(cnr, rule.min_contrast_to_noise)


def regenerate(manifest_dir: str | os.PathLike, name: str) -> ExportItem:
    """Make item ``name`` of an exported dataset again, from its ``manifest.json``.

    With the same package version the result is bit for bit the exported item.

    Parameters
    ----------
    manifest_dir
        The dataset's folder (the one holding ``manifest.json``).
    name
        The item's name, as its files are named (e.g. ``"000004"``; text).

    Raises
    ------
    KeyError
        If the dataset has no item of that name.
    """
    import json

    path = Path(manifest_dir) / "manifest.json"
    document = json.loads(path.read_text("utf-8"))
    settings = export_settings_from_dict(document["settings"])
    source = PipelineSource(settings, document.get("render_backend", "scipy"))
    names = [source.unit_names(unit) for unit in range(source.n_units)]
    for unit, unit_names in enumerate(names):
        if name in unit_names:
            return next(item for item in source.make_unit(unit) if item.name == name)
    every = [n for unit_names in names for n in unit_names]
    raise KeyError(  # found as an API user: 42 for "000042", with no hint
        f"{path} has no item named {name!r}: its {len(every)} items are named "
        f"{every[0]!r} to {every[-1]!r} (text, as their files are named)"
    )
