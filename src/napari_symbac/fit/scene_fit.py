"""Scene fitting by analysis by synthesis (issue 10).

Place and size spherocylinder cells (centre, angle, length, curvature, one shared or
hierarchical width) and the trench (left wall, width, closed end) so that the
rendered image overlays the real recording pixel for pixel, jointly with the
optical parameters and the camera's noise.

The stages, each in its own module:

* start (:mod:`~napari_symbac.fit.start`): cells from an instance mask, from painted
  labels or from a plain segmentation, with the polarity from the labels or the
  modality;
* censoring and noise (:mod:`~napari_symbac.fit.camera_estimate`,
  :mod:`~napari_symbac.fit.noise`): clipped pixels are left out; the camera's gain
  and read noise (eq. 17) are given or measured by photon transfer;
* the model and its solver (:mod:`~napari_symbac.fit.engine`,
  :mod:`~napari_symbac.fit.lm`): intensities in closed form (eq. 3 is linear in
  them), per-cell patches for the Jacobian, Levenberg-Marquardt, rounds of
  iteratively reweighted least squares;
* moves (:mod:`~napari_symbac.fit.moves`): remove, merge, split and add cells where
  the BIC says so;
* uncertainty: the Fisher information at the optimum and the standard errors.

Coordinates of fitted cells are in micrometres from the top-left corner of the
image (x along columns, y down the rows), angle as in
:class:`~napari_symbac.sim.FrameCells` (0 = vertical).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import sparse

from napari_symbac.arguments import require_argument
from napari_symbac.fit.camera_estimate import (
    censored_pixels,
    estimate_camera,
    image_bit_depth,
    with_unresolved_dark_noise,
)
from napari_symbac.fit.colony import is_dense_colony
from napari_symbac.fit.engine import CURVATURE_B, CURVATURE_C, Layout
from napari_symbac.fit.illumination import illumination_stage, illumination_terms
from napari_symbac.fit.inputs import as_label_stack, as_single_image
from napari_symbac.fit.lm import State, normal_equations
from napari_symbac.fit.moves import improve_scene, prune_cells
from napari_symbac.fit.noise import expected_level, variance
from napari_symbac.fit.objectives import objective_terms
from napari_symbac.fit.parameters import DEFAULT_FIT, _Budget, _variance, parameter_bounds
from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.fit.preflight import API_CAMERA_HINT, check_fit_image, check_instance_masks
from napari_symbac.fit.problem import Problem
from napari_symbac.fit.start import (
    _pixel_noise,
    otsu_cells,
    polarity_of,
    refuse_a_start_mostly_removed,
    start_scene,
)
from napari_symbac.scene import Scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

__all__ = [
    "SceneFit",
    "TrenchPlacement",
    "before_after_montage",
    "fit_scene",
    "otsu_cells",
    "recording_camera",
]

_INTENSITIES = ("cell_intensity", "media_intensity", "device_intensity")
#: The name of bright field's fourth amplitude, ``kappa I_m`` (ADU um^2), among the
#: fitted parameters (:attr:`~napari_symbac.fit.engine.SceneModel.lens`).
LENS_AMPLITUDE = "lens_amplitude_adu_um2"
#: Fitted optics by default: phase as :data:`~napari_symbac.fit.DEFAULT_FIT`; in
#: fluorescence and bright field the phase ring's parameters do not exist, defocus
#: remains (bright field's lens term is an amplitude, solved with the intensities).
DEFAULT_FIT_OPTICS = {
    "phase": DEFAULT_FIT,
    "fluorescence": ("defocus_sigma_um",),
    "brightfield": ("defocus_sigma_um",),
}
#: Optics of a fluorescence fit that also places the stain: the fraction of it in the
#: cells' envelope (``napari-symbac fit --envelope-stain``, Auto-fit's check box).
ENVELOPE_FIT_OPTICS = (*DEFAULT_FIT_OPTICS["fluorescence"], "envelope_stain_fraction")
#: Where that fraction starts when the settings give none: from 0, its lower bound, the
#: fit would start where the volume stain's cells (a third wider than the rims: 1.51 um
#: on ColiCoords ds2) keep the gradient of the fraction below 0.
ENVELOPE_START = 0.5


#: Where the focal plane of the depth-resolved image (``depth_layers``) starts when the
#: settings put it at the cells' mid-plane: the image is the same at ``+z`` and ``-z``,
#: so at 0 the fit's gradient in it vanishes; ColiCoords ds2 fits 0.21 um (docs/fitting.md).
DEPTH_FOCUS_START_UM = 0.2
#: Slabs of a depth-resolved fit when the user names none (Auto-fit's check box): 5 fit
#: ColiCoords ds2 as well as 15 (docs/fitting.md).
DEPTH_FIT_LAYERS = 5


def depth_start(render: RenderSettings, layers: int) -> RenderSettings:
    """``render`` as a fit of the depth-resolved image starts from it (``napari-symbac
    fit --depth-layers``): ``layers`` slabs, its focal plane or
    :data:`DEPTH_FOCUS_START_UM` when it gives none (fit ``focus_offset_um`` with it)."""
    focus = render.focus_offset_um or DEPTH_FOCUS_START_UM
    return dataclasses.replace(render, depth_layers=layers, focus_offset_um=focus)


def depth_fit_optics(optics: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The optics a depth-resolved fit fits: ``optics`` (the fluorescence default when
    ``None``) and the focal plane ``focus_offset_um`` (with :func:`depth_start`)."""
    return (*(DEFAULT_FIT_OPTICS["fluorescence"] if optics is None else optics), "focus_offset_um")


def envelope_stain_start(render: RenderSettings) -> RenderSettings:
    """``render`` as a fit of the envelope's fraction of the stain starts from it: its
    own fraction, or :data:`ENVELOPE_START` when it gives none (the CLI's
    ``--envelope-stain`` and Auto-fit's check box, with :data:`ENVELOPE_FIT_OPTICS`)."""
    if render.envelope_stain_fraction > 0:
        return render
    return dataclasses.replace(render, envelope_stain_fraction=ENVELOPE_START)
#: Levenberg-Marquardt iterations the other closed end gets before the two are compared.
CLOSED_END_ITERATIONS = 6
#: Iterations of the first round when later rounds follow. It settles the cells
#: (curvature held straight) for the closed-end choice and the moves, which change
#: the scene; the later rounds converge. On the SyMBac trench its iterations after
#: the 10th lowered the cost by about 0.1 % each, with 7 rods for 4 cells.
FIRST_ROUND_ITERATIONS = 15


