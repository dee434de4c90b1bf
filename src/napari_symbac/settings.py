"""Frozen, validated settings with units in their names.

Every object here is a frozen dataclass whose ``__post_init__`` rejects impossible
values with a :class:`ValueError` that names the field and says how to fix it.
All of them round-trip through plain dicts, YAML and JSON (:func:`to_dict`,
:func:`from_dict`, :func:`save_settings`, :func:`load_settings`), so a dataset
records exactly how it was made.

Conventions
-----------
* Lengths are in micrometres (``_um``), times in minutes (``_min``), camera values
  in ADU or electrons (``_adu``, ``_e``), render-resolution pixels in ``_px``.
* The trench is vertical: the closed end is at the top of the image (row 0), the
  open end, where cells leave, at the bottom.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import re
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np
import yaml

__all__ = [
    "CONDENSERS",
    "AgarPadGeometry",
    "Camera",
    "Condenser",
    "ExtraStage",
    "Microscope",
    "OutlineGeometry",
    "PipelineSettings",
    "RenderSettings",
    "SimulationSettings",
    "TrenchGeometry",
    "from_dict",
    "load_microscope",
    "load_settings",
    "load_settings_or_pipeline",
    "load_simulation_settings",
    "microscope_sets_pixel_size",
    "plain_numbers",
    "read_settings_mapping",
    "refuse_another_kind",
    "save_settings",
    "to_dict",
]

GrowthModel = Literal["sizer", "adder", "timer"]
GeometryKind = Literal["trench", "chamber", "agar_pad", "outline"]
Modality = Literal["phase", "fluorescence", "brightfield"]
NoiseModel = Literal["camera", "gaussian", "none"]
ClosedEnd = Literal["square", "round"]


def plain_numbers(settings: object) -> None:
    """Replace a frozen settings dataclass's numpy scalar fields (``np.int64``,
    ``np.float32``, ``np.bool_``) with Python's own numbers, so they are checked, compared
    and written to YAML as such. Found as a user: ``SimulationSettings(seed=
    rng.integers(1000))`` was refused as "must be a non-negative integer, got
    np.int64(850)"."""
    for item in dataclasses.fields(settings):
        value = getattr(settings, item.name)
        if isinstance(value, np.floating):  # float32's 0.065 is 0.065, not 0.06499999...
            object.__setattr__(settings, item.name, float(str(value)))
        elif isinstance(value, np.generic):
            object.__setattr__(settings, item.name, value.item())


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _positive(obj: object, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _require(
            isinstance(value, (int, float)) and math.isfinite(value) and value > 0,
            f"{type(obj).__name__}.{name} must be a positive finite number, got {value!r}",
        )


def _finite(obj: object, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _require(
            isinstance(value, (int, float)) and math.isfinite(value),
            f"{type(obj).__name__}.{name} must be a finite number, got {value!r}",
        )


def _non_negative(obj: object, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _require(
            isinstance(value, (int, float)) and math.isfinite(value) and value >= 0,
            f"{type(obj).__name__}.{name} must be zero or positive, got {value!r}",
        )


def _nested(obj: object, **classes: type) -> None:
    """Require each named field of ``obj`` to be an instance of its settings class.

    Raises
    ------
    TypeError
        Naming the field, the class it needs and how to build it from a mapping.
    """
    for name, cls in classes.items():
        value = getattr(obj, name)
        if not isinstance(value, cls):
            raise TypeError(
                f"{type(obj).__name__}.{name} must be a {cls.__name__}, got "
                f"{type(value).__name__} {value!r}: pass {cls.__name__}(...), or build "
                f"the whole settings from a mapping with from_dict({type(obj).__name__}, ...)"
            )


def _choice(obj: object, name: str, allowed: typing.Iterable[str]) -> None:
    value = getattr(obj, name)
    allowed = tuple(allowed)
    _require(
        value in allowed,
        f"{type(obj).__name__}.{name} must be one of {', '.join(map(repr, allowed))}, "
        f"got {value!r}",
    )


@dataclass(frozen=True)
class Condenser:
    """Phase-ring / condenser-annulus dimensions (supplement Fig. S4.1).

    Parameters
    ----------
    ring_width_mm
        Width ``W`` of the annulus.
    ring_radius_mm
        Outer radius ``R`` of the annulus.
    pupil_diameter_mm
        Diameter of the back focal plane that the annulus sits in; the annulus
        radii are expressed as fractions of the pupil radius in the PSF model.
    """

    ring_width_mm: float
    ring_radius_mm: float
    pupil_diameter_mm: float

    def __post_init__(self) -> None:
        plain_numbers(self)
        _positive(self, "ring_width_mm", "ring_radius_mm", "pupil_diameter_mm")
        _require(
            self.ring_width_mm < self.ring_radius_mm,
            f"Condenser ring width W={self.ring_width_mm} mm must be smaller than its "
            f"radius R={self.ring_radius_mm} mm",
        )
        _require(
            self.ring_radius_mm <= self.pupil_diameter_mm / 2,
            f"Condenser ring radius R={self.ring_radius_mm} mm must fit in the pupil "
            f"(radius {self.pupil_diameter_mm / 2} mm)",
        )

    @property
    def outer_fraction(self) -> float:
        """Outer annulus radius as a fraction of the pupil radius."""
        return self.ring_radius_mm / (self.pupil_diameter_mm / 2)

    @property
    def inner_fraction(self) -> float:
        """Inner annulus radius as a fraction of the pupil radius."""
        return (self.ring_radius_mm - self.ring_width_mm) / (self.pupil_diameter_mm / 2)


#: Most slabs of the depth-resolved fluorescence image (``RenderSettings.depth_layers``):
#: each is a convolution per frame; 5 slabs of a 1.2 um depth fit ColiCoords ds2 as
#: well as 15 (docs/fitting.md).
MAX_DEPTH_LAYERS = 32

#: Nominal annulus dimensions (W, R, pupil diameter, mm) of the standard condensers,
#: as used by SyMBac 0.5 (Fig. S4.2 of the supplement uses Ph2: W = 0.8, R = 5).
CONDENSERS: dict[str, Condenser] = {
    "Ph1": Condenser(0.45, 3.75, 24.0),
    "Ph2": Condenser(0.8, 5.0, 24.0),
    "Ph3": Condenser(1.0, 9.5, 24.0),
    "Ph4": Condenser(1.5, 14.0, 30.0),
    "PhF": Condenser(1.5, 19.0, 40.0),
}


@dataclass(frozen=True)
class TrenchGeometry:
    """A mother-machine trench and the device around it in the field of view.

    Parameters
    ----------
    length_um
        Trench length from the closed end to the open end (``trench_length``).
    width_um
        Trench width (``trench_width``).
    depth_um
        Depth of media in the trench (``s_media`` of eq. OPL2-3); cells thinner than
        this leave media above and below them.
    margin_um
        Device (PDMS) shown around the trench on the left, right and closed end.
    top_margin_um
        Device shown above the closed end when it differs from the sides' (a fit keeps
        the recording's: ``napari-symbac fit`` writes it); ``None``: ``margin_um``.
    closed_end
        Shape of the closed end in the rendered image: ``"square"`` (corners of media)
        or ``"round"`` (a semicircle of diameter ``width_um``, PDMS in the corners, as
        moulded trenches are; docs/fitting.md). The simulator keeps a square end.
    """

    length_um: float = 16.0
    width_um: float = 1.4
    depth_um: float = 1.2
    margin_um: float = 0.8
    top_margin_um: float | None = None
    closed_end: ClosedEnd = "square"

    def __post_init__(self) -> None:
        plain_numbers(self)
        _positive(self, "length_um", "width_um", "depth_um")
        _non_negative(self, "margin_um")
        if self.top_margin_um is not None:
            _non_negative(self, "top_margin_um")
        _choice(self, "closed_end", typing.get_args(ClosedEnd))

    @property
    def shown_top_um(self) -> float:
        """Device shown above the closed end: ``top_margin_um``, else ``margin_um``."""
        return self.margin_um if self.top_margin_um is None else self.top_margin_um


@dataclass(frozen=True)
class AgarPadGeometry:
    """An open agar-pad field in which a monolayer colony grows (supplement 13.2).

    Coordinates of cells are measured from the top-left corner of the field (x to the
    right, y down the image rows). With one colony and no scattered cells (the
    default) the founders start in a small grid at the centre; otherwise the
    ``SimulationSettings.n_founders`` founders are shared out over ``n_colonies``
    colonies whose centres are drawn at random over the field (the run's seed), and
    ``scattered_cells`` more founders are dropped alone at random places, as on a
    real pad. There are no walls: cells whose centre leaves the field are removed
    (fate ``"exited"``), which also bounds the cost of a long run.

    Colony size is set by the founders per colony and the number of frames; density
    by ``founder_spacing_um`` (founders further apart leave gaps the colony fills
    later) and by ``SimulationSettings.gravity`` (towards the field centre).

    Parameters
    ----------
    field_width_um, field_height_um
        Size of the simulated field of view.
    n_colonies
        Colonies the founders are shared between (at least 1, at most
        ``n_founders``).
    scattered_cells
        Extra founders placed alone, each at least ``colony_separation_um`` from
        every colony centre and half of it from each other.
    founder_spacing_um
        Distance between the founders of one colony; 0 means the mean division
        length (``cell_max_length_um``).
    colony_separation_um
        Smallest distance between two colony centres.
    edge_margin_um
        Colony centres and scattered cells stay this far inside the field.
    """

    field_width_um: float = 40.0
    field_height_um: float = 40.0
    n_colonies: int = 1
    scattered_cells: int = 0
    founder_spacing_um: float = 0.0
    colony_separation_um: float = 10.0
    edge_margin_um: float = 3.0

    def __post_init__(self) -> None:
        plain_numbers(self)
        _positive(self, "field_width_um", "field_height_um")
        _non_negative(self, "founder_spacing_um", "colony_separation_um", "edge_margin_um")
        _require(
            isinstance(self.n_colonies, int) and self.n_colonies >= 1,
            f"AgarPadGeometry.n_colonies must be an integer >= 1, got {self.n_colonies!r}",
        )
        _require(
            isinstance(self.scattered_cells, int) and self.scattered_cells >= 0,
            "AgarPadGeometry.scattered_cells must be an integer >= 0, got "
            f"{self.scattered_cells!r}",
        )
        _require(
            2 * self.edge_margin_um < min(self.field_width_um, self.field_height_um),
            f"AgarPadGeometry.edge_margin_um={self.edge_margin_um} leaves no room in a "
            f"{self.field_width_um} x {self.field_height_um} um field: lower it",
        )


@dataclass(frozen=True)
class OutlineGeometry:
    """A user's own device drawn as wall polylines, or read from a DXF drawing.

    Coordinates are in micrometres with x to the right and y down the image rows
    (a DXF drawing, whose y axis points up, is flipped and shifted so that the top-left
    corner of its bounding box is the origin). Cells whose centre leaves the bounding
    box of the walls (grown by ``exit_margin_um``) are removed; leave gaps in the walls
    where the device opens to the flow.

    Parameters
    ----------
    polylines_um
        Wall polylines, each a sequence of ``(x, y)`` vertices; close a polygon by
        repeating its first vertex. Ignored when ``dxf_path`` is given.
    dxf_path
        A DXF drawing whose LINE, LWPOLYLINE, POLYLINE, ARC and CIRCLE entities are the
        walls (needs the ``[dxf]`` extra, i.e. ``ezdxf``).
    dxf_layer
        Only read entities on this layer (``None``: all layers).
    dxf_unit_um
        Micrometres per drawing unit (1 for a drawing in um, 1000 for mm).
    founders_um
        Where the founder cells start, ``(x, y)`` each; empty puts ``n_founders`` cells
        at the centre of the bounding box.
    exit_margin_um
        How far past the walls' bounding box a cell may go before it is removed.
    """

    polylines_um: tuple[tuple[tuple[float, float], ...], ...] = ()
    dxf_path: str | None = None
    dxf_layer: str | None = None
    dxf_unit_um: float = 1.0
    founders_um: tuple[tuple[float, float], ...] = ()
    exit_margin_um: float = 2.0

    def __post_init__(self) -> None:
        plain_numbers(self)
        _positive(self, "dxf_unit_um")
        _non_negative(self, "exit_margin_um")
        lines = []
        for index, line in enumerate(self.polylines_um):
            try:
                points = tuple((float(x), float(y)) for x, y in line)
            except (TypeError, ValueError) as err:
                raise ValueError(
                    f"OutlineGeometry.polylines_um[{index}] must be a list of (x, y) pairs in "
                    f"um, got {line!r}"
                ) from err
            _require(
                len(points) >= 2 and all(math.isfinite(v) for p in points for v in p),
                f"OutlineGeometry.polylines_um[{index}] needs at least two finite (x, y) "
                f"vertices, got {line!r}",
            )
            lines.append(points)
        object.__setattr__(self, "polylines_um", tuple(lines))
        try:
            founders = tuple((float(x), float(y)) for x, y in self.founders_um)
        except (TypeError, ValueError) as err:
            raise ValueError(
                f"OutlineGeometry.founders_um must be a list of (x, y) pairs in um, got "
                f"{self.founders_um!r}"
            ) from err
        object.__setattr__(self, "founders_um", founders)


@dataclass(frozen=True)
class SimulationSettings:
    """Agent-based growth in a mother-machine trench (supplement section 2, Algorithm 1)
    or a 2D geometry (section 13).

    The names follow the supplement's parameter list; each carries its unit.
    ``docs/simulation.md`` explains every parameter and how to tune stacking.

    Parameters
    ----------
    n_frames
        Number of frames to simulate (``sim_length``).
    trench
        Geometry of the trench (``trench_length``, ``trench_width``); also the
        chamber's size when ``geometry="chamber"``.
    geometry
        ``"trench"`` (mother machine, founders stacked along it), ``"chamber"`` (a wide
        trench open to the flow channel at its bottom, founders spread across it,
        section 13.1), ``"agar_pad"`` (open monolayer colony, section 13.2) or
        ``"outline"`` (walls from :attr:`outline`).
    agar_pad
        Field of view of the ``"agar_pad"`` geometry.
    outline
        Walls of the ``"outline"`` geometry (polylines or a DXF drawing).
    n_founders
        Number of cells the run starts with.
    frame_interval_min
        Time between frames.
    cell_max_length_um
        Mean length at division for the sizer model (``cell_max_length``).
    max_length_var_um2
        Variance of the division length between cells (``max_length_var``).
    cell_width_um
        Mean cell width (``cell_width``).
    width_var_um2
        Variance of the cell width between cells (``width_var``).
    growth_model
        ``"sizer"`` (divide at a drawn length), ``"adder"`` (divide after adding a
        drawn length) or ``"timer"`` (divide after a drawn time).
    added_length_um
        Mean length added between birth and division (adder model).
    interdivision_time_min
        Mean time between divisions (timer model).
    growth_rate_per_min
        Exponential elongation rate constant ``k`` in ``L(t) = L0 exp(k t)``.
    growth_noise
        Per-step multiplicative noise: the rate is scaled by ``U(1 - a, 1 + a)``
        (the supplement uses ``U(0.7, 1.3)``, i.e. ``a = 0.3``).
    interdivision_time_var_min2
        Variance of the interdivision time between cells (timer model).
    septum_sd
        Standard deviation of the septum position as a fraction of cell length.
    angle_jitter_rad
        Daughters' angles differ from their mother's by ``U(-a, a)`` (Algorithm 1).
    jitter_um
        Standard deviation of the random displacement of every cell in each physics
        iteration ("jitter cells", Algorithm 1); the cell's angle jitters by the same
        amount divided by its half-length.
    gravity
        Drift speed of a free cell towards the closed end (positive) or the open end
        (negative), in um/min; zero gives stacking driven by growth alone. In the
        ``"agar_pad"`` geometry it pulls towards the field centre, in ``"outline"``
        towards the top of the image.
    phys_iters
        Physics iterations per frame (``phys_iters``); more resolves overlaps more
        completely (tighter, cleaner stacking).
    lysis_p
        Probability that a cell lyses in each frame (``lysis_p``).
    do_transformation
        Give cells a random curvature (eq. 1) when scenes are drawn.
    seed
        Seed of the random generator that drives every draw of a run.
    save_dir
        Where the CLI saves the simulation (``save_dir``); ``None`` keeps it in memory.
    """

    n_frames: int = 60
    trench: TrenchGeometry = field(default_factory=TrenchGeometry)
    geometry: GeometryKind = "trench"
    agar_pad: AgarPadGeometry = field(default_factory=AgarPadGeometry)
    outline: OutlineGeometry = field(default_factory=OutlineGeometry)
    n_founders: int = 1
    frame_interval_min: float = 3.0
    cell_max_length_um: float = 3.5
    max_length_var_um2: float = 0.04
    cell_width_um: float = 1.0
    width_var_um2: float = 0.0025
    growth_model: GrowthModel = "sizer"
    added_length_um: float = 1.75
    interdivision_time_min: float = 25.0
    growth_rate_per_min: float = math.log(2) / 25.0
    growth_noise: float = 0.3
    interdivision_time_var_min2: float = 4.0
    septum_sd: float = 0.05
    angle_jitter_rad: float = 0.01
    jitter_um: float = 0.002
    gravity: float = 0.0
    phys_iters: int = 15
    lysis_p: float = 0.0
    do_transformation: bool = False
    seed: int = 0
    save_dir: str | None = None

    def __post_init__(self) -> None:
        plain_numbers(self)
        _nested(
            self, trench=TrenchGeometry, agar_pad=AgarPadGeometry, outline=OutlineGeometry
        )
        _require(
            isinstance(self.n_frames, int) and self.n_frames >= 1,
            f"SimulationSettings.n_frames must be an integer >= 1, got {self.n_frames!r}",
        )
        _require(
            isinstance(self.phys_iters, int) and self.phys_iters >= 1,
            f"SimulationSettings.phys_iters must be an integer >= 1, got {self.phys_iters!r}",
        )
        _positive(
            self,
            "frame_interval_min",
            "cell_max_length_um",
            "cell_width_um",
            "added_length_um",
            "interdivision_time_min",
            "growth_rate_per_min",
        )
        _non_negative(
            self,
            "max_length_var_um2",
            "width_var_um2",
            "septum_sd",
            "growth_noise",
            "interdivision_time_var_min2",
            "angle_jitter_rad",
            "jitter_um",
        )
        _choice(self, "growth_model", typing.get_args(GrowthModel))
        _choice(self, "geometry", typing.get_args(GeometryKind))
        _require(
            isinstance(self.n_founders, int) and self.n_founders >= 1,
            f"SimulationSettings.n_founders must be an integer >= 1, got {self.n_founders!r}",
        )
        _require(
            self.septum_sd < 0.25,
            f"SimulationSettings.septum_sd={self.septum_sd} is a fraction of the cell length "
            f"and must be below 0.25 (daughters must keep a positive length)",
        )
        _require(
            self.geometry != "outline"
            or bool(self.outline.polylines_um)
            or self.outline.dxf_path is not None,
            "SimulationSettings.geometry='outline' needs walls: give outline.polylines_um "
            "or outline.dxf_path",
        )
        _require(
            self.growth_noise < 1,
            f"SimulationSettings.growth_noise must be below 1 (rates stay positive), "
            f"got {self.growth_noise!r}",
        )
        _require(
            0 <= self.lysis_p <= 1,
            f"SimulationSettings.lysis_p is a probability in [0, 1], got {self.lysis_p!r}",
        )
        _require(
            isinstance(self.gravity, (int, float)) and math.isfinite(self.gravity),
            f"SimulationSettings.gravity must be a finite number, got {self.gravity!r}",
        )
        _require(
            isinstance(self.seed, int) and self.seed >= 0,
            f"SimulationSettings.seed must be a non-negative integer, got {self.seed!r}",
        )
        _require(
            self.geometry != "agar_pad" or self.agar_pad.n_colonies <= self.n_founders,
            f"AgarPadGeometry.n_colonies={self.agar_pad.n_colonies} exceeds "
            f"SimulationSettings.n_founders={self.n_founders}: every colony needs a founder; "
            "raise n_founders",
        )
        widest_um = self.cell_width_um + 3 * math.sqrt(self.width_var_um2)
        _require(
            self.geometry not in ("trench", "chamber") or widest_um < self.trench.width_um,
            f"cell_width_um={self.cell_width_um} (+3 sd of width_var_um2: {widest_um:.3g}) "
            f"does not fit in a trench of width_um={self.trench.width_um}: make the trench "
            f"wider or the cells narrower (or lower width_var_um2)",
        )
        _require(
            self.cell_max_length_um > self.cell_width_um,
            f"cell_max_length_um={self.cell_max_length_um} must exceed cell_width_um="
            f"{self.cell_width_um}: a rod is longer than it is wide",
        )
        _require(
            self.geometry not in ("trench", "chamber")
            or self.cell_max_length_um < self.trench.length_um,
            f"cell_max_length_um={self.cell_max_length_um} must be shorter than the trench "
            f"(length_um={self.trench.length_um})",
        )


@dataclass(frozen=True)
class Microscope:
    """Objective, illumination and sampling.

    Parameters
    ----------
    pixel_size_um
        Camera pixel size in the sample plane (camera pixel / magnification).
    magnification
        Objective magnification, recorded for reference.
    numerical_aperture
        Objective NA; cannot exceed ``refractive_index``.
    refractive_index
        Refractive index of the immersion medium (1.0 air, 1.33 water, 1.518 oil).
    wavelength_um
        Imaging (vacuum) wavelength; the emission wavelength in fluorescence.
    condenser
        Phase-contrast condenser, one of :data:`CONDENSERS`.
    modality
        ``"phase"`` (phase contrast), ``"fluorescence"`` or ``"brightfield"``
        (transmitted light without a phase ring: absorption, and the cells' lens effect
        out of focus, ``RenderSettings.defocus_contrast_um2``).
    """

    pixel_size_um: float = 0.065
    magnification: float = 100.0
    numerical_aperture: float = 1.45
    refractive_index: float = 1.518
    wavelength_um: float = 0.65
    condenser: str = "Ph3"
    modality: Modality = "phase"

    def __post_init__(self) -> None:
        plain_numbers(self)
        _positive(
            self,
            "pixel_size_um",
            "magnification",
            "numerical_aperture",
            "refractive_index",
            "wavelength_um",
        )
        _require(
            self.numerical_aperture <= self.refractive_index,
            f"Microscope.numerical_aperture={self.numerical_aperture} cannot exceed the "
            f"immersion refractive_index={self.refractive_index} (an oil objective needs "
            f"refractive_index ~1.518)",
        )
        _choice(self, "condenser", CONDENSERS)
        _choice(self, "modality", typing.get_args(Modality))
        _require(
            self.wavelength_um < 5,
            f"Microscope.wavelength_um={self.wavelength_um} looks like nanometres: give it "
            f"in micrometres (e.g. 0.65)",
        )
        _require(  # found as a user: 0.00065 (mm for um) was fitted
            self.wavelength_um >= 0.2,
            f"Microscope.wavelength_um={self.wavelength_um} is below the ultraviolet (0.2 um): "
            "give the light's wavelength in micrometres (e.g. 0.65 for 650 nm)",
        )

    @property
    def min_apodisation_sigma_um(self) -> float:
        """Lower bound of the apodisation sigma, eq. 13: ``0.9 lambda n / (2 NA)``."""
        return 0.9 * self.wavelength_um * self.refractive_index / (2 * self.numerical_aperture)


@dataclass(frozen=True)
class RenderSettings:
    """Parameters of the forward model that turns a scene into an image.

    Parameters
    ----------
    upsample
        Render-resolution pixels per camera pixel (>= 3, supplement section 4).
    psf_radius_px
        PSF kernel radius in render-resolution pixels.
    cell_intensity, media_intensity, device_intensity
        Effective intensities ``I_c``, ``I_m``, ``I_t`` of eq. 3 (ADU above the camera
        baseline for a full-depth column of each material).
    apodisation_sigma_um
        Gaussian apodisation of the phase PSF, eq. 11-12; at least the bound of eq. 13.
    defocus_sigma_um
        Gaussian defocus blur, eq. 14 (0 = in focus).
    ring_contrast
        Weight of the phase-ring term against the bright-field term of the phase
        kernel; sets halo strength independently of the kernel's shape.
    psf_offset
        Weight moved from the bright-field part of the phase kernel to a negative
        uniform disk over its radius (a constant inside the radius, kernel sum kept
        at 1); positive values add long-range halo and shade-off (section 13.2).
    ring_model
        Shape of the ring part of the phase kernel: ``"airy"`` (intensity pattern of
        the obscured Airy of eq. 7, the shape before ``"annulus"`` existed) or
        ``"annulus"`` (weak-phase transfer function of partially coherent annular
        illumination through the phase plate, ``optics.psf.annulus_transfer_function``;
        its halo reaches ``~ lambda / (W NA)``, several um, so give it a
        ``psf_radius_px`` of a few um).
    phase_ring_width_scale
        Width of the phase plate's ring over the width of the condenser's catalogue
        annulus (:data:`CONDENSERS`), 0.5-3 (makers differ); the ring stays centred
        on the annulus. Wider rings pass fewer low frequencies: a narrower halo.
    cell_phase_adu, device_phase_adu
        Phase signal of a full-depth column of cells (device) against media, in ADU:
        ``I_0 (2 sin(theta) / a) 2 pi (n - n_media) depth / lambda`` for a plate of
        amplitude transmission ``a`` and phase shift ``theta``, the weight of the
        zero-sum ring part, separate from the bright-field contrast of the
        intensities. ``None`` for both (default): the ring part is tied to the
        intensities, ``P_k = ring_contrast (I_media - I_k)`` (one kernel
        ``h = k_bf + gamma k_ring``); a number for either sets them apart (the other
        ``None`` counts as 0) and ``ring_contrast`` is not used.
    phase_model
        ``"linear"`` (default): the image is the sample convolved with the phase
        kernel (eq. 7-15; weak-phase approximation, cached per component).
        ``"partially_coherent"``: the sample's complex transmission
        ``sqrt(B) exp(i phi)`` imaged through the annular illumination and the phase
        plate, summed over source points
        (``optics.partial_coherence.annular_phase_image``): reaches the halo,
        bright gaps and weak shade-off of dense colonies that the linear model
        cannot. Uses ``cell_phase_rad``, ``device_phase_rad``,
        ``plate_transmission``, ``plate_phase_rad``, ``phase_ring_width_scale``,
        ``apodisation_sigma_um``, ``defocus_sigma_um``, ``focus_offset_um`` and
        ``source_points``; the intensities give the bright-field transmission
        ``B = I_k / I_media`` and the level of the empty field (``media_intensity``);
        ``ring_contrast``, ``psf_offset``, ``ring_model`` and the ``*_phase_adu`` are
        not used.
    cell_phase_rad, device_phase_rad
        Phase delay of a full-depth column of cells (device) against the media,
        ``2 pi (n - n_media) depth / lambda`` (eq. OPL1-3), partially coherent model.
    plate_transmission
        Intensity transmission of the phase plate's ring (``(0, 1]``; commercial
        plates 0.05-0.3), partially coherent model.
    plate_phase_rad
        Phase advance of the plate's ring; ``pi / 2`` is positive (dark-medium)
        phase contrast. Partially coherent model.
    source_points
        Points of the condenser annulus summed by the partially coherent model
        (angles x 2 radii; >= 8).
    focus_offset_um
        Distance of the focal plane from the sample, um, as the pupil phase of free
        propagation in the immersion medium (positive: focus past the sample, towards
        the objective); partially coherent model. Unlike ``defocus_sigma_um`` (a blur)
        it moves light between a cell's rim and centre; 0 = in focus. In fluorescence
        with ``depth_layers > 0``: the focal plane's distance from the cells'
        mid-plane (the image is the same at ``+z`` and ``-z``: a cell is symmetric
        about its mid-plane and the index-matched PSF about its focus).
    defocus_contrast_um2
        Bright field: ``kappa`` (um^2) of the cells' lens term out of focus, the
        transport-of-intensity equation's ``kappa = z lambda phi / (2 pi n)`` (``z`` the
        focal plane's distance from the sample, ``phi`` the phase of a full-depth cell
        column, ``n`` the immersion index): the image gets ``- kappa I_m`` times the
        cells' fraction convolved with ``laplacian(k)`` (``k`` the Airy PSF with eq. 14's
        defocus; :func:`~napari_symbac.optics.psf.brightfield_kernels`). Positive: a
        bright centre in a dark rim; negative: the reverse; 0 = in focus (absorption
        only). docs/physics.md, "Bright field". Not used in phase contrast or
        fluorescence.
    noise_model
        ``"camera"`` (EMVA1288, eq. 17), ``"gaussian"`` or ``"none"``.
    gaussian_noise_sd_adu
        Standard deviation of the Gaussian noise model.
    texture_amplitude
        Perlin background texture of an agar pad (section 13.2.1): the media image is
        multiplied by ``1 + texture_amplitude * T`` with ``T`` a unit-s.d. Perlin
        texture drawn from the simulation seed (same seed, same texture); 0 = none.
    texture_scale_um
        Lattice spacing of the texture's coarser octave (um; two octaves, the finer half
        as strong), a texture measured on a recording (``calibrate`` in bright field:
        twice the background's correlation length); 0 = section 13.2.1's random Perlin
        texture, coarsest octave 0.1-0.5 of the field.
    cell_brightness_cv
        Per-cell brightness variability for fluorescence (section 13.2.2, stochastic
        gene expression): when a simulation is rendered, each cell's image is
        multiplied by a gain from a gamma distribution with mean 1 and this
        coefficient of variation. The gain is drawn once per cell id from the
        simulation seed, so a cell keeps its brightness in every frame and the same
        seed gives the same gains; 0 = every cell alike (in phase contrast a gain
        scales the cell's material, so its optical path: the spread ``fit_colony``
        measures on a colony, 0.10-0.19 on the Omnipose colonies).
    cell_brightness_max_gain
        The largest per-cell gain, as a multiple of the mean cell (at least 1): the
        gamma of ``cell_brightness_cv`` truncated there, so that no cell is brighter
        than the recording's brightest (``calibrate`` sets it from the masks' whole
        cells; a CV measured on a few cells has a long tail); 0 (default) = no bound.
    envelope_stain_fraction
        Fluorescence: the fraction of each cell's stain that sits in its envelope
        (a membrane dye, a periplasmic or surface label) instead of filling its
        volume, in ``[0, 1]``; 0 (default) = a cytoplasmic stain, the image unchanged.
        The envelope is a shell :data:`~napari_symbac.scene.ENVELOPE_THICKNESS_UM`
        thick; its projection is brighter at the rim than on the centre line
        (:func:`~napari_symbac.scene.envelope_stain`, extending eq. OPL2). The cell
        intensity keeps its meaning: both stains put the same light per unit length
        of a cell's cylinder. Phase contrast does not draw it (a stain does not
        change the optical path).
    depth_layers
        Fluorescence: the number of slabs through the optical depth in which the
        cells' stain is imaged, each through the PSF defocused by its distance from
        the focal plane, ``S = sum_z PSF_z conv OPL_z`` (eq. 16 of the supplement;
        :func:`~napari_symbac.scene.stain_layers`,
        :func:`~napari_symbac.optics.psf.born_wolf_psf_3d`). A cell's top and bottom,
        out of focus by about its radius, are blurred more than its sides: a stain in
        the envelope dips between its rims as recorded. 0 (default) = the 2-D
        projection of eq. OPL2 through one PSF, the image unchanged. The media and
        device (the background) stay imaged through the 2-D PSF. Phase contrast does
        not use it (its focus is ``focus_offset_um`` of the partially coherent
        model).
    debris_density_per_100um2
        Debris (:func:`~napari_symbac.scene.add_debris`): unlabelled particles in the
        medium, out of focus, never in the masks: particles per 100 um^2 of the field
        outside the cells (a Poisson count); 0 (default) = none, the image unchanged.
    debris_diameter_um, debris_diameter_cv
        Median diameter of a particle (a disk) and the coefficient of variation of its
        log-normal distribution.
    debris_brightness, debris_brightness_cv
        Median peak of a particle of the median diameter, as a fraction of a
        full-depth cell column (the particle adds ``b (I_c - I_m)`` at its centre,
        eq. 3), and the CV of its log-normal distribution; a particle of diameter ``d``
        has ``b (debris_diameter_um / d)^2`` (the same light whatever its size,
        :func:`~napari_symbac.scene.add_debris`).
    debris_defocus_sigma_um
        Extra Gaussian blur of each particle (eq. 14): its distance from the focal
        plane, on top of the image's ``defocus_sigma_um``.
    """

    upsample: int = 3
    psf_radius_px: int = 50
    cell_intensity: float = 1400.0
    media_intensity: float = 2600.0
    device_intensity: float = 900.0
    apodisation_sigma_um: float = 0.6
    defocus_sigma_um: float = 0.0
    ring_contrast: float = 0.5
    psf_offset: float = 0.0
    ring_model: str = "airy"
    phase_ring_width_scale: float = 1.0
    cell_phase_adu: float | None = None
    device_phase_adu: float | None = None
    phase_model: str = "linear"
    cell_phase_rad: float = 0.6
    device_phase_rad: float = 0.0
    plate_transmission: float = 0.25
    plate_phase_rad: float = 1.5707963267948966
    source_points: int = 24
    focus_offset_um: float = 0.0
    defocus_contrast_um2: float = 0.0
    noise_model: NoiseModel = "camera"
    gaussian_noise_sd_adu: float = 20.0
    texture_amplitude: float = 0.0
    texture_scale_um: float = 0.0
    cell_brightness_cv: float = 0.0
    cell_brightness_max_gain: float = 0.0
    envelope_stain_fraction: float = 0.0
    depth_layers: int = 0
    debris_density_per_100um2: float = 0.0
    debris_diameter_um: float = 0.8
    debris_diameter_cv: float = 0.4
    debris_brightness: float = 0.2
    debris_brightness_cv: float = 0.5
    debris_defocus_sigma_um: float = 0.3

    def __post_init__(self) -> None:
        plain_numbers(self)
        _require(
            isinstance(self.upsample, int) and self.upsample >= 1,
            f"RenderSettings.upsample must be an integer >= 1, got {self.upsample!r}",
        )
        _require(
            isinstance(self.psf_radius_px, int) and self.psf_radius_px >= 3,
            f"RenderSettings.psf_radius_px must be an integer >= 3, got {self.psf_radius_px!r}",
        )
        _non_negative(
            self,
            "cell_intensity",
            "media_intensity",
            "device_intensity",
            "defocus_sigma_um",
            "ring_contrast",
            "gaussian_noise_sd_adu",
            "texture_amplitude",
            "texture_scale_um",
            "cell_brightness_cv",
            "debris_density_per_100um2",
            "debris_diameter_cv",
            "debris_brightness",
            "debris_brightness_cv",
            "debris_defocus_sigma_um",
        )
        _positive(self, "apodisation_sigma_um", "debris_diameter_um")
        _require(
            isinstance(self.envelope_stain_fraction, (int, float))
            and 0 <= self.envelope_stain_fraction <= 1,
            "RenderSettings.envelope_stain_fraction must be in [0, 1] (the fraction of the "
            f"stain in the cell envelope), got {self.envelope_stain_fraction!r}",
        )
        _finite(self, "psf_offset")
        _choice(self, "noise_model", typing.get_args(NoiseModel))
        _choice(self, "ring_model", ("airy", "annulus"))
        _choice(self, "phase_model", ("linear", "partially_coherent"))
        _non_negative(self, "cell_phase_rad", "device_phase_rad")
        _require(
            isinstance(self.plate_transmission, (int, float))
            and 0 < self.plate_transmission <= 1,
            "RenderSettings.plate_transmission must be in (0, 1] (an intensity "
            f"transmission), got {self.plate_transmission!r}",
        )
        _require(
            isinstance(self.plate_phase_rad, (int, float))
            and 0 < self.plate_phase_rad < math.pi,
            "RenderSettings.plate_phase_rad must be in (0, pi) (pi/2: positive phase "
            f"contrast), got {self.plate_phase_rad!r}",
        )
        _finite(self, "focus_offset_um", "defocus_contrast_um2")
        max_gain = self.cell_brightness_max_gain
        _require(
            isinstance(max_gain, (int, float))
            and (max_gain == 0 or (math.isfinite(max_gain) and max_gain >= 1)),
            "RenderSettings.cell_brightness_max_gain must be 0 (no bound) or at least 1 "
            f"(a multiple of the mean cell), got {max_gain!r}",
        )
        _require(
            isinstance(self.depth_layers, int)
            and not isinstance(self.depth_layers, bool)
            and 0 <= self.depth_layers <= MAX_DEPTH_LAYERS,
            f"RenderSettings.depth_layers must be an integer in [0, {MAX_DEPTH_LAYERS}] (0: the "
            f"2-D projection through one PSF), got {self.depth_layers!r}",
        )
        _require(
            isinstance(self.source_points, int) and self.source_points >= 8,
            f"RenderSettings.source_points must be an integer >= 8, got {self.source_points!r}",
        )
        _require(
            isinstance(self.phase_ring_width_scale, (int, float))
            and 0.5 <= self.phase_ring_width_scale <= 3.0,
            "RenderSettings.phase_ring_width_scale must be in [0.5, 3] (relative to the "
            f"condenser's catalogue annulus), got {self.phase_ring_width_scale!r}",
        )
        for name in ("cell_phase_adu", "device_phase_adu"):
            value = getattr(self, name)
            _require(
                value is None
                or (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0),
                f"RenderSettings.{name} must be None or a finite number >= 0, got {value!r}",
            )

    @property
    def phase_separate(self) -> bool:
        """True when the ring part has its own amplitudes (``*_phase_adu``)."""
        return self.cell_phase_adu is not None or self.device_phase_adu is not None

    def phase_amplitudes(self) -> tuple[float, float]:
        """``(P_cell, P_device)``, the ring part's weights in ADU (see the class notes)."""
        if self.phase_separate:
            return (float(self.cell_phase_adu or 0.0), float(self.device_phase_adu or 0.0))
        return (
            self.ring_contrast * (self.media_intensity - self.cell_intensity),
            self.ring_contrast * (self.media_intensity - self.device_intensity),
        )


@dataclass(frozen=True)
class Camera:
    """EMVA1288 linear camera (supplement section 6).

    Parameters
    ----------
    baseline_adu
        Mean dark signal ``mu_d`` in ADU (offset).
    sensitivity_adu_per_e
        System gain ``s`` in ADU per electron.
    dark_noise_e
        Dark (read) noise ``sigma_d`` in electrons.
    bit_depth
        Bits of the digitiser; output is clipped to ``[0, 2**bit_depth - 1]``.
    """

    baseline_adu: float = 100.0
    sensitivity_adu_per_e: float = 2.9
    dark_noise_e: float = 8.0
    bit_depth: int = 16

    def __post_init__(self) -> None:
        plain_numbers(self)
        _non_negative(self, "baseline_adu", "dark_noise_e")
        _positive(self, "sensitivity_adu_per_e")
        _require(
            isinstance(self.bit_depth, int) and 1 <= self.bit_depth <= 16,
            f"Camera.bit_depth must be an integer in 1..16, got {self.bit_depth!r}",
        )
        _require(  # found as a user: 70000 ADU rendered every pixel 65535, without a word
            self.baseline_adu < self.max_adu,
            f"Camera.baseline_adu={self.baseline_adu!r} is not below the camera's full scale "
            f"({self.max_adu} ADU at bit_depth {self.bit_depth}): every pixel would be "
            "clipped white; give the camera's dark level (its offset, e.g. 100 ADU)",
        )

    @property
    def max_adu(self) -> int:
        """Largest value the digitiser can output."""
        return 2**self.bit_depth - 1


@dataclass(frozen=True)
class ExtraStage:
    """A physical effect that ``napari-symbac diagnose`` found in a recording and
    accepted, drawn by render and export between the intensities (eq. 3) and the
    camera (eq. 17) (:mod:`napari_symbac.diagnose.stages`).

    Parameters
    ----------
    name
        The effect: ``uneven_illumination``, ``halo``, ``stray_light``,
        ``defocus_gradient``, ``fixed_pattern_noise`` or ``saturation``.
    parameters
        Its fitted parameters, as the diagnosis reports them (``diagnosis.json``).
    """

    name: str
    parameters: dict[str, Any] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        plain_numbers(self)
        # imported here: the effects' modules import these settings
        from napari_symbac.diagnose.stages import check_drawn_stage

        _require(
            isinstance(self.parameters, dict),
            f"ExtraStage.parameters of {self.name!r} must be a mapping of its fitted "
            f"parameters, got {self.parameters!r}",
        )
        check_drawn_stage(self.name, self.parameters)


@dataclass(frozen=True)
class PipelineSettings:
    """Everything needed to simulate and render a dataset, in one file.

    ``extra_stages`` are the effects a diagnosis accepted (:class:`ExtraStage`), in the
    order render and export apply them; empty by default.
    """

    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    microscope: Microscope = field(default_factory=Microscope)
    render: RenderSettings = field(default_factory=RenderSettings)
    camera: Camera = field(default_factory=Camera)
    extra_stages: tuple[ExtraStage, ...] = ()

    def __post_init__(self) -> None:
        plain_numbers(self)
        _nested(
            self,
            simulation=SimulationSettings,
            microscope=Microscope,
            render=RenderSettings,
            camera=Camera,
        )
        _require(
            isinstance(self.extra_stages, (list, tuple)),
            "PipelineSettings.extra_stages must be a list of {name, parameters}, got "
            f"{self.extra_stages!r}",
        )
        stages = tuple(
            s if isinstance(s, ExtraStage) else from_dict(
                ExtraStage, s, _where=f"PipelineSettings.extra_stages[{k}]"
            )
            for k, s in enumerate(self.extra_stages)
        )
        object.__setattr__(self, "extra_stages", stages)
        _require(
            self.render.apodisation_sigma_um >= self.microscope.min_apodisation_sigma_um,
            f"RenderSettings.apodisation_sigma_um={self.render.apodisation_sigma_um} is below "
            f"the diffraction bound of eq. 13 ({self.microscope.min_apodisation_sigma_um:.3f} "
            f"um for this microscope): raise it",
        )


# --------------------------------------------------------------------------------------
# Serialisation
# --------------------------------------------------------------------------------------

T = TypeVar("T")


def to_dict(settings: Any) -> dict[str, Any]:
    """Convert a settings dataclass (nested ones included) to plain Python types."""
    if not dataclasses.is_dataclass(settings) or isinstance(settings, type):
        raise TypeError(f"to_dict expects a settings dataclass, got {type(settings).__name__}")
    return dataclasses.asdict(settings)


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ValueError(f"{where} must be a mapping of {tp.__name__} fields, got {value!r}")
        return from_dict(tp, value, _where=where)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, where)
            except (TypeError, ValueError):
                continue
        raise ValueError(f"{where} has an unsupported value {value!r}")
    if origin is Literal:
        return value  # checked by the dataclass' own validation
    if value is None and tp in (bool, int, float, str):  # YAML's null, or an empty value
        raise ValueError(
            f"{where} is empty (null): give it a value, or leave the line out for the default"
        )
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not (
            isinstance(value, int) or (isinstance(value, float) and value.is_integer())
        ):
            raise ValueError(f"{where} must be an integer, got {value!r}")
        return int(value)
    if tp is float:
        if isinstance(value, str) and _YAML_EXPONENT.fullmatch(value.strip()):
            # YAML 1.1 reads 65e-3 (no dot) as text: found as a user, "must be a number,
            # got '65e-3'"; the number it spells is taken
            return float(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(
                f"{where} must be a number, got {value!r}: write a plain number (0.065 or "
                "6.5e-2), without units or quotes"
            )
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{where} must be text, got {value!r}")
        return value
    return value


#: A number in exponent notation without a dot (``65e-3``), which YAML 1.1 reads as text.
_YAML_EXPONENT = re.compile(r"[-+]?\d+[eE][-+]?\d+")


def from_dict(cls: type[T], data: dict[str, Any], *, _where: str | None = None) -> T:
    """Build settings of type ``cls`` from a mapping, rejecting unknown fields.

    Missing fields take their defaults. Nested settings may be given as mappings.
    """
    where = _where or cls.__name__
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - names)
    if unknown:
        import difflib

        # found as a user: cell_intensty got the 35 valid names, none singled out
        close = {key: difflib.get_close_matches(str(key), names, n=1) for key in unknown}
        meant = [f"{key} -> {match[0]}" for key, match in close.items() if match]
        said = f" (did you mean {', '.join(meant)}?)" if meant else ""
        raise ValueError(
            f"unknown field(s) {', '.join(unknown)} in {where}{said}; valid fields are: "
            f"{', '.join(sorted(names))}"
        )
    kwargs = {key: _convert(hints[key], value, f"{where}.{key}") for key, value in data.items()}
    try:
        return cls(**kwargs)
    except ValueError as err:  # a nested value's own check, named by where it sits (found
        # as a user: "Range low=2.0 must not exceed high=1.0" from a file of six ranges)
        if _where is None or str(err).startswith(f"{cls.__name__}."):
            raise
        raise ValueError(f"{where}: {err}") from None


def save_settings(settings: Any, path: str | Path) -> Path:
    """Write settings to ``path`` as YAML (``.yaml``/``.yml``) or JSON (``.json``)."""
    path = Path(path)
    data = to_dict(settings)
    if path.suffix.lower() in {".yaml", ".yml"}:
        text = yaml.safe_dump(data, sort_keys=False)
    elif path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2)
    else:
        raise ValueError(f"cannot save settings to {path}: use a .yaml, .yml or .json file")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def load_settings(path: str | Path, cls: type[T]) -> T:
    """Read settings of type ``cls`` from a YAML or JSON file written by :func:`save_settings`.

    A file may also hold only some fields (the rest take their defaults); an empty
    file is an error, so that a wrong or blank file never silently means the defaults.
    """
    data = read_settings_mapping(path)
    if cls is PipelineSettings:
        data = _pipeline_of_export(data)
        _refuse_a_section_file(data, path)
    else:  # `fit --camera microscope.yaml` listed the microscope's fields as unknown
        refuse_another_kind(data, path, cls)
    with _naming_the_file(path):
        return from_dict(cls, data)


@contextlib.contextmanager
def _naming_the_file(path: str | Path) -> Iterator[None]:
    """A settings file's invalid value or unknown key, said with the file's path (found
    as a user: "unknown field(s) numerical_apperture in Microscope" left the user to
    guess which of the command's files held it)."""
    try:
        yield
    except (TypeError, ValueError) as err:
        if str(path) in str(err):
            raise
        raise type(err)(f"settings file {path}: {err}") from None


def _refuse_a_section_file(data: Any, path: str | Path) -> None:
    """Refuse, in one line, a file of one section's fields given where a pipeline file
    is wanted (``render --config sim.yaml``): before, the message listed its 26 fields
    as unknown. An export file (``render --config export.yaml``) is refused so too."""
    if not isinstance(data, dict) or not data or _is_pipeline_mapping(data):
        return
    hints = typing.get_type_hints(PipelineSettings)
    for section in dataclasses.fields(PipelineSettings):
        if not dataclasses.is_dataclass(hints[section.name]):
            continue  # extra_stages: a list, not a section of fields
        names = {f.name for f in dataclasses.fields(hints[section.name])}
        if set(data) <= names:
            raise ValueError(
                f"{path} holds {section.name} settings only, and a pipeline file is wanted "
                "here: its sections are camera, microscope, render and simulation (start "
                "from `napari-symbac defaults pipeline --out FILE`, or put these fields "
                f"under `{section.name}:`)"
            )
    refuse_another_kind(data, path, PipelineSettings)


def refuse_another_kind(data: Any, path: str | Path, cls: type) -> None:
    """Refuse, in one line, a file of another kind of settings given where ``cls`` is
    wanted: ``simulate --config microscope.yaml`` (the file ``fit`` takes) listed the
    microscope's fields as unknown and the 26 valid ones, naming neither the file nor the
    kind wanted. The kinds recognised are the pipeline's sections, an export file and a
    pipeline file (where a pipeline is not wanted). A file whose fields are all of
    ``cls``, or of no single other kind, is left to :func:`from_dict` (a typo there is
    named by it).

    Found as a user: ``fit --microscope settings.yaml`` (the file ``fit`` writes),
    ``diagnose --microscope sim.yaml`` and ``export --config sim.yaml`` (whose ``seed``
    is a field of both) listed every field of the file as unknown."""
    if not isinstance(data, dict) or not data:
        return
    keys = set(data)
    if keys <= _field_names(cls):
        return
    wanted = _kind_name(cls)
    for kind, names in _settings_kinds():
        if kind == wanted or not keys <= names:
            continue
        held = "is a pipeline file" if kind == "pipeline" else f"holds {kind} settings"
        start = f"start from `napari-symbac defaults {wanted} --out FILE`"
        if kind == "pipeline":  # a section is wanted: the file holds it
            hint = f"copy its {wanted}: section into a file of its own, or {start}"
        elif kind == "export" and cls is PipelineSettings:
            hint = f"copy its pipeline: section into a file of its own, or {start}"
        elif wanted in ("simulation", "export"):  # these commands take pipeline files
            hint = f"{start}, or give a pipeline file such as the settings.yaml that fit writes"
        elif cls is Microscope:
            hint = (
                f"{start}, or copy the microscope: section of a pipeline file (the "
                "settings.yaml that fit writes) into a file of its own"
            )
        else:
            hint = start
        wanted_text = "a pipeline file is" if cls is PipelineSettings else f"{wanted} settings are"
        raise ValueError(f"{path} {held}, and {wanted_text} wanted here ({hint})")


def _field_names(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def _settings_kinds() -> list[tuple[str, set[str]]]:
    """Each kind of settings file (as ``napari-symbac defaults`` names it) with its
    fields: the pipeline's sections, then an export file, then a pipeline file."""
    from napari_symbac.export.dataset import ExportSettings

    hints = typing.get_type_hints(PipelineSettings)
    kinds = [
        (section.name, _field_names(hints[section.name]))
        for section in dataclasses.fields(PipelineSettings)
        if dataclasses.is_dataclass(hints[section.name])
    ]
    kinds.append(("export", _field_names(ExportSettings)))
    kinds.append(("pipeline", _field_names(PipelineSettings)))
    return kinds


def _kind_name(cls: type) -> str:
    """The kind of settings ``napari-symbac defaults`` names ``cls`` by: simulation,
    export, microscope, ..."""
    return cls.__name__.removesuffix("Settings").lower()


def _pipeline_of_export(data: Any) -> Any:
    """The ``pipeline`` section of an export settings mapping (the export_settings.yaml
    that ``calibrate`` writes), else ``data`` as it is. Found as a user: simulate's help
    and the README say calibrate's settings are reused, and simulate and render refused
    its file as export settings."""
    exported = isinstance(data, dict) and isinstance(data.get("pipeline"), dict)
    return data["pipeline"] if exported and set(data) <= dict(_settings_kinds())["export"] else data


def _is_pipeline_mapping(data: Any) -> bool:
    """Whether a settings file holds :class:`PipelineSettings`: a mapping of its sections
    only (what ``fit`` and ``calibrate`` write as settings.yaml)."""
    sections = {f.name for f in dataclasses.fields(PipelineSettings)}
    return isinstance(data, dict) and set(data) <= sections


def load_simulation_settings(path: str | Path) -> SimulationSettings:
    """Read :class:`SimulationSettings` from their own file, or from the ``simulation``
    section of a :class:`PipelineSettings` file or of an export file's pipeline (so that
    one file simulates, renders and exports alike)."""
    data = _pipeline_of_export(read_settings_mapping(path))
    with _naming_the_file(path):
        if _is_pipeline_mapping(data) and "simulation" in data:
            return from_dict(SimulationSettings, data["simulation"] or {}, _where="simulation")
        refuse_another_kind(data, path, SimulationSettings)
        return from_dict(SimulationSettings, data)


def load_settings_or_pipeline(path: str | Path, cls: type[T]) -> T | PipelineSettings:
    """Settings of type ``cls`` from their own file, or the :class:`PipelineSettings` of a
    pipeline file (:func:`_is_pipeline_mapping`), whose errors then name its sections."""
    data = read_settings_mapping(path)
    with _naming_the_file(path):
        if _is_pipeline_mapping(data):
            return from_dict(PipelineSettings, data)
        refuse_another_kind(data, path, cls)
        return from_dict(cls, data)


def load_microscope(path: str | Path) -> Microscope:
    """Read the :class:`Microscope` of a microscope file: its own field names
    (``numerical_aperture``, ..., some or all), or the spelling of ``napari-symbac
    diagnose`` (``NA``, ``objective``, ...), beside an optional camera section; the
    reader every command uses (:func:`napari_symbac.diagnose.config.load_microscope_file`,
    which also gives the camera), so that one file serves every command."""
    from napari_symbac.diagnose.config import load_microscope_file

    return load_microscope_file(path).microscope


def microscope_sets_pixel_size(path: str | Path | None) -> bool:
    """Whether the microscope file at ``path`` gives a pixel size (``pixel_size_um``; the
    spelling of ``napari-symbac diagnose``, with ``NA``, requires it), rather than leaving
    :class:`Microscope`'s default of 0.065 um; ``False`` without a file."""
    if path is None:
        return False
    data = read_settings_mapping(path)
    return isinstance(data, dict) and ("pixel_size_um" in data or "NA" in data)


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (YAML allows it
    and keeps the last: found as a user, ``pixel_size_um: 0.065`` then ``0.65`` further
    down was read as 0.65 without a word)."""

    def construct_mapping(self, node, deep=False):
        seen: set = set()
        for key_node, _value in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue  # `<<: *anchor` merges another mapping, whose keys it may override
            key = self.construct_object(key_node, deep=deep)
            try:
                hash(key)
            except TypeError:
                continue  # an unhashable key: the safe loader's own error says so
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    "while reading a mapping", node.start_mark,
                    f"found {key!r} a second time: give each setting once",
                    key_node.start_mark,
                )  # fmt: skip
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _unique_json_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object, refusing a key given twice (as :class:`_UniqueKeyLoader`)."""
    keys = [key for key, _ in pairs]
    twice = sorted({key for key in keys if keys.count(key) > 1})
    if twice:
        raise ValueError(f"found {twice[0]!r} a second time in one object: give each setting once")
    return dict(pairs)


def read_settings_mapping(path: str | Path) -> Any:
    """The parsed contents of a YAML/JSON settings file (refused when empty, a folder,
    missing, binary or not valid YAML/JSON, with a message that names the file)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"settings file {path} is a folder: give the path of a .yaml/.json file")
    if not path.is_file():
        raise FileNotFoundError(f"settings file {path} does not exist")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(
            f"settings file {path} is not a YAML/JSON text file (it holds binary data, e.g. "
            "an image): give the path of the .yaml/.json settings file"
        ) from None
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text, object_pairs_hook=_unique_json_keys)
        else:
            data = yaml.load(text, Loader=_UniqueKeyLoader)  # safe: a SafeLoader
    except (json.JSONDecodeError, yaml.YAMLError, ValueError) as err:
        raise ValueError(f"{path} is not valid YAML/JSON: {err}") from err
    if data is None:
        raise ValueError(
            f"settings file {path} is empty: write the fields to change in it (start from "
            "`napari-symbac defaults KIND --out FILE`), or leave the file out to use the "
            "defaults"
        )
    return data
