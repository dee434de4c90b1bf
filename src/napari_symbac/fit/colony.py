"""Dense phase-contrast colonies: the masks' scene with the partially coherent optics fitted.

The scene fit (:func:`~napari_symbac.fit.fit_scene`) renders phase contrast through
the linear (weak-phase) kernel of eq. 7-14, which cannot make the bright halo around a
colony on a pad nor the bright seams between its touching cells (docs/rendering.md).
Given instance masks of such a colony, :func:`fit_colony` draws the masks' scene
(:func:`~napari_symbac.scene.scene_from_masks`: each cell's thickness the chord across
its mask) and fits the partially coherent phase model (docs/physics.md) to it pixel by
pixel with :func:`~napari_symbac.fit.fit_parameters`: the cells' phase, apodisation and
ring width, the media level in closed form, with Gaussian noise of the
background's pixel noise (the 8-bit exports such colonies come in are not raw camera
counts). Then each cell's own optical path, a gain on its phase
(:func:`~napari_symbac.fit.cell_gains.fit_cell_gains`: real cells differ in thickness
and density), whose spread becomes the export's ``cell_brightness_cv``. The cells are
the masks' (centre, length, width and angle from each mask's moments), not refitted.
:func:`is_dense_colony` says when to take this path.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from napari_symbac.arguments import require_argument
from napari_symbac.fit.camera_estimate import image_bit_depth
from napari_symbac.fit.inputs import as_single_image
from napari_symbac.fit.preflight import (
    API_CAMERA_HINT,
    as_instance_ids,
    check_fit_image,
    check_instance_masks,
)
from napari_symbac.settings import Camera, Microscope, RenderSettings
from napari_symbac.sim.cells import FrameCells

__all__ = [
    "COLONY_START_OPTICS",
    "MIN_NOISE_ADU",
    "MIN_TOUCHING_CELLS",
    "ColonyFit",
    "band_upsample",
    "checked_colony_frame",
    "colony_cell_gains",
    "colony_optics",
    "colony_phase_render",
    "colony_result",
    "colony_start",
    "fit_colony",
    "is_dense_colony",
    "rendered_start",
    "resample_render",
    "touching_cells",
]

#: Fewest cells that touch another for masks to hold a colony (:func:`is_dense_colony`).
MIN_TOUCHING_CELLS = 5
#: Least Gaussian noise a colony fit draws (ADU). Below one grey level of an 8-bit
#: export the robust noise estimate (median absolute pixel differences) reads 0 while
#: the pixels still scatter by a fraction of a level; drawing no noise would make
#: flat, noiseless training images (Sample000033: background s.d. 0.33 over levels
#: 7-9). 0.5 ADU, quantised, scatters the pixels by ~0.58 ADU.
MIN_NOISE_ADU = 0.5
#: The partially coherent optics a colony fit starts from (:func:`colony_phase_render`):
#: a cell column's phase, the plate's transmission, the apodisation and the points of
#: the condenser annulus summed.
COLONY_START_OPTICS = {
    "cell_phase_rad": 0.6,
    "plate_transmission": 0.2,
    "apodisation_sigma_um": 2.0,
    "source_points": 12,
}


def touching_cells(masks: np.ndarray) -> int:
    """How many cells of an instance mask touch another cell (8-neighbours)."""
    labels = np.asarray(masks, np.int64)
    footprint = np.ones((3, 3), bool)
    above = int(labels.max()) + 1  # background and outside: above every label
    high = ndimage.maximum_filter(labels, footprint=footprint, mode="constant")
    low = ndimage.minimum_filter(
        np.where(labels > 0, labels, above), footprint=footprint, mode="constant", cval=above
    )
    cell = labels > 0
    touching = cell & ((high != labels) | (low != labels))
    return int(np.unique(labels[touching]).size)


def is_dense_colony(masks: np.ndarray | None, modality: str) -> bool:
    """Phase contrast whose masks hold a colony: at least :data:`MIN_TOUCHING_CELLS`
    cells, and at least half of them, touch another (the Omnipose colonies: 96-98 % of
    neighbouring pairs touch), so that the halo and seams matter."""
    if masks is None or modality != "phase":
        return False
    n_cells = int(np.count_nonzero(np.unique(np.asarray(masks))))
    n_touching = touching_cells(masks)
    return n_touching >= MIN_TOUCHING_CELLS and n_touching >= 0.5 * n_cells


def band_upsample(microscope: Microscope) -> int:
    """Smallest render upsampling whose pixels sample the image band ``2 NA / lambda``."""
    nyquist_um = microscope.wavelength_um / (4 * microscope.numerical_aperture)
    return max(1, math.ceil(microscope.pixel_size_um / nyquist_um - 1e-9))


def resample_render(
    render: RenderSettings, fitted_pixel_um: float, microscope: Microscope
) -> RenderSettings:
    """``render`` fitted on camera pixels of ``fitted_pixel_um``, for rendering with
    ``microscope``'s pixels: :func:`band_upsample` of that microscope, and a PSF radius of
    the same reach in um (the rest, the optics, are physical and stay)."""
    upsample = band_upsample(microscope)
    reach_um = render.psf_radius_px * fitted_pixel_um / render.upsample
    radius_px = max(8, math.ceil(reach_um * upsample / microscope.pixel_size_um - 1e-9))
    return dataclasses.replace(render, upsample=upsample, psf_radius_px=radius_px)


def colony_optics(
    image: np.ndarray,
    masks: np.ndarray,
    microscope: Microscope,
    camera: Camera,
    noise_adu: float,
    max_evaluations: int,
    *,
    progress: Any = None,
    cancel: Any = None,
) -> tuple[Any, Any, RenderSettings]:
    """The partially coherent phase model fitted to the scene of ``masks``.

    Starts from phase 0.6 rad, plate transmission 0.2, apodisation 2 um and the image's
    median as every intensity, at :func:`band_upsample`, 12 source points; the noise is
    Gaussian, ``noise_adu`` (at least :data:`MIN_NOISE_ADU`). Returns the
    :class:`~napari_symbac.fit.FitResult`, the scene and the starting render settings.
    """
    from napari_symbac.fit.parameters import fit_parameters

    render, scene = colony_start(masks, microscope, float(np.percentile(image, 50)), noise_adu)
    result = fit_parameters(
        image,
        None,
        scene,
        microscope,
        render,
        camera,
        terms=("pixel",),
        max_evaluations=max_evaluations,
        global_search=False,
        progress=progress,
        cancel=cancel,
    )
    return result, scene, render


def colony_start(
    masks: np.ndarray, microscope: Microscope, level_adu: float, noise_adu: float
) -> tuple[RenderSettings, Any]:
    """The start of :func:`colony_optics` (its notes) and the scene of ``masks``:
    every intensity ``level_adu`` (the image's median)."""
    from napari_symbac.scene import scene_from_masks

    render = colony_phase_render(
        RenderSettings(
            media_intensity=level_adu,
            noise_model="gaussian",
            gaussian_noise_sd_adu=max(noise_adu, MIN_NOISE_ADU),
        ),
        microscope,
    )
    return render, scene_from_masks(masks, microscope, render)


def colony_phase_render(render: RenderSettings, microscope: Microscope) -> RenderSettings:
    """``render`` on the partially coherent phase model at the start of the colony fit
    (:data:`COLONY_START_OPTICS`; the fitted colonies of docs/rendering.md: phase
    0.46-0.63 rad, apodisation 1.8-4 um, ring width 0.69-0.88), sampled at
    :func:`band_upsample` with a PSF reaching 3 um (the colony's halo). Every
    intensity is the media's, ``render.media_intensity``: in this model the
    intensities are the bright-field transmission ``B = I_k / I_media`` (docs/
    physics.md) and a cell on a pad is transparent; its contrast is its phase."""
    upsample = band_upsample(microscope)
    level = render.media_intensity
    return dataclasses.replace(
        render,
        **COLONY_START_OPTICS,
        upsample=upsample,
        psf_radius_px=max(8, round(3.0 * upsample / microscope.pixel_size_um)),
        phase_model="partially_coherent",
        cell_intensity=level,
        device_intensity=level,
    )


@dataclass(frozen=True)
class ColonyFit:
    """Outcome of :func:`fit_colony`, read like a :class:`~napari_symbac.fit.SceneFit`
    (the ``fit`` command writes both alike).

    Attributes
    ----------
    cells
        The masks' cells: centre, length, width and angle from each mask's moments;
        each cell's id is its mask's label.
    render
        Fitted render settings (partially coherent phase model, Gaussian noise of
        ``measured_noise_adu``, at least :data:`MIN_NOISE_ADU`).
    scene
        The masks' scene.
    synthetic, synthetic_before
        The fitted and the starting image without noise, baseline included (ADU).
    residual
        ``real - synthetic`` (ADU).
    terms
        ``{"pixel": (before, after)}``: reduced chi-square with the Gaussian noise.
    objective_before, objective_after
        The pixel term at the start and at the end.
    parameter_names, parameters, standard_errors
        The fitted optics and the media level; standard errors from the fit's Fisher
        information (NaN for the media level, solved in closed form, and for a
        parameter at a bound).
    warnings, at_bounds
        What sits at a bound, a fit worse than its start.
    n_evaluations
        Renders used.
    camera
        The camera of the likelihood (its baseline and bit depth; the noise is the
        render's Gaussian).
    measured_noise_adu
        The image's pixel noise (robust, from pixel differences; 0 below one grey level),
        whose variance plus the quantisation's (1/12 ADU^2) weighs the pixel term.
    cell_gains
        Cell id -> its fitted optical path relative to ``render.cell_phase_rad``
        (empty when not fitted); the scene and the synthetic image carry them.
    """

    cells: FrameCells
    render: RenderSettings
    scene: Any = field(repr=False)
    synthetic: np.ndarray = field(repr=False)
    synthetic_before: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    terms: dict[str, tuple[float, float]]
    objective_before: float
    objective_after: float
    parameter_names: tuple[str, ...]
    parameters: np.ndarray
    standard_errors: np.ndarray
    warnings: tuple[str, ...]
    at_bounds: tuple[str, ...]
    n_evaluations: int
    camera: Camera
    measured_noise_adu: float = 0.0
    trench: None = None
    cell_gains: dict[int, float] = field(default_factory=dict)

    @property
    def pixel_size_um(self) -> float:
        """The camera pixel the optics were fitted on (``render``'s sampling is for it)."""
        return float(self.scene.pixel_size_um * self.scene.upsample)

    @property
    def history(self) -> tuple[float, float]:
        """The pixel term at the start and the end (the scene fit's convergence curve)."""
        return (self.objective_before, self.objective_after)

    def cells_table(self) -> dict[str, list]:
        """The cells as lists (JSON), as :meth:`SceneFit.cells_table` (no standard errors:
        the cells are the masks', not fitted)."""
        table: dict[str, list] = {
            name: np.asarray(getattr(self.cells, name)).tolist()
            for name in ("ids", "x_um", "y_um", "angle_rad", "length_um", "width_um")
        }
        if self.cell_gains:
            table["optical_path_gain"] = [self.cell_gains.get(int(i)) for i in table["ids"]]
        return table


def fit_colony(
    image: np.ndarray,
    microscope: Microscope,
    masks: np.ndarray,
    camera: Camera | None = None,
    *,
    max_evaluations: int = 40,
    cell_gains: bool = True,
    max_gain_evaluations: int = 40,
    progress: Any = None,
    cancel: Any = None,
) -> ColonyFit:
    """Fit a phase-contrast colony drawn from its masks (module notes).

    Parameters
    ----------
    image
        One 2D frame (ADU; an 8-bit image is read as 8-bit counts with baseline 0).
    microscope
        Pixel size, wavelength, numerical aperture; modality phase.
    masks
        Instance masks of ``image`` (0 background).
    camera
        Its baseline and bit depth; default baseline 0 and the image's bit depth.
    max_evaluations
        Renders of the partially coherent model (each sums its source points) for the
        optics.
    cell_gains
        Fit each cell's optical path after the optics (with at least
        :data:`~napari_symbac.fit.fitted_settings.MIN_CELLS_FOR_SPREAD` cells); kept
        only when it lowers the residual.
    max_gain_evaluations
        Renders for the cells' optical paths.
    progress, cancel
        As :func:`~napari_symbac.fit.fit_parameters`.

    Raises
    ------
    TypeError
        No masks, or a microscope or camera of the wrong kind.
    ValueError
        Not phase contrast, an image the model cannot produce (NaN, RGB, a stack,
        negative or normalised values), or masks that are not instance masks of it
        (another shape, not integer ids, no cell or no background, an image's grey
        levels).
    """
    real, masks, camera, noise = checked_colony_frame(image, microscope, masks, camera)
    gain_budget = max_gain_evaluations if cell_gains else 0
    total = max_evaluations + gain_budget

    def optics_progress(done: int, _total: int) -> None:
        if progress is not None:
            progress(min(done, max_evaluations), total)

    result, scene, start = colony_optics(
        real, masks, microscope, camera, noise, max_evaluations,
        progress=optics_progress, cancel=cancel,
    )  # fmt: skip
    before = rendered_start(microscope, start, camera, scene)
    names = (*result.fitted, "media_intensity")
    values = np.array([float(getattr(result.render, n)) for n in names])
    errors = np.array([result.standard_errors.get(n, math.nan) for n in result.fitted] + [math.nan])
    gains = colony_cell_gains(
        real - camera.baseline_adu, scene, microscope, camera, result.render, gain_budget,
        progress=None if progress is None else lambda k, _n: progress(max_evaluations + k, total),
        cancel=cancel,
    )  # fmt: skip
    render, objective_after = result.render, result.objective_after
    synthetic = real - result.residual
    if gains is not None and gains.improved:
        scene, render = gains.scene, gains.render_with_spread(result.render)
        synthetic = gains.image + camera.baseline_adu
        objective_after = _pixel_term(real, synthetic, scene, render, camera)
    return colony_result(
        real,
        masks,
        microscope,
        camera,
        scene,
        render,
        synthetic=synthetic,
        before=before,
        objective=(result.objective_before, objective_after),
        parameter_names=names,
        parameters=values,
        standard_errors=errors,
        warnings=(*result.warnings, *(gains.warnings if gains is not None else ())),
        at_bounds=tuple(n for n in result.fitted if any(n in w for w in result.warnings)),
        n_evaluations=result.n_evaluations + (gains.n_evaluations if gains is not None else 0),
        cell_gains=gains.gains if gains is not None and gains.improved else None,
    )


def colony_cell_gains(
    image: np.ndarray,
    scene: Any,
    microscope: Microscope,
    camera: Camera,
    render: RenderSettings,
    budget: int,
    *,
    progress: Any = None,
    cancel: Any = None,
) -> Any:
    """Each cell's own optical path on the fitted optics ``render``
    (:func:`~napari_symbac.fit.cell_gains.fit_cell_gains`, ``budget`` renders; ``image``
    in ADU above the baseline), or None with no budget or fewer cells than a spread
    needs (:data:`~napari_symbac.fit.fitted_settings.MIN_CELLS_FOR_SPREAD`). The
    gains are worth keeping only where :attr:`~napari_symbac.fit.cell_gains.CellGainFit.improved`.
    Used by :func:`fit_colony` and by ``calibrate`` for dense colonies."""
    from napari_symbac.fit.cell_gains import fit_cell_gains
    from napari_symbac.fit.fitted_settings import MIN_CELLS_FOR_SPREAD

    if budget <= 0 or scene.cell_ids.size < MIN_CELLS_FOR_SPREAD:
        return None
    return fit_cell_gains(
        image, scene, microscope, render, camera,
        max_evaluations=budget, progress=progress, cancel=cancel,
    )  # fmt: skip


def _pixel_term(
    real: np.ndarray, synthetic: np.ndarray, scene: Any, render: RenderSettings, camera: Camera
) -> float:
    """The pixel term of :func:`~napari_symbac.fit.fit_parameters` (its variance) for
    ``synthetic`` (ADU, baseline included) against ``real``."""
    from napari_symbac.fit.objectives import objective_terms
    from napari_symbac.fit.parameters import _variance, scene_classes

    variance = _variance(synthetic, render, camera)
    classes = scene_classes(scene)
    return objective_terms(synthetic, real, classes, terms=("pixel",), variance=variance)["pixel"]


def checked_colony_frame(
    image: np.ndarray, microscope: Microscope, masks: np.ndarray, camera: Camera | None
) -> tuple[np.ndarray, np.ndarray, Camera, float]:
    """One frame and its masks checked for :func:`fit_colony`: the image as float64,
    the masks (int64; a binary mask: one cell per connected region), the camera
    (default baseline 0 and the image's bit depth) and the background's Gaussian pixel
    noise (1 ADU where too little background to measure).

    Raises
    ------
    TypeError
        No masks, or a microscope or camera of the wrong kind.
    ValueError
        Not phase contrast, an image the model cannot produce (NaN, RGB, a stack,
        negative or normalised values), or masks that are not instance masks of it
        (another shape, not integer ids, no cell or no background, an image's grey
        levels).
    """
    from napari_symbac.export.visibility import pixel_noise

    require_argument(microscope, Microscope, "fit_colony(microscope=...)")
    require_argument(camera, Camera, "fit_colony(camera=...)", optional=True)
    if masks is None:
        raise TypeError(
            "fit_colony needs the colony's instance masks (0 background, one id per cell; "
            "e.g. from Omnipose or Cellpose): without them fit the image with fit_scene"
        )
    if microscope.modality != "phase":
        raise ValueError(
            "fit_colony fits the partially coherent phase-contrast model: the microscope's "
            f"modality is {microscope.modality!r} (use fit_scene for fluorescence)"
        )
    bit_depth = image_bit_depth(image)
    real = as_single_image(image)
    check_fit_image(real, camera_hint=API_CAMERA_HINT)
    masks = np.asarray(masks)
    check_instance_masks(masks, real.shape)
    masks = as_instance_ids(masks)[0].astype(np.int64)  # binary: a cell per region
    background = masks == 0
    camera = Camera(baseline_adu=0.0, bit_depth=bit_depth) if camera is None else camera
    noise = pixel_noise(real, background)
    return real, masks, camera, noise if math.isfinite(noise) else 1.0


def rendered_start(
    microscope: Microscope, start: RenderSettings, camera: Camera, scene: Any
) -> np.ndarray:
    """The image of ``scene`` with the starting optics, noise-free, baseline included (ADU)."""
    from napari_symbac.optics import ForwardModel

    clean = ForwardModel(microscope, start, camera).render_clean(scene, cache=False)
    return np.asarray(clean, np.float64) + camera.baseline_adu


def colony_result(
    real: np.ndarray,
    masks: np.ndarray,
    microscope: Microscope,
    camera: Camera,
    scene: Any,
    render: RenderSettings,
    *,
    synthetic: np.ndarray,
    before: np.ndarray,
    objective: tuple[float, float],
    parameter_names: tuple[str, ...],
    parameters: np.ndarray,
    standard_errors: np.ndarray,
    warnings: tuple[str, ...],
    at_bounds: tuple[str, ...],
    n_evaluations: int,
    cell_gains: dict[int, float] | None = None,
) -> ColonyFit:
    """A :class:`ColonyFit` of one frame: the masks' cells measured (each cell's id its
    mask's label), ``render``'s noise (the measured) drawn at least :data:`MIN_NOISE_ADU`,
    the images as float32 and the residual ``real - synthetic`` (ADU, baseline included)."""
    from napari_symbac.fit.start import cells_from_instances

    cells = cells_from_instances(masks, microscope.pixel_size_um, math.inf, keep_labels=True)[0]
    synthetic = np.asarray(synthetic, np.float32)
    measured = render.gaussian_noise_sd_adu
    drawn = dataclasses.replace(render, gaussian_noise_sd_adu=max(measured, MIN_NOISE_ADU))
    return ColonyFit(
        cells=cells,
        render=drawn,
        scene=scene,
        synthetic=synthetic,
        synthetic_before=np.asarray(before, np.float32),
        residual=(real - synthetic).astype(np.float32),
        terms={"pixel": objective},
        objective_before=objective[0],
        objective_after=objective[1],
        parameter_names=parameter_names,
        parameters=parameters,
        standard_errors=standard_errors,
        warnings=warnings,
        at_bounds=at_bounds,
        n_evaluations=n_evaluations,
        camera=camera,
        measured_noise_adu=measured,
        cell_gains=dict(cell_gains or {}),
    )