@dataclass(frozen=True)
class SceneFit:
    """Outcome of :func:`fit_scene`.

    Attributes
    ----------
    cells
        Fitted cells (image coordinates, um), model-based lengths and widths.
    initial_cells
        The Otsu / watershed / moments start, or the cells a series fit carried over
        from the previous frame (:func:`~napari_symbac.fit.fit_series`).
    otsu_width_um
        Otsu width of each initial cell (area and length of its region); for carried
        cells, their fitted widths.
    trench
        Fitted trench placement (``None`` for an open field).
    render
        Fitted render settings (intensities and kernel parameters).
    scene
        The fitted scene at render resolution.
    synthetic
        Noise-free rendered image, baseline included (ADU, float32).
    residual
        ``real - synthetic`` (ADU, float32): the pixelwise residual for diagnosis.
    synthetic_before
        The rendered start (Otsu geometry, starting optics, intensities solved).
    terms
        ``{term: (before, after)}``; ``pixel`` is the reduced chi-square with the
        camera's variance (1 = fitted to the noise).
    objective_before, objective_after
        The pixel term at the start (Otsu geometry, starting optics, intensities
        solved) and at the end.
    n_evaluations
        Renders used.
    curvature_um
        Fitted curvature amplitude ``a`` (um) of eq. 1 per cell, with ``b, c`` =
        :data:`~napari_symbac.fit.engine.CURVATURE_B`, ``CURVATURE_C`` (zeros when not
        fitted); see :meth:`curvature`.
    camera
        The camera of the likelihood: the one given, or the one estimated from the
        residual variance against the model mean (gain, read noise; the baseline is
        the given or guessed offset).
    parameter_names
        Names of all fitted parameters: ``cell<id>.x_um`` ... per cell (see
        :class:`~napari_symbac.fit.engine.Layout`), the shared ones, then the three
        intensities (ADU above the baseline), and in bright field the lens amplitude
        ``kappa I_m`` (:data:`LENS_AMPLITUDE`, ADU um^2).
    parameters, standard_errors
        Their values and standard errors (same order), the errors from the inverse
        of :attr:`information`.
    information
        Fisher information at the optimum, ``J^T W J + P`` with ``J = d mu / d theta``
        over the valid pixels (:meth:`jacobian`), ``W`` the inverse camera variance
        and ``P`` the precision of the Gaussian priors (curvature, per-cell widths).
        A score test of an extra parameter ``phi`` uses
        ``J_phi^T W r`` and the Schur complement ``J_phi^T W J_phi -
        J_phi^T W J (information)^-1 J^T W J_phi``, with ``r`` = :attr:`residual`.
    at_bounds
        Parameters that ended at a bound.
    warnings
        Plain words: what did not converge, what sits at a bound, a fit worse than
        its start, a reduced chi-square far from 1.
    valid
        The pixels used in the likelihood (False: censored, e.g. clipped).
    moves
        What the fit chose, in order: the trench's closed end (when it was not given
        and is in the image) and the accepted add / remove / split / merge moves.
    history
        Reduced chi-square after every accepted Levenberg-Marquardt step of the
        rounds, and after the moves (their trial refits are not recorded): the fit's
        convergence curve.
    illumination_order, illumination
        Degree of the fitted illumination surface (0: flat) and its coefficients in
        the order of :func:`~napari_symbac.fit.illumination.illumination_terms`
        (:meth:`extra_stages` renders it).
    """

    cells: FrameCells
    initial_cells: FrameCells
    otsu_width_um: np.ndarray
    trench: TrenchPlacement | None
    render: RenderSettings
    scene: Scene = field(repr=False)
    synthetic: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    synthetic_before: np.ndarray | None = field(default=None, repr=False)
    terms: dict[str, tuple[float, float]] = field(default_factory=dict)
    objective_before: float = math.nan
    objective_after: float = math.nan
    n_evaluations: int = 0
    curvature_um: np.ndarray = field(default_factory=lambda: np.zeros(0))
    camera: Camera | None = None
    parameter_names: tuple[str, ...] = ()
    parameters: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    standard_errors: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    information: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    jacobian_matrix: sparse.csc_matrix | None = field(default=None, repr=False)
    at_bounds: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    valid: np.ndarray | None = field(default=None, repr=False)
    moves: tuple[str, ...] = ()
    history: tuple[float, ...] = ()
    illumination_order: int = 0
    illumination: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def extra_stages(self) -> list:
        """Forward-model stages of the fitted effects beyond eq. 3 (``ForwardModel``'s
        ``extra_stages``): the illumination surface when fitted, else none."""
        if self.illumination_order == 0:
            return []
        return [illumination_stage(self.illumination, self.illumination_order)]

    def jacobian(self) -> sparse.csc_matrix:
        """``d mu / d theta`` at the optimum (ADU per unit of each parameter).

        Sparse, one row per camera pixel (row-major, censored pixels included) and
        one column per :attr:`parameter_names`; ``mu`` is the clean image above the
        baseline. Cell columns are non-zero only near their cell.
        """
        if self.jacobian_matrix is None:
            raise ValueError("this fit holds no Jacobian")
        return self.jacobian_matrix

    def standard_error(self, name: str) -> float:
        """Standard error of one parameter by name."""
        try:
            return float(self.standard_errors[self.parameter_names.index(name)])
        except ValueError:
            raise ValueError(
                f"no fitted parameter {name!r}; names are in SceneFit.parameter_names"
            ) from None

    def curvature(self) -> dict[int, tuple[float, float, float]]:
        """The fitted curvature as ``draw_scene``'s mapping ``cell id -> (a_um, b, c)``."""
        return {
            int(i): (float(a), CURVATURE_B, CURVATURE_C)
            for i, a in zip(self.cells.ids, self.curvature_um)
            if a != 0
        }

    def trench_geometry(
        self, image_shape: tuple[int, int], pixel_size_um: float
    ) -> TrenchGeometry:
        """An approximate :class:`TrenchGeometry` for re-rendering with the pipeline.

        The pipeline centres the trench between equal side margins; they are chosen so
        that a rendered frame has the recording's ``(rows, columns)`` (the trench sits
        half the difference of the fitted left and right margins off its place in the
        recording: a training image of another size than the recording's would not do).
        The closed end keeps its fitted place (``top_margin_um``; found as a user: with
        the sides' margin above it, DeLTA's exported closed end sat 15 px too high).
        """
        if self.trench is None:
            raise ValueError("an open-field fit has no trench")
        rows, cols = image_shape
        margin = max((cols * pixel_size_um - self.trench.width_um) / 2, 0.0)
        room = max(rows * pixel_size_um - self.trench.width_um, 0.0)
        top = min(max(self.trench.top_um, 0.0), room)  # a closed end above the image: 0
        length = max(rows * pixel_size_um - top, self.trench.width_um)
        return TrenchGeometry(
            length_um=length,
            width_um=self.trench.width_um,
            depth_um=self.trench.depth_um,
            margin_um=margin,
            top_margin_um=top,
            closed_end=self.trench.closed_end,
        )

    def cells_table(self) -> dict[str, list]:
        """The fitted cells, their standard errors (``*_se``) and start sizes as lists (JSON)."""
        table: dict[str, list] = {
            name: np.asarray(getattr(self.cells, name)).tolist()
            for name in ("ids", "x_um", "y_um", "angle_rad", "length_um", "width_um")
        }
        table["curvature_um"] = np.asarray(self.curvature_um).tolist()
        # Each fitted cell next to the start cell nearest to it (moves may have
        # changed the count).
        start = self.initial_cells
        nearest = [
            int(np.argmin(np.hypot(start.x_um - x, start.y_um - y))) if len(start) else -1
            for x, y in zip(self.cells.x_um, self.cells.y_um)
        ]
        table["otsu_width_um"] = [float(self.otsu_width_um[k]) for k in nearest]
        table["otsu_length_um"] = [float(start.length_um[k]) for k in nearest]
        names = {"x_um": "x_um", "y_um": "y_um", "angle_rad": "angle_rad", "length_um": "length_um"}
        for column, name in names.items():
            table[f"{column}_se"] = [
                self._se_or_nan(f"cell{int(i)}.{name}") for i in self.cells.ids
            ]
        if any(name.endswith(".dbrightness") for name in self.parameter_names):
            values = dict(zip(self.parameter_names, self.parameters))
            table["intensity_adu"] = [
                self.render.cell_intensity * (1 + values[f"cell{int(i)}.dbrightness"])
                for i in self.cells.ids
            ]
        table["width_um_se"] = [
            self._se_or_nan(f"cell{int(i)}.dwidth_um", "width_um") for i in self.cells.ids
        ]
        return table

    def _se_or_nan(self, name: str, fallback: str | None = None) -> float:
        for key in (name, fallback):
            if key is not None and key in self.parameter_names:
                return float(self.standard_errors[self.parameter_names.index(key)])
        return math.nan


@dataclass
class _FrameRun:
    """One frame's fit before its results are assembled (see :func:`_frame_result`)."""

    real: np.ndarray
    labels: np.ndarray | None
    valid: np.ndarray
    y: np.ndarray
    baseline: float
    render: RenderSettings
    estimate: bool
    camera_used: Camera
    problem: Problem
    state: State
    start: State
    warnings: list[str]
    log: list[str]
    history: list[float]
    init_cells: FrameCells
    otsu_w: np.ndarray
    budget: _Budget
    progress: Callable[[int, int], None] | None


def fit_scene(
    real_image: np.ndarray,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera | None = None,
    *,
    geometry: Literal["trench", "open", "field"] = "trench",
    labels: np.ndarray | None = None,
    masks: np.ndarray | None = None,
    trench: TrenchPlacement | TrenchGeometry | None = None,
    closed_end: Literal["square", "round"] | None = None,
    fit_optics: tuple[str, ...] | None = None,
    valid: np.ndarray | None = None,
    width_sd_um: float = 0.0,
    per_cell_brightness: bool | None = None,
    fit_curvature: bool = True,
    curvature_sd_um: float = 0.1,
    illumination_order: int = 0,
    irls_rounds: int = 3,
    max_iterations: int = 25,
    moves: bool = True,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> SceneFit:
    """Fit cells, trench, optics and camera so the rendered image overlays the real one.

    Parameters
    ----------
    real_image
        One 2D frame (ADU, camera baseline included), phase contrast or fluorescence
        (``microscope.modality``).
    microscope, render
        Starting model; ``render`` gives the starting kernel parameters.
    camera
        The camera (eq. 17-19). ``None``: estimated from the data, without the model:
        the photon transfer of :func:`~napari_symbac.fit.camera_estimate.estimate_camera`
        on the image's high-pass residual gives gain and read noise, held fixed in
        every round (a camera refitted to the model's residual would absorb the
        model's misfit, so chi-square would always look like 1). Only when the image's
        levels span too little for it, the gain and read noise come from the residual
        variance against the model mean after each round
        (:func:`~napari_symbac.fit.camera_estimate.estimate_camera` with the model
        mean, :func:`_camera_from_model`). The baseline is
        guessed (100 ADU, or the image's 0.1 % quantile when lower, e.g. 0 for a
        background-subtracted image).
    geometry
        ``"trench"`` (mother machine) or ``"open"`` (an open field, an agar pad: no
        device; ``"field"``, the command line's word, is taken for it too).
    labels
        Painted classes (1 cell, 2 media, 3 device, 0 unpainted): rough strokes that
        give the polarity and rule out painted media/device in the start
        (:func:`~napari_symbac.fit.start.start_scene`), and the eq. 20
        / class-statistics terms of :attr:`SceneFit.terms`.
    masks
        An instance mask (or binary mask) to start from: the user's or any
        segmenter's.
    trench
        Starting trench placement (:class:`TrenchPlacement` in image coordinates, or a
        :class:`TrenchGeometry` read as ``left = margin_um``, ``top =
        shown_top_um``); default: found from the image.
    closed_end
        Shape of the trench's closed end: ``"square"`` or ``"round"``; default: that
        of ``trench`` if given, else the one that fits the image better (chosen after
        the first round, when the closed end is in the image: :func:`_better_closed_end`,
        said in :attr:`SceneFit.moves`).
    fit_optics
        Kernel parameters fitted jointly (any :func:`parameter_bounds` knows); the
        intensities always are. Default: :data:`DEFAULT_FIT_OPTICS` of the modality.
    valid
        Pixels to use (False: censored). Default:
        not :func:`~napari_symbac.fit.camera_estimate.censored_pixels` (saturated
        pixels and a pile of background-subtraction zeros left out).
    width_sd_um
        0 (default): one width shared by all cells. > 0: per-cell widths tied to the
        shared width by a Gaussian prior of this s.d. (hierarchical).
    per_cell_brightness
        Give each cell its own intensity ``I_c (1 + dbrightness)`` (a Gaussian prior
        of s.d. 1 ties ``dbrightness`` to 0). Default: on in fluorescence (cells
        differ in fluorophore content), off in phase contrast.
    fit_curvature, curvature_sd_um
        Fit each cell's curvature amplitude ``a`` of eq. 1 (one bend), with a
        Gaussian prior of this s.d. centred on 0; cells start straight and stay
        straight in the first round.
    illumination_order
        0 (default): flat illumination. ``k`` >= 1: the image is multiplied by a
        smooth surface ``1 + sum c_j P_j`` of degree ``k`` over the frame (vignetting,
        a tilted lamp; :mod:`~napari_symbac.fit.illumination`), its coefficients
        fitted with the scene (:attr:`SceneFit.illumination`). Degree 2 is the
        diagnosis' ``uneven_illumination`` surface.
    irls_rounds
        Rounds of iteratively reweighted least squares (variance, and the estimated
        camera, held fixed within a round).
    max_iterations
        Levenberg-Marquardt iterations per round (the first of several rounds at most
        :data:`FIRST_ROUND_ITERATIONS`).
    moves
        Add, remove, split and merge cells by the BIC after the first round
        (:mod:`~napari_symbac.fit.moves`).
    progress, cancel
        ``progress(done, total)`` after every render (``total`` an upper bound);
        ``cancel()`` returning True raises :class:`~napari_symbac.fit.FitCancelled`.

    Returns
    -------
    SceneFit

    Raises
    ------
    TypeError
        ``microscope``, ``render``, ``camera`` or ``trench`` of the wrong kind.
    ValueError
        An image the model cannot produce (NaN, RGB, a stack, negative or normalised
        values: :func:`~napari_symbac.fit.preflight.check_fit_image`), masks that are
        not instance masks of it, or a dense phase-contrast colony's masks (fitted by
        :func:`~napari_symbac.fit.fit_colony`).
    """
    return _frame_result(
        _run_frame(
            real_image,
            microscope,
            render,
            camera,
            geometry=geometry,
            labels=labels,
            masks=masks,
            trench=trench,
            closed_end=closed_end,
            fit_optics=fit_optics,
            valid=valid,
            width_sd_um=width_sd_um,
            per_cell_brightness=per_cell_brightness,
            fit_curvature=fit_curvature,
            curvature_sd_um=curvature_sd_um,
            illumination_order=illumination_order,
            irls_rounds=irls_rounds,
            max_iterations=max_iterations,
            moves=moves,
            progress=progress,
            cancel=cancel,
        )
    )


#: The gain of a camera whose noise could not be measured (:func:`_camera_from_model`):
#: a placeholder that leaves the read noise all of a constant variance.
UNMEASURED_GAIN_ADU_PER_E = 1e-3
#: How :attr:`SceneFit.warnings` starts to say so (the CLI and the docks say it their
#: own way, from the image's photon transfer: they leave this warning out).
UNMEASURED_CAMERA = "the camera could not be measured from the image"
#: Said when fit_scene is given the masks of a dense phase-contrast colony (found as an
#: API user: 43 of an Omnipose crop's 45 masked cells removed, the fit worse than its start).
DENSE_COLONY_MASKS = (
    "these masks hold a dense phase-contrast colony (touching cells): fit_scene's linear "
    "kernel cannot make its halo and bright seams and would remove most of the cells; "
    "fit it with napari_symbac.fit.fit_colony(image, microscope, masks), as "
    "`napari-symbac fit --masks` and calibrate do"
)


def _run_frame(
    real_image: np.ndarray,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera | None = None,
    *,
    geometry: Literal["trench", "open", "field"] = "trench",
    labels: np.ndarray | None = None,
    masks: np.ndarray | None = None,
    trench: TrenchPlacement | TrenchGeometry | None = None,
    closed_end: Literal["square", "round"] | None = None,
    fit_optics: tuple[str, ...] | None = None,
    valid: np.ndarray | None = None,
    width_sd_um: float = 0.0,
    per_cell_brightness: bool | None = None,
    fit_curvature: bool = True,
    curvature_sd_um: float = 0.1,
    illumination_order: int = 0,
    irls_rounds: int = 3,
    max_iterations: int = 25,
    moves: bool = True,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    start_cells: FrameCells | None = None,
) -> _FrameRun:
    """Check the inputs, start, and run the rounds and moves of :func:`fit_scene`.

    ``start_cells`` (a series fit's previous frame, moved by the drift) replace the
    automatic start's cells; the trench is still found from the image.
    """
    require_argument(microscope, Microscope, "fit_scene(microscope=...)")
    require_argument(render, RenderSettings, "fit_scene(render=...)")
    require_argument(camera, Camera, "fit_scene(camera=...)", optional=True)
    require_argument(
        trench, (TrenchPlacement, TrenchGeometry), "fit_scene(trench=...)", optional=True
    )
    real = as_single_image(real_image, name="real_image")
    check_fit_image(real, "real_image", camera_hint=API_CAMERA_HINT)
    bit_depth = image_bit_depth(real_image)  # of a camera measured from the image
    geometry = "open" if geometry == "field" else geometry  # `fit --geometry field`'s word
    if geometry not in ("trench", "open"):
        raise ValueError(f"geometry must be 'trench' or 'open' ('field'), got {geometry!r}")
    _refuse_what_the_command_line_refuses(real, microscope, camera, geometry)
    if masks is not None:  # refused before minutes of fit (an image given as masks, ...)
        masks = np.asarray(masks)
        check_instance_masks(masks, real.shape)
        if geometry == "open" and is_dense_colony(masks, microscope.modality):
            raise ValueError(DENSE_COLONY_MASKS)
    if labels is not None:
        labels = as_label_stack(labels, (1, *real.shape))[0]
    if not (math.isfinite(width_sd_um) and width_sd_um >= 0):
        raise ValueError(f"width_sd_um must be zero or positive, got {width_sd_um!r}")
    if not (math.isfinite(curvature_sd_um) and curvature_sd_um > 0):
        raise ValueError(f"curvature_sd_um must be positive, got {curvature_sd_um!r}")
    if irls_rounds < 1 or max_iterations < 1:
        raise ValueError("irls_rounds and max_iterations must be at least 1")
    n_light = len(illumination_terms(illumination_order))
    if getattr(render, "phase_separate", False) or (
        microscope.modality == "phase" and getattr(render, "phase_model", "linear") != "linear"
    ):
        raise ValueError(
            "fit_scene models the image as cells, media and device through one linear kernel: "
            "use the linear phase model without separate phase amplitudes "
            "(phase_model='linear', cell_phase_adu=device_phase_adu=None)"
        )
    modality = microscope.modality
    if fit_optics is None:
        fit_optics = DEFAULT_FIT_OPTICS.get(modality, ())
    fit_optics = tuple(fit_optics)
    for name in fit_optics:
        parameter_bounds(name, microscope)
    if valid is None:
        digitiser = camera if camera is not None else Camera(bit_depth=bit_depth)
        valid = ~censored_pixels(real, digitiser)
        if not valid.any():
            raise ValueError("every pixel of the image is clipped: no pixel is left to fit")
    else:
        valid = np.asarray(valid, bool)
        if valid.shape != real.shape:
            raise ValueError(f"valid of shape {valid.shape} does not match the image {real.shape}")
    valid = valid & np.isfinite(real)
    if valid.sum() < 10:
        raise ValueError("fewer than 10 valid pixels: check the valid mask")
    px = microscope.pixel_size_um
    depth = trench.depth_um if trench is not None else 1.2
    if isinstance(trench, TrenchGeometry):
        trench = TrenchPlacement(
            trench.margin_um, trench.width_um, trench.shown_top_um, depth, trench.closed_end
        )
    polarity = polarity_of(real, modality, labels)
    init_cells, otsu_w, found, _ = start_scene(
        real,
        microscope,
        geometry=geometry,
        labels=labels,
        masks=masks,
        trench=trench,
        depth_um=depth,
        valid=valid,
        refuse_wide=start_cells is None,  # a series' frame starts from the last one's cells
    )
    if start_cells is not None:
        init_cells, otsu_w = start_cells, np.asarray(start_cells.width_um, np.float64)
    placement = None if geometry == "open" else (trench if trench is not None else found)
    if placement is not None and closed_end is not None:
        placement = dataclasses.replace(placement, closed_end=closed_end)
    choose_end = placement is not None and closed_end is None and trench is None
    shape = real.shape
    n = len(init_cells)
    if per_cell_brightness is None:
        per_cell_brightness = modality == "fluorescence"
    layout = Layout(
        n=n,
        fit_curvature=fit_curvature,
        per_cell_width=width_sd_um > 0,
        trench=placement is not None,
        fit_top=placement is not None and placement.top_um > 0,
        optics=fit_optics,
        per_cell_brightness=bool(per_cell_brightness),
        illumination=illumination_order,
    )
    width_um, height_um = shape[1] * px, shape[0] * px
    # angles are wrapped into [-pi/2, pi/2) after each step (Layout.wrap_angles): +-pi
    # only bounds one step
    cell_lower = [-2.0, -3.0, -math.pi, 0.3] + [-0.5] * fit_curvature
    cell_lower += [-1.0] * (width_sd_um > 0)
    cell_upper = [width_um + 2, height_um + 3, math.pi, 12.0]
    cell_upper += [0.5] * fit_curvature + [1.0] * (width_sd_um > 0)
    cell_sd = [math.inf] * 4 + [curvature_sd_um] * fit_curvature
    cell_sd += [width_sd_um] * (width_sd_um > 0)
    if per_cell_brightness:
        cell_lower.append(-0.8)
        cell_upper.append(4.0)
        cell_sd.append(1.0)
    # Otsu is biased narrow (section 1.3): start a little wider; fitted widths as they are.
    widening = 0.1 if start_cells is None else 0.0
    width0 = float(np.clip(np.median(otsu_w) + widening, 0.4, 2.0))
    g0, g_lo, g_hi = [width0], [0.3], [2.5]
    if placement is not None:
        g0 += [placement.left_um, placement.width_um]
        g_lo += [-1.0, 0.3]
        g_hi += [width_um, width_um + 1]
        if layout.fit_top:
            g0.append(placement.top_um)
            g_lo.append(-1.0)
            g_hi.append(height_um)
    # The illumination surface starts flat; +-1 keeps it a modulation of the light.
    g0 += [0.0] * n_light
    g_lo += [-1.0] * n_light
    g_hi += [1.0] * n_light
    for name in fit_optics:
        lo, hi = parameter_bounds(name, microscope)
        g0.append(float(np.clip(getattr(render, name), lo, hi)))
        g_lo.append(lo)
        g_hi.append(hi)
    blocks = np.zeros((n, layout.per_cell))
    blocks[:, 0], blocks[:, 1] = init_cells.x_um, init_cells.y_um
    blocks[:, 2] = init_cells.angle_rad
    blocks[:, 3] = np.maximum(init_cells.length_um + 0.1, width0)
    estimate = camera is None
    baseline = camera.baseline_adu if camera is not None else _baseline_guess(real, valid)
    y = (real - baseline).ravel().astype(np.float64)
    flat_valid = valid.ravel()
    measured = None
    if camera is None:
        guess = Camera(baseline_adu=baseline, bit_depth=bit_depth)
        measured = _measured_camera(real, valid, guess)
        unclipped = ~censored_pixels(real) & np.isfinite(real)
        if measured is None and np.any(unclipped & ~valid):
            # A sparse valid mask (a held-out checkerboard) leaves no whole 3 x 3
            # neighbourhood for photon transfer; the pixels left out of the
            # likelihood carry the same camera noise.
            measured = _measured_camera(real, unclipped, guess)
        if measured is not None:
            baseline = measured.baseline_adu
            y = (real - baseline).ravel().astype(np.float64)
            w = flat_valid / variance(expected_level(y, valid), measured)
            camera_used = measured
        else:
            noise = _pixel_noise(real, valid) or float(np.std(real[valid])) or 1.0
            w = flat_valid / noise**2
            camera_used = guess
    else:
        w = flat_valid / _variance(expected_level(y, valid), render, camera)
        camera_used = camera
    per_cell = layout.per_cell
    history: list[float] = []
    total = irls_rounds * (max_iterations + 2) * (n * per_cell + 12) * 2
    budget = _Budget(total, progress, cancel)
    problem = Problem(
        shape=shape,
        microscope=microscope,
        render=render,
        camera=camera_used,
        placement=placement,
        depth_um=depth,
        layout=layout,
        y=y,
        w=w.astype(np.float64),
        cell_lower=np.array(cell_lower),
        cell_upper=np.array(cell_upper),
        cell_prior_sd=np.array(cell_sd),
        global_lower=np.array(g_lo),
        global_upper=np.array(g_hi),
        global_prior_sd=np.full(len(g0), math.inf),
        tick=budget.tick,
        on_step=lambda state: history.append(state.chi2 / max(int(flat_valid.sum()), 1)),
    )
    x0 = np.clip(
        Problem.join(blocks, np.array(g0)), problem.lower(n) + 1e-9, problem.upper(n) - 1e-9
    )
    start = problem.evaluate(x0)
    if modality == "brightfield":
        start = _narrower_start(problem, start)
    state = start
    warnings: list[str] = []
    log: list[str] = []

    def reweight(state: State) -> tuple[Problem, State]:
        nonlocal camera_used
        mu = state.mu
        if estimate:
            # The model-free photon transfer of the image is kept: a camera refitted
            # to the residual would absorb the model's misfit (gain 40.9 instead of
            # 2.0 ADU/e- on the real trench) and make chi-square meaningless. Only
            # an image whose levels span too little for it falls back to the residual.
            if measured is None:
                camera_used = _camera_from_model(
                    real, valid, (mu + baseline).reshape(shape), problem.camera
                )
            var = variance(mu, camera_used)
        else:
            var = _variance(mu, render, camera_used)
        new = problem.with_weights(flat_valid / var, camera_used)
        return new, new.evaluate(state.x)

    rounds = irls_rounds + (1 if irls_rounds == 1 and moves else 0)
    for round_ in range(rounds):
        free = np.ones(state.x.size, bool)
        if round_ == 0 and rounds > 1 and fit_curvature:
            # Curvature held straight in the first round: the centres and angles settle
            # first, so that a bend cannot stand in for them.
            held = np.ones(per_cell, bool)
            held[4] = False  # curvature_um
            free[: problem.n_cells(state.x) * per_cell] = np.tile(held, problem.n_cells(state.x))
        iterations = max_iterations
        if round_ == 0 and rounds > 1:
            iterations = min(max_iterations, FIRST_ROUND_ITERATIONS)
        state, converged = problem.refit(state, free, iterations)
        if not converged and iterations == max_iterations:
            warnings.append(
                f"round {round_ + 1}: the fit stopped at the iteration limit "
                f"({max_iterations}) before converging"
            )
        problem, state = reweight(state)
        if round_ == 0 and choose_end and layout.fit_top:
            problem, state, chosen = _better_closed_end(
                problem, state, min(CLOSED_END_ITERATIONS, max_iterations)
            )
            log.append(chosen)
        if round_ == 0 and moves:
            state, moved, phi = improve_scene(problem.without_history(), state, polarity)
            log += moved
            history.append(state.chi2 / max(problem.n_valid, 1))
            if phi > 1.5:
                warnings.append(  # found as a user: "(dispersion 191): the moves
                    # demanded that much more evidence" said nothing a user could act on
                    f"the residual is spatially correlated (neighbouring pixels err "
                    f"together: over 4 x 4 px its mean varies {phi:.3g} times as much as "
                    "noise alone gives): cells were added, removed, split or merged only "
                    "on that much stronger evidence"
                )
    if estimate and measured is None and (
        camera_used.sensitivity_adu_per_e == UNMEASURED_GAIN_ADU_PER_E
    ):  # found as an API user: ColiCoords' bright field near clipping, a "camera" of
        # 0.001 ADU/e- and 48629 e- read noise, without a word
        sd_adu = camera_used.sensitivity_adu_per_e * camera_used.dark_noise_e
        warnings.append(
            f"{UNMEASURED_CAMERA}: its levels span too little for photon transfer, or it "
            "is not raw counts. The noise is taken as constant, "
            f"{sd_adu:.3g} ADU s.d., from the residual, which takes up structure the model "
            "lacks, so a reduced chi-square near 1 says little; pass camera=Camera(...) "
            "when it matters"
        )
    if moves:
        state, pruned = prune_cells(problem.without_history(), state)
        if pruned:  # the rest settles without them
            log += [f"{line} after the last round" for line in pruned]
            state, converged = problem.refit(state, None, max_iterations)
            if not converged:
                warnings.append(
                    f"after the cells removed at the end: the fit stopped at the iteration "
                    f"limit ({max_iterations}) before converging"
                )
        if masks is None and labels is None and start_cells is None:
            removed = sum(line.startswith("removed") for line in log)
            refuse_a_start_mostly_removed(n, removed, problem.n_cells(state.x))
    return _FrameRun(
        real,
        labels,
        valid,
        y,
        baseline,
        render,
        estimate,
        camera_used,
        problem,
        state,
        start,
        warnings,
        log,
        history,
        init_cells,
        otsu_w,
        budget,
        progress,
    )


def lens_contrast_um2(intensities: np.ndarray) -> float:
    """Bright field's ``kappa`` (``RenderSettings.defocus_contrast_um2``, um^2) from the
    solved amplitudes ``(I_c, I_m, I_d, kappa I_m)``; 0 for an empty media level."""
    media = float(intensities[1])
    return float(intensities[3]) / media if media > 0 else 0.0


#: Fractions of the start's width a bright-field start also tries (:func:`_narrower_start`).
NARROWER_START = (0.6, 0.7, 0.8, 0.9)


def _narrower_start(problem: Problem, start: State) -> State:
    """The start, or the same cells narrower where the likelihood is better.

    A bright-field cell's edge is not where a mask's outline runs (ColiCoords' masks
    lie ~0.2 um outside the cells) nor where the segmentation's dark ring does: its
    lens term puts a dark rim around the edge and a bright centre inside, and started
    wider than the cell the fit widens the cell further to lay its rim on the real
    rim's outer side (ColiCoords' crop 01 from its mask, 1.52 um: 2.0 um at the
    defocus bound; started at 0.7 of it, 1.06 um). The shared width is tried at
    :data:`NARROWER_START` of its start, each one render, before the first step.
    """
    n = problem.n_cells(start.x)
    if n == 0:
        return start
    model = problem.model(n)
    k = model.layout.names(np.arange(1, n + 1)).index("width_um")
    low, high = problem.lower(n)[k], problem.upper(n)[k]
    best = start
    for factor in NARROWER_START:
        x = start.x.copy()
        x[k] = float(np.clip(start.x[k] * factor, low, high))
        trial = problem.evaluate(x)
        if trial.cost < best.cost:
            best = trial
    return best


def _refuse_what_the_command_line_refuses(
    real: np.ndarray, microscope: Microscope, camera: Camera | None, geometry: str
) -> None:
    """The checks ``napari-symbac fit`` and the docks make before a fit, made for the
    Python API too (found as an API user: a camera offset of 3000 ADU fitted 2 cells of
    4 to a reduced chi-square of 3350, a trench on its side was "4 trenches side by
    side", 65 um for 65 nm "5329 cells 909 um wide"): a pixel size no micrograph has, a
    camera that cannot have recorded the image, a trench on its side."""
    from napari_symbac.fit.preflight import (
        camera_recording_problem,
        check_pixel_size,
        lying_trench_problem,
    )

    check_pixel_size(microscope.pixel_size_um, "microscope.pixel_size_um")
    if camera is not None and (problem := camera_recording_problem(camera, real)):
        raise ValueError(f"fit_scene(camera=...): {problem}")
    lying = lying_trench_problem(real.shape, microscope.modality, "real_image")
    if geometry == "trench" and lying:
        raise ValueError(f"{lying}; or pass geometry='open' for an open field")


def _better_closed_end(
    problem: Problem, state: State, iterations: int
) -> tuple[Problem, State, str]:
    """The trench's closed end, square or round, that fits the image better, and a line
    that says so.

    Both shapes have the same parameters, so the lower chi-square decides (a choice
    between two models of equal size: no price). Both are refitted from the same
    state for ``iterations``, so that neither wins by descending further (found in a
    test: after 3 iterations the square end of a square trench lost to a round end
    given 3 more); a tie keeps the incumbent. Found as a user: the SyMBac
    trench's moulded round end, fitted square, left its corners in the residual
    unless ``--config`` said ``closed_end: round``.
    """
    current = problem.placement.closed_end
    other = "round" if current == "square" else "square"
    trial_problem = problem.with_placement(
        dataclasses.replace(problem.placement, closed_end=other)
    )
    trial, _ = trial_problem.refit(trial_problem.evaluate(state.x), None, iterations)
    state, _ = problem.refit(state, None, iterations)
    n = max(problem.n_valid, 1)
    if trial.cost < state.cost:
        return trial_problem.reporting_to(problem.on_step), trial, (
            f"closed end: {other}, which fits better (pixel chi-square {trial.chi2 / n:.4g} "
            f"against {state.chi2 / n:.4g} {current})"
        )
    return problem, state, (
        f"closed end: {current}, which fits better (pixel chi-square {state.chi2 / n:.4g} "
        f"against {trial.chi2 / n:.4g} {other})"
    )


def _frame_result(run: _FrameRun) -> SceneFit:
    """The :class:`SceneFit` of a run: unpacked cells, terms, uncertainty, warnings."""
    real, labels, valid, y, baseline = run.real, run.labels, run.valid, run.y, run.baseline
    render, estimate, camera_used = run.render, run.estimate, run.camera_used
    problem, state, start = run.problem, run.state, run.start
    warnings, log, history = list(run.warnings), run.log, run.history
    init_cells, otsu_w, budget, progress = run.init_cells, run.otsu_w, run.budget, run.progress
    shape = real.shape
    flat_valid = valid.ravel()
    # ---- results -----------------------------------------------------------------
    x = state.x
    n = problem.n_cells(x)
    model = problem.model(n)
    cells, curvature, place, r = model.unpack(x)
    intens = state.intensities
    final_render = dataclasses.replace(r, **{k: float(v) for k, v in zip(_INTENSITIES, intens)})
    if model.lens:  # the lens amplitude kappa I_m, as kappa (um^2)
        final_render = dataclasses.replace(
            final_render, defocus_contrast_um2=lens_contrast_um2(intens)
        )
    mu = state.mu
    mu0 = start.mu
    var_after = problem.w
    chi_after = float(np.sum(var_after * (y - mu) ** 2) / max(problem.n_valid, 1))
    w_before = flat_valid / (
        variance(mu0, camera_used) if estimate else _variance(mu0, render, camera_used)
    )
    chi_before = float(np.sum(w_before * (y - mu0) ** 2) / max(problem.n_valid, 1))
    synthetic = (mu + baseline).reshape(shape).astype(np.float32)
    before_img = (mu0 + baseline).reshape(shape)
    terms = {"pixel": (chi_before, chi_after)}
    if labels is not None:
        tb = objective_terms(before_img, real, labels, terms=("eq20", "class_stats"))
        ta = objective_terms(synthetic, real, labels, terms=("eq20", "class_stats"))
        terms.update({k: (tb[k], ta[k]) for k in ta})
    names, values, se, info, jac = _uncertainty(problem, state)
    lower, upper = problem.lower(n), problem.upper(n)
    tol = 1e-3 * model.layout.scales()
    at_bounds = tuple(
        name
        for name, v, lo, hi, t in zip(names, x, lower, upper, tol)
        if v <= lo + t or v >= hi - t
    )
    if at_bounds:
        warnings.append(f"at a bound: {', '.join(at_bounds)}")
    values, se, round_cells = _round_cells(model.layout, names, values, se, cells.length_um)
    if round_cells:
        warnings.append(
            f"at a bound: {', '.join(round_cells)} no longer than wide, at the cell's width "
            "(a round cell, or one cut by the image's edge: its length is not measured)"
        )
        at_bounds = (*at_bounds, *(name for name in round_cells if name not in at_bounds))
    if chi_after > chi_before:
        warnings.append(
            f"the fit is worse than its start (reduced chi-square {chi_after:.3g} > "
            f"{chi_before:.3g})"
        )
    if chi_after > 2.0:
        warnings.append(
            f"reduced chi-square {chi_after:.3g}: the model misses structure of the image, "
            "so the standard errors are too small"
        )
    if progress is not None:
        progress(budget.done, budget.done)  # the fit may end well within its bound
    return SceneFit(
        cells=cells,
        initial_cells=init_cells,
        otsu_width_um=otsu_w,
        trench=place,
        render=final_render,
        scene=state.scene,
        synthetic=synthetic,
        residual=(real - synthetic).astype(np.float32),
        synthetic_before=before_img.astype(np.float32),
        terms=terms,
        objective_before=chi_before,
        objective_after=chi_after,
        n_evaluations=budget.done,
        curvature_um=np.array([curvature.get(i, (0.0,))[0] for i in cells.ids], float),
        camera=camera_used,
        parameter_names=names,
        parameters=values,
        standard_errors=se,
        information=info,
        jacobian_matrix=jac,
        at_bounds=at_bounds,
        warnings=tuple(warnings),
        valid=valid,
        moves=tuple(log),
        history=tuple(history),
        illumination_order=model.layout.illumination,
        illumination=np.array(
            [values[names.index(k)] for k in model.layout.illumination_names], float
        ),
    )


def _measured_camera(real: np.ndarray, valid: np.ndarray, camera: Camera) -> Camera | None:
    """The camera from the image alone: photon transfer on its high-pass residual
    (:func:`~napari_symbac.fit.camera_estimate.estimate_camera`), free of any model.

    The baseline is the guess in ``camera`` (one frame cannot separate it from the read
    noise), unless the variance line puts the level of zero variance so far above it
    that the guess would predict at least twice the variance the line gives at the
    darkest pixels (their 0.1 % quantile): the baseline is then that level (at most the
    quantile), and the read noise 0. (Found as a user: a fluorescence series that kept
    its camera offset, all pixels above 1717 ADU and the line's zero at 1761 ADU, was
    fitted with the 100 ADU guess, and its noise predicted 4x too wide.) ``None`` when
    the estimate fails (too little range of levels): the fit then uses
    :func:`_camera_from_model`.
    """
    try:
        estimate = estimate_camera(real, valid=valid, camera=camera)
    except ValueError:
        return None
    measured = estimate.camera
    gain = measured.sensitivity_adu_per_e
    zero_variance_adu = -estimate.variance_intercept_adu2 / gain
    darkest = float(np.quantile(real[valid], 0.001))
    if darkest - camera.baseline_adu > 2 * (darkest - zero_variance_adu):
        baseline = min(zero_variance_adu, darkest)
        read_variance = max(estimate.variance_intercept_adu2 + gain * baseline, 0.0)
        measured = dataclasses.replace(
            measured, baseline_adu=baseline, dark_noise_e=math.sqrt(read_variance) / gain
        )
        measured = with_unresolved_dark_noise(measured, real, valid)
    return measured


def recording_camera(image: np.ndarray) -> Camera:
    """The camera ``napari-symbac fit`` starts from for ``image`` when none is given.

    Its digitiser's bits (:func:`~napari_symbac.fit.camera_estimate.image_bit_depth`),
    the offset guessed from its darkest pixels and the gain and read noise from photon
    transfer on the image alone (:func:`_measured_camera`). When the image spans too few
    levels for that (a flattened image), the fit's placeholder: a constant noise, the
    image's own pixel noise, carried by the read noise at
    :data:`UNMEASURED_GAIN_ADU_PER_E` (found as a user: the built-in gain at ColiCoords'
    flattened bright field, ~65000 ADU, drew noise of 158 ADU s.d. against its 28).
    Clipped and non-finite pixels are left out.
    """
    real = np.asarray(image, np.float64)
    valid = np.isfinite(real) & ~censored_pixels(image)
    if not valid.any():
        return Camera(bit_depth=image_bit_depth(image))
    guess = Camera(baseline_adu=_baseline_guess(real, valid), bit_depth=image_bit_depth(image))
    measured = _measured_camera(real, valid, guess)
    if measured is not None:
        return measured
    noise = _pixel_noise(real, valid)
    gain = UNMEASURED_GAIN_ADU_PER_E
    read_e = math.sqrt(max(noise**2 - 1 / 12, 0.0)) / gain
    return dataclasses.replace(guess, sensitivity_adu_per_e=gain, dark_noise_e=read_e)


def _camera_from_model(
    real: np.ndarray, valid: np.ndarray, model_adu: np.ndarray, camera: Camera
) -> Camera:
    """The camera from the residual against the model mean, after a round.

    Photon transfer of :func:`~napari_symbac.fit.camera_estimate.estimate_camera`
    with ``model_mean`` (baseline kept from ``camera``). When the model's levels span
    too little for a slope, the variance is taken as constant, the residual's mean
    square: the gain is then not identifiable and is set to
    :data:`UNMEASURED_GAIN_ADU_PER_E`, so that the read noise carries all of it.
    """
    try:
        return estimate_camera(real, valid=valid, model_mean=model_adu, camera=camera).camera
    except ValueError:
        residual = (real - model_adu)[valid]
        gain = UNMEASURED_GAIN_ADU_PER_E
        floor = max(float(np.mean(residual**2)), 1 / 12)
        return dataclasses.replace(
            camera,
            sensitivity_adu_per_e=gain,
            dark_noise_e=math.sqrt(max(floor - 1 / 12, 0.0)) / gain,
        )


def _baseline_guess(real: np.ndarray, valid: np.ndarray) -> float:
    """Camera offset of an unknown camera: 100 ADU, or the 0.1 % quantile when lower."""
    low = float(np.quantile(real[valid], 0.001))
    return float(min(Camera().baseline_adu, max(low, 0.0)))


def _round_cells(
    layout: Layout,
    names: tuple[str, ...],
    values: np.ndarray,
    se: np.ndarray,
    drawn_length_um: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Lengths fitted below their cell's width, given as drawn.

    A cell is drawn at least as long as it is wide (a capsule's caps), so a length
    parameter below the width changes nothing in the image: its value is not measured
    (found as a user: report.txt gave ``cell7.length_um: 0.928 +- 4e-11`` for a round
    cell and cells.json 1.172 um, the width). Such a length is reported as drawn, with an
    unknown (NaN) standard error, and named.

    Returns
    -------
    values, se, names
        Copies with those lengths replaced, and their parameter names.
    """
    values, se = np.array(values, float), np.array(se, float)
    names_found = []
    for k, drawn in enumerate(np.asarray(drawn_length_um, float)):
        i = k * layout.per_cell + layout.cell_names.index("length_um")
        if values[i] < drawn:
            values[i], se[i] = drawn, math.nan
            names_found.append(names[i])
    return values, se, names_found


def _uncertainty(
    problem: Problem, state: State
) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray, sparse.csc_matrix]:
    """Names, values, standard errors, Fisher information and ``d mu / d theta``.

    The Jacobian of every parameter (forward differences, per-cell patches) is
    taken in physical units; the information is ``J^T W J`` over the valid pixels
    plus the prior precisions; the standard errors are the square roots of the
    diagonal of its (pseudo-)inverse.
    """
    n = problem.n_cells(state.x)
    model = problem.model(n)
    free = np.ones(state.x.size, bool)
    jac_z = model.jacobian(
        state.x,
        state.a,
        state.intensities,
        state.scene,
        state.render,
        free,
        upper=problem.upper(n),
    )
    n_amp = model.n_amplitudes
    scales = np.concatenate([model.layout.scales(), np.ones(n_amp)])
    jac = (jac_z @ sparse.diags(1.0 / scales)).tocsc()
    info, _ = normal_equations(jac, np.sqrt(problem.w))
    sd = np.concatenate([problem.prior_sd(n), np.full(n_amp, math.inf)])
    info[np.diag_indices_from(info)] += 1.0 / sd**2
    # An intensity whose component is empty (no device on a pad) is not a parameter.
    keep = np.concatenate([np.ones(state.x.size, bool), np.any(state.a != 0, axis=0)])
    jac = jac[:, np.flatnonzero(keep)]
    info = info[np.ix_(keep, keep)]
    cov = np.linalg.pinv(info, rcond=1e-12, hermitian=True)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    amplitudes = (*_INTENSITIES, LENS_AMPLITUDE)[:n_amp]
    names = (*model.layout.names(np.arange(1, n + 1)), *amplitudes)
    names = tuple(name for name, k in zip(names, keep) if k)
    values = np.concatenate([state.x, state.intensities])[keep]
    return names, values, se, info, jac


def before_after_montage(real_image: np.ndarray, result: SceneFit) -> np.ndarray:
    """An 8-bit RGB figure: real | start (Otsu) | fitted | residual, side by side.

    The three images share one grey scale (0.5-99.5 percentiles of the real image);
    the residual is shown on a symmetric scale, red positive, blue negative.
    """
    real = as_single_image(real_image, name="real_image")
    low, high = np.percentile(real, [0.5, 99.5])
    panels = []
    before = result.synthetic_before if result.synthetic_before is not None else result.synthetic
    for image in (real, before, result.synthetic):
        grey = np.clip((np.asarray(image, float) - low) / max(high - low, 1e-9), 0, 1)
        panels.append(np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=-1))
    res = np.asarray(result.residual, float)
    limit = max(float(np.percentile(np.abs(res), 99)), 1e-9)
    v = np.clip(res / limit, -1, 1)
    rgb = np.full((*res.shape, 3), 255, np.uint8)
    rgb[..., 0] = (255 * (1 - np.maximum(-v, 0))).astype(np.uint8)
    rgb[..., 1] = (255 * (1 - np.abs(v))).astype(np.uint8)
    rgb[..., 2] = (255 * (1 - np.maximum(v, 0))).astype(np.uint8)
    panels.append(rgb)
    gap = np.zeros((real.shape[0], 3, 3), np.uint8)
    row = [panels[0]]
    for panel in panels[1:]:
        row.extend([gap, panel])
    return np.concatenate(row, axis=1)
