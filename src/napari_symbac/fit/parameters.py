"""Automatic fit of the optical parameters to a real image (section 7, eq. 13, 20).

For fixed geometry and kernel the clean image is linear in the intensities,
``mu = I_c C + I_m M + I_t D`` (eq. 3, 15) with ``C, M, D`` the convolved scene
components that the :class:`~napari_symbac.optics.ForwardModel` caches. The fit
therefore solves the intensities *exactly* (non-negative least squares) inside every
evaluation and leaves only the kernel parameters (apodisation, defocus, ring
contrast, PSF offset) and the noise to the nonlinear optimiser (variable
projection).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from napari_symbac.fit.inputs import CLASS_VALUES, as_label_stack, as_single_image
from napari_symbac.fit.noise import expected_level
from napari_symbac.fit.objectives import (
    DEFAULT_TERMS,
    TERM_NAMES,
    measured_noise_sd_adu,
    objective_terms,
    total_objective,
)
from napari_symbac.optics import ForwardModel
from napari_symbac.optics.forward import block_average
from napari_symbac.settings import CONDENSERS, Camera, Microscope, RenderSettings

__all__ = [
    "DEFAULT_FIT",
    "DEFAULT_FIT_PARTIALLY_COHERENT",
    "DEFAULT_FIT_STATISTICS",
    "MAX_PHASE_OVER_MEDIA",
    "FitCancelled",
    "FitResult",
    "fit_parameters",
    "fit_warnings",
    "parameter_bounds",
    "scene_classes",
    "with_media_level",
]

Progress = Callable[[int, int], None]
Cancel = Callable[[], bool]

#: Kernel parameters fitted by default with the pixel term (the intensities are always
#: fitted). The ring contrast is left at the condenser's value: with apodisation and
#: PSF offset it forms a nearly degenerate "optics" family (docs/fitting.md); add it to
#: ``fit`` to free it.
DEFAULT_FIT = ("apodisation_sigma_um", "defocus_sigma_um", "psf_offset")
#: Default with the statistics terms, which barely constrain the PSF offset: the
#: supplement's own pair (section 7).
DEFAULT_FIT_STATISTICS = ("apodisation_sigma_um", "defocus_sigma_um")
#: Default of the partially coherent phase model (``phase_model="partially_coherent"``):
#: the sample's phase and the shape of the pupil; the media level is solved exactly,
#: the cells' and device's bright-field transmission kept. The plate's transmission
#: is left at its value: near the weak-phase limit only ``phi / sqrt(T)`` shows, so
#: phase and plate trade off along a valley (on a real colony the pair ran to
#: ``T = 0.02``, ``phi = 0.19`` with the same class medians as ``T = 0.25``); add it
#: to ``fit`` when the phase is known.
DEFAULT_FIT_PARTIALLY_COHERENT = (
    "cell_phase_rad",
    "apodisation_sigma_um",
    "phase_ring_width_scale",
)
_FITTABLE = (
    *DEFAULT_FIT,
    "ring_contrast",
    "phase_ring_width_scale",
    "cell_phase_rad",
    "device_phase_rad",
    "plate_transmission",
    "plate_phase_rad",
    "focus_offset_um",
    "envelope_stain_fraction",
    "cell_transmission",
    "device_transmission",
    "gaussian_noise_sd_adu",
)
#: What :func:`fit_parameters` fits in fluorescence: the phase kernel's parameters
#: have no effect there.
_FLUORESCENCE_FITTABLE = ("defocus_sigma_um", "gaussian_noise_sd_adu")
#: Bright-field intensity transmissions of the partially coherent model (``B`` of
#: eq. 3 relative to the media): not render settings of their own but the ratios
#: ``cell_intensity / media_intensity`` and ``device_intensity / media_intensity``,
#: which the fit keeps while it solves the media level.
_TRANSMISSIONS = {"cell_transmission": "cell_intensity", "device_transmission": "device_intensity"}
#: The pixel fit's least squares works on ``z + _Z_OFFSET`` (z in natural scales, 0
#: at the start), so that its relative finite-difference step is ~0.02 of a scale.
_Z_OFFSET = 100.0
#: Natural scale of each parameter: the optimiser works in these units.
_SCALE = {
    "apodisation_sigma_um": 0.1,
    "defocus_sigma_um": 0.05,
    "ring_contrast": 0.1,
    "psf_offset": 0.05,
    "phase_ring_width_scale": 0.1,
    "cell_phase_rad": 0.1,
    "device_phase_rad": 0.1,
    "plate_transmission": 0.03,
    "plate_phase_rad": 0.1,
    "focus_offset_um": 0.05,
    "cell_transmission": 0.03,
    "device_transmission": 0.03,
    "gaussian_noise_sd_adu": 10.0,
    "envelope_stain_fraction": 0.1,
}
_INTENSITIES = ("cell_intensity", "media_intensity", "device_intensity")
_PHASE_AMPLITUDES = ("cell_phase_adu", "device_phase_adu")
#: Largest phase signal of a full-depth column against the media level, ``P / I_m``:
#: ``(2 sin(theta) / a) 2 pi dn depth / lambda`` with the darkest plates made
#: (intensity transmission 4 %, ``a = 0.2``), ``dn = n_cell - n_media <= 0.1`` and a
#: depth of at most 1.2 um at 0.5 um: ``10 x 1.5 = 15``.
MAX_PHASE_OVER_MEDIA = 15.0


class FitCancelled(RuntimeError):
    """Raised inside a fit when its ``cancel`` callable returns True."""


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_parameters`.

    Attributes
    ----------
    render
        Fitted render settings (intensities, kernel parameters, noise).
    terms
        ``{term: (before, after)}`` for every objective term computed.
    objective_before, objective_after
        Weighted sum of the optimised terms at the start and at the end.
    n_evaluations
        Renders of the forward model the fit used.
    weights
        The optimised terms and their weights.
    fitted
        Names of the nonlinear parameters that were free.
    residual
        ``real - synthetic`` (ADU) when the pixel term was used, else ``None``.
    message
        The optimiser's last message.
    warnings
        Plain-language problems with the result: a fitted parameter at (or within
        0.1 % of the range of) one of its bounds, a phase amplitude beyond its
        physical bound, or an objective that ended worse than it started. Empty
        when the fit is trustworthy by these checks.
    standard_errors
        Pixel term only: the standard error of every fitted nonlinear parameter
        (name -> value, in its own units), from the Fisher information ``J^T W J`` of
        the last weighted solve with the intensities solved in closed form (profiled
        out); NaN for a parameter at a bound or one the image does not determine.
        Empty with the statistics terms.
    """

    render: RenderSettings
    terms: dict[str, tuple[float, float]]
    objective_before: float
    objective_after: float
    n_evaluations: int
    weights: dict[str, float] = field(default_factory=dict)
    fitted: tuple[str, ...] = ()
    residual: np.ndarray | None = field(default=None, repr=False)
    message: str = ""
    warnings: tuple[str, ...] = ()
    standard_errors: dict[str, float] = field(default_factory=dict)

    @property
    def terms_before(self) -> dict[str, float]:
        """Term values at the starting parameters."""
        return {k: v[0] for k, v in self.terms.items()}

    @property
    def terms_after(self) -> dict[str, float]:
        """Term values at the fitted parameters."""
        return {k: v[1] for k, v in self.terms.items()}

    def report(self) -> str:
        """A small table of the terms before and after, and the fitted values."""
        lines = [f"{'term':<14}{'before':>12}{'after':>12}"]
        for name, (before, after) in self.terms.items():
            lines.append(f"{name:<14}{before:12.4g}{after:12.4g}")
        lines.append(f"{'objective':<14}{self.objective_before:12.4g}{self.objective_after:12.4g}")
        names = (*_INTENSITIES, *(_PHASE_AMPLITUDES if self.render.phase_separate else ()))
        for name in (*names, *self.fitted):
            lines.append(f"{name:<24}{_value(self.render, name):12.5g}")
        lines.append(f"evaluations: {self.n_evaluations}")
        lines.extend(f"WARNING: {w}" for w in self.warnings)
        return "\n".join(lines)


def _sharp_ring_sigma_um(microscope: Microscope) -> float:
    """Apodisation sigma whose pupil-edge softness is a tenth of the ring's half width."""
    cond = CONDENSERS[microscope.condenser]
    half = 0.5 * (cond.outer_fraction - cond.inner_fraction)
    cutoff = microscope.numerical_aperture / microscope.wavelength_um
    return 10.0 / (2 * math.pi * cutoff * half)


def parameter_bounds(
    name: str,
    microscope: Microscope,
    real_sd_adu: float = 1000.0,
    *,
    coherent: bool = False,
) -> tuple[float, float]:
    """Physical bounds of a fitted parameter.

    The apodisation sigma cannot be below the diffraction bound of eq. 13,
    ``0.9 lambda n / (2 NA)``; defocus (eq. 14) is non-negative and, for a usable
    recording, below half a micrometre. The plate's ring width is relative to the
    catalogue annulus of the condenser setting (:data:`~napari_symbac.settings.CONDENSERS`):
    makers' rings differ from it, so from half to three times (wider rings block the
    detail they are meant to pass; below half the ring would miss the direct light
    of the annulus' own source points). In the partially coherent model the
    apodisation sigma sets the softness of the pupil's and ring's edges,
    ``1 / (2 pi sigma NA / lambda)`` in pupil units; beyond the sigma at which that is
    a tenth of the ring's half width the edges are sharp and the image no longer
    changes, which is its upper bound there. ``ring_contrast`` (the coupled model,
    ``gamma = P / (I_m - I_c)``) is the ratio of phase to bright-field contrast and
    has no finite physical bound when the cells barely absorb; ``[0, 3]`` is the
    range where it stays identifiable: beyond it give the phase signal its own
    amplitudes (``RenderSettings.cell_phase_adu``), which the fit solves exactly.
    The bright-field transmissions of the partially coherent model (``B`` of eq. 3
    over the media's) are at most 1: nothing passes more light than the clear media.
    The fraction of a fluorescence stain in the cell envelope is a fraction, ``[0, 1]``.
    """
    if name == "apodisation_sigma_um":
        low = microscope.min_apodisation_sigma_um if microscope.modality == "phase" else 0.05
        if coherent:
            return (low, max(3.0, _sharp_ring_sigma_um(microscope)))
        return (low, max(3.0, 4 * low))
    if name == "defocus_sigma_um":
        return (0.0, 0.5)
    if name == "ring_contrast":
        return (0.0, 3.0)
    if name == "psf_offset":
        return (-0.5, 0.5)
    if name == "phase_ring_width_scale":
        return (0.5, 3.0)
    if name in ("cell_phase_rad", "device_phase_rad"):
        # 2 pi dn depth / lambda: dn <= 0.1 (cells in water; PDMS 1.41 vs 1.333
        # is 0.08), depth <= 1.5 um, lambda >= 0.45 um.
        return (0.0, 2.1)
    if name == "plate_transmission":
        # Intensity transmission of the ring: the darkest commercial plates pass
        # ~3 %, an unattenuated ring (pure phase plate) 100 %.
        return (0.02, 1.0)
    if name == "plate_phase_rad":
        # lambda/4 plates: pi/2 at the design wavelength, ~ +-50 % across the
        # visible band.
        return (math.pi / 4, 3 * math.pi / 4)
    if name == "focus_offset_um":
        # Two axial depths of field, 2 lambda n / NA^2 each way (0.8 um at NA 1.45,
        # 0.55 um, oil): further out a cell is a ring, not a recording one would fit.
        reach = 2 * microscope.wavelength_um * microscope.refractive_index
        return (-reach / microscope.numerical_aperture**2, reach / microscope.numerical_aperture**2)
    if name in _TRANSMISSIONS:
        # B of eq. 3 over the media's: no sample passes more light than the clear
        # media beside it; below 0.2 a cell would look dark in bright field.
        return (0.2, 1.0)
    if name == "gaussian_noise_sd_adu":
        return (0.0, max(5 * real_sd_adu, 1.0))
    if name == "envelope_stain_fraction":
        if microscope.modality != "fluorescence":
            raise ValueError(
                "envelope_stain_fraction is where a fluorescence stain sits in the cells: "
                "fit it on a fluorescence image, not a phase-contrast one"
            )
        return (0.0, 1.0)
    raise ValueError(f"cannot fit {name!r}; fittable parameters are {', '.join(_FITTABLE)}")


def _refuse_phase_only(names: tuple[str, ...]) -> None:
    """Refuse, in fluorescence, the named parameters that :func:`fit_parameters` does not
    fit there (the phase kernel's, and the envelope stain, which it does not draw)."""
    unfit = [n for n in names if n not in _FLUORESCENCE_FITTABLE]
    if not unfit:
        return
    fix = (
        "; fit envelope_stain_fraction with the scene (fit_scene(..., fit_optics="
        "ENVELOPE_FIT_OPTICS), or `napari-symbac fit --envelope-stain`)"
        if "envelope_stain_fraction" in unfit
        else ""
    )
    raise ValueError(
        f"in fluorescence fit_parameters fits only {' and '.join(_FLUORESCENCE_FITTABLE)}; "
        f"drop {', '.join(unfit)} from fit{fix}"
    )


def scene_classes(scene: Any) -> np.ndarray:
    """Class map (:data:`~napari_symbac.fit.CLASS_VALUES`) of a scene at camera resolution.

    Cells are the pixels of :meth:`Scene.camera_labels`; device the remaining pixels
    that are mostly PDMS; media the rest.
    """
    cell = scene.camera_labels() > 0
    device = block_average(scene.interior(scene.device), scene.upsample) > 0.5
    out = np.full(scene.camera_shape, CLASS_VALUES["media"], np.int64)
    out[device] = CLASS_VALUES["device"]
    out[cell] = CLASS_VALUES["cell"]
    return out


def _variance(clean_adu: np.ndarray, render: RenderSettings, camera: Camera) -> np.ndarray:
    """Per-pixel noise variance (ADU^2) of the camera stage for a clean image (eq. 17)."""
    if render.noise_model == "camera":
        s = camera.sensitivity_adu_per_e
        return s * np.maximum(clean_adu, 0.0) + (s * camera.dark_noise_e) ** 2 + 1 / 12
    if render.noise_model == "gaussian":
        return np.full(clean_adu.shape, render.gaussian_noise_sd_adu**2 + 1 / 12)
    return np.full(clean_adu.shape, 1 / 12)


class _Budget:
    def __init__(self, total: int, progress: Progress | None, cancel: Cancel | None) -> None:
        self.total = total
        self.done = 0
        self.progress = progress
        self.cancel = cancel

    def tick(self) -> None:
        if self.cancel is not None and self.cancel():
            raise FitCancelled("fit cancelled")
        self.done += 1
        if self.progress is not None:
            self.progress(min(self.done, self.total), self.total)


def _nnls(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Non-negative least squares that tolerates all-zero columns."""
    use = np.any(a != 0, axis=0)
    x = np.zeros(a.shape[1])
    if use.any():
        x[use] = optimize.nnls(a[:, use], b, maxiter=50 * a.shape[1])[0]
    return x


def _value(render: RenderSettings, name: str) -> float:
    """A fitted parameter's value: a render setting or a bright-field transmission."""
    if name in _TRANSMISSIONS:
        return float(getattr(render, _TRANSMISSIONS[name])) / render.media_intensity
    return float(getattr(render, name) or 0.0)


def _render_with(render: RenderSettings, names: tuple[str, ...], z: np.ndarray, start) -> Any:
    values = {n: float(start[n] + _SCALE[n] * zi) for n, zi in zip(names, z)}
    for name, intensity in _TRANSMISSIONS.items():
        if name in values:
            values[intensity] = values.pop(name) * render.media_intensity
    return dataclasses.replace(render, **values)


def with_media_level(render: RenderSettings, media_adu: float) -> RenderSettings:
    """``render`` of the partially coherent model with the media level ``media_adu``: it
    scales the image; the cells' and device's bright-field transmission (their
    intensities' ratios to the media's) stay as they were."""
    scale = media_adu / render.media_intensity
    return dataclasses.replace(
        render,
        cell_intensity=render.cell_intensity * scale,
        media_intensity=media_adu,
        device_intensity=render.device_intensity * scale,
    )


def fit_parameters(
    real_image: np.ndarray,
    labels: np.ndarray,
    scene: Any,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera | None = None,
    *,
    terms: tuple[str, ...] | Mapping[str, float] | None = None,
    fit: tuple[str, ...] | None = None,
    rng: np.random.Generator | None = None,
    progress: Progress | None = None,
    cancel: Cancel | None = None,
    max_evaluations: int = 400,
    global_search: bool = True,
    model: ForwardModel | None = None,
) -> FitResult:
    """Fit intensities, apodisation, defocus, ring contrast, PSF offset and noise.

    Parameters
    ----------
    real_image
        One 2D frame of the real recording (ADU, camera baseline included).
    labels
        Painted class map of ``real_image`` (1 = cell, 2 = media, 3 = device, 0 =
        unpainted); rough strokes suffice for the statistics terms.
    scene
        A synthetic :class:`~napari_symbac.scene.Scene`. With the statistics terms it
        may be any scene of the same kind of sample; with ``terms=("pixel",)`` it must
        reproduce the real image pixel for pixel (e.g. from :func:`fit_scene`).
    microscope, render, camera
        The starting model; ``render`` gives the starting values.
    terms
        Objective terms and weights (names of :data:`~napari_symbac.fit.objectives.TERM_NAMES`).
        Default :data:`~napari_symbac.fit.objectives.DEFAULT_TERMS`. ``("pixel",)`` fits
        the image pixel by pixel, by iteratively reweighted least squares with the
        camera's variance (eq. 17) held fixed in each round.
    fit
        Nonlinear parameters to fit; the intensities are always solved exactly
        (with ``render.cell_phase_adu`` / ``device_phase_adu`` set, the phase
        amplitudes too, in the pixel fit). Default :data:`DEFAULT_FIT` with the pixel
        term, else :data:`DEFAULT_FIT_STATISTICS`; with
        ``render.phase_model="partially_coherent"``
        :data:`DEFAULT_FIT_PARTIALLY_COHERENT`, and there the media level is the one
        linear amplitude (the cells' and device's bright-field transmission, their
        intensities over the media's, stay as given unless ``cell_transmission`` /
        ``device_transmission`` are named here; they are ~1 for unstained cells and
        clear PDMS, not the intensities of a linear fit: docs/physics.md).
        ``gaussian_noise_sd_adu`` is added when ``render.noise_model == "gaussian"``.
    rng
        Generator for the fixed noise field of the statistics terms (common random
        numbers keep the objective deterministic); default ``default_rng(0)``.
    progress
        ``progress(done, total)`` after every render.
    cancel
        Checked before every render; when it returns True the fit raises
        :class:`FitCancelled`.
    max_evaluations
        Budget of renders for the whole fit.
    global_search
        Start with a coarse grid over apodisation x defocus (the landscape has local
        minima in those two) before the local optimiser.
    model
        A forward model to reuse (its convolution cache is shared); built from
        ``microscope``, ``render``, ``camera`` when omitted.

    Returns
    -------
    FitResult
        With :attr:`FitResult.warnings` naming any parameter that ended at a bound
        and an objective that ended worse than it started.
    """
    camera = Camera() if camera is None else camera
    real = as_single_image(real_image, name="real_image")
    weights = dict(DEFAULT_TERMS) if terms is None else _weights(terms)
    pixel_mode = "pixel" in weights
    if pixel_mode and tuple(scene.camera_shape) != real.shape:
        raise ValueError(
            f"the pixel term compares images pixel by pixel, but the scene's camera shape "
            f"{tuple(scene.camera_shape)} differs from the image's {real.shape}: fit the scene "
            "first (fit_scene) or use the statistics terms"
        )
    has_device = bool(np.any(scene_classes(scene) == CLASS_VALUES["device"]))
    required = ("cell", "media", "device") if has_device and not pixel_mode else ("cell", "media")
    if pixel_mode and labels is None:
        labels = scene_classes(scene)
    real_classes = as_label_stack(labels, (1, *real.shape), required=required)[0]
    fit_named = fit is not None
    if fit is None:
        if microscope.modality == "phase" and render.phase_model == "partially_coherent":
            fit = DEFAULT_FIT_PARTIALLY_COHERENT
        else:
            fit = DEFAULT_FIT if pixel_mode else DEFAULT_FIT_STATISTICS
    names = tuple(dict.fromkeys(fit))
    if render.noise_model == "gaussian" and not pixel_mode:
        names = (*names, "gaussian_noise_sd_adu") if "gaussian_noise_sd_adu" not in names else names
    for n in names:
        parameter_bounds(n, microscope)  # validates the name
    coherent = microscope.modality == "phase" and render.phase_model == "partially_coherent"
    if not coherent and any(n in _TRANSMISSIONS for n in names):
        raise ValueError(
            "cell_transmission and device_transmission are parameters of the partially "
            "coherent phase model: set RenderSettings(phase_model='partially_coherent') or "
            "drop them from fit (the linear model solves the intensities exactly)"
        )
    if microscope.modality != "phase":
        if fit_named:
            _refuse_phase_only(names)
        names = tuple(n for n in names if n in _FLUORESCENCE_FITTABLE)
    rng = np.random.default_rng(0) if rng is None else rng
    base = ForwardModel(microscope, render, camera) if model is None else model.with_render(render)
    budget = _Budget(max_evaluations, progress, cancel)
    syn_classes = scene_classes(scene)
    real_sd = float(real.std())
    start = {n: _value(render, n) for n in names}
    bounds = [
        parameter_bounds(
            n, microscope, real_sd, coherent=render.phase_model == "partially_coherent"
        )
        for n in names
    ]
    for n, (lo, hi) in zip(names, bounds):
        start[n] = float(np.clip(start[n], lo, hi))
    z_lo = np.array([(lo - start[n]) / _SCALE[n] for n, (lo, _) in zip(names, bounds)])
    z_hi = np.array([(hi - start[n]) / _SCALE[n] for n, (_, hi) in zip(names, bounds)])
    y = real - camera.baseline_adu
    noise_z = rng.standard_normal(scene.camera_shape)
    real_masks_for_terms = (real_classes, syn_classes)

    separate = microscope.modality == "phase" and render.phase_separate and not coherent
    if coherent:
        amplitude_names: tuple[str, ...] = ("media_intensity",)
    else:
        amplitude_names = (*_INTENSITIES, *(_PHASE_AMPLITUDES if separate else ()))
    n_amp = len(amplitude_names)
    n_solved = 1 if coherent else 3  # solved by the class means; the rest kept

    def components(r: RenderSettings) -> np.ndarray:
        budget.tick()
        if coherent:
            return base.with_render(r).phase_image(scene)[None]
        comps = base.with_render(r).components(scene)
        parts = [comps["cells"], comps["media"], comps["device"]]
        if separate:
            parts += [-comps["cells_phase"], -comps["device_phase"]]
        return np.stack(parts).astype(np.float64)

    def amplitudes(r: RenderSettings) -> np.ndarray:
        if coherent:
            return np.array([r.media_intensity], np.float64)
        values = [getattr(r, k) for k in _INTENSITIES]
        if separate:
            values += list(r.phase_amplitudes())
        return np.array(values, np.float64)

    def solve_class_means(a: np.ndarray, r: RenderSettings) -> np.ndarray:
        # Class means pin the three intensities; the phase amplitudes (if separate)
        # stay at their values, their image subtracted from the target.
        fixed = amplitudes(r)[n_solved:]
        rows, rhs = [], []
        for _cname, value in CLASS_VALUES.items():
            rmask = real_classes == value
            smask = syn_classes == value
            if rmask.any() and smask.any():
                means = a[:, smask].mean(axis=1)
                rows.append(means[:n_solved])
                rhs.append(real[rmask].mean() - camera.baseline_adu - means[n_solved:] @ fixed)
        return np.concatenate([_nnls(np.array(rows), np.array(rhs)), fixed])

    def with_intensities(r: RenderSettings, intens: np.ndarray) -> RenderSettings:
        if coherent:
            return with_media_level(r, float(intens[0]))
        return dataclasses.replace(r, **{k: float(v) for k, v in zip(amplitude_names, intens)})

    def synthetic(r: RenderSettings, a: np.ndarray, noisy: bool) -> np.ndarray:
        clean = np.tensordot(amplitudes(r), a, axes=1)
        if not noisy:
            return clean + camera.baseline_adu
        var = _variance(clean, r, camera)
        return clean + camera.baseline_adu + np.sqrt(var) * noise_z

    def all_terms(r: RenderSettings, a: np.ndarray, var: np.ndarray | None) -> dict[str, float]:
        stats = tuple(t for t in TERM_NAMES if t != "pixel")
        out = objective_terms(synthetic(r, a, True), real, real_masks_for_terms, terms=stats)
        if pixel_mode:
            out.update(
                objective_terms(
                    synthetic(r, a, False), real, real_classes, terms=("pixel",), variance=var
                )
            )
        return out

    a0 = components(render)
    clean0 = np.tensordot(amplitudes(render), a0, axes=1)
    var0 = _variance(clean0, render, camera) if pixel_mode else None
    terms_before = all_terms(render, a0, var0)
    message = ""

    if pixel_mode:
        # IRLS: the variance is held fixed within each weighted solve, then updated; the
        # first round's from each pixel's 3 x 3 neighbourhood, as the scene fit's.
        level = expected_level(y, np.ones(y.shape, bool)).reshape(y.shape)
        var = _variance(level, render, camera)
        z = np.zeros(len(names))
        jacobian = None
        current = render
        for round_index in range(3):
            sw = 1 / np.sqrt(var).ravel()

            def residual(zz: np.ndarray, sw: np.ndarray = sw) -> np.ndarray:
                r = _render_with(render, names, zz, start)
                a = components(r).reshape(n_amp, -1).T
                intens = _nnls(a * sw[:, None], y.ravel() * sw)
                return (y.ravel() - a @ intens) * sw

            if names and budget.done < budget.total:
                if round_index == 0 and global_search:
                    z = _grid_start(
                        names, z, start, bounds, lambda zz: float(np.sum(residual(zz) ** 2))
                    )
                remaining = max(budget.total - budget.done, 2 * len(names) + 2)
                sol = scaled_least_squares(
                    lambda zz, sw=sw: residual(zz, sw),
                    z,
                    (z_lo, z_hi),
                    max(remaining // (len(names) + 1), 3),
                )
                z = sol.x
                message = str(sol.message)
                jacobian = sol.jac
            current = _render_with(render, names, z, start)
            a = components(current)
            am = a.reshape(n_amp, -1).T
            intens = _nnls(am * sw[:, None], y.ravel() * sw)
            current = with_intensities(current, intens)
            clean = (am @ intens).reshape(real.shape)
            if render.noise_model == "gaussian":
                # The noise of the recording, not the model's misfit: a robust
                # estimate from pixel-to-pixel differences (smooth misfit cancels).
                sd = measured_noise_sd_adu(real)
                current = dataclasses.replace(current, gaussian_noise_sd_adu=sd)
            var = _variance(clean, current, camera)
        final = current
        a_final = components(final)
        terms_after = all_terms(final, a_final, var)
        # before and after weighed with one variance, so they compare
        terms_before = all_terms(render, a0, var)
        residual_image = (real - synthetic(final, a_final, False)).astype(np.float32)
        errors = _standard_errors(names, jacobian, z, z_lo, z_hi)
    else:

        def scalar(zz: np.ndarray) -> float:
            zz = np.clip(zz, z_lo, z_hi)
            r = _render_with(render, names, zz, start)
            a = components(r)
            r = with_intensities(r, solve_class_means(a, r))
            t = objective_terms(
                synthetic(r, a, True), real, real_masks_for_terms, terms=tuple(weights)
            )
            return total_objective(t, weights)

        z = np.zeros(len(names))
        if names:
            if global_search:
                z = _grid_start(names, z, start, bounds, scalar)
            remaining = max(budget.total - budget.done - 2, 10)
            sol = optimize.minimize(
                scalar,
                z,
                method="Powell",
                bounds=list(zip(z_lo, z_hi)),
                options={"maxfev": remaining, "xtol": 1e-3, "ftol": 1e-6},
            )
            z = np.clip(sol.x, z_lo, z_hi)
            message = str(sol.message)
        final = _render_with(render, names, z, start)
        a_final = components(final)
        final = with_intensities(final, solve_class_means(a_final, final))
        terms_after = all_terms(final, a_final, None)
        residual_image = None
        errors = {}

    terms_table = {k: (terms_before[k], terms_after[k]) for k in terms_after}
    if progress is not None:  # the fit may end well within its bound; Powell's line
        # searches may pass it by a few renders, which the bar does not count (found as
        # a user: "40 of at most 40 steps", then "47 of at most 47")
        ended = min(budget.done, budget.total)
        progress(ended, ended)
    objective_before = total_objective(terms_before, weights)
    objective_after = total_objective(terms_after, weights)
    return FitResult(
        render=final,
        terms=terms_table,
        objective_before=objective_before,
        objective_after=objective_after,
        warnings=fit_warnings(
            final, names, bounds, objective_before, objective_after, separate=separate
        ),
        n_evaluations=budget.done,
        weights=weights,
        fitted=names,
        residual=residual_image,
        message=message,
        standard_errors=errors,
    )


def scaled_least_squares(
    residual: Callable[[np.ndarray], np.ndarray],
    z: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    max_nfev: int,
) -> optimize.OptimizeResult:
    """Bounded least squares of ``residual(z)``, z in the parameters' natural scales
    (:data:`_SCALE`), starting at ``z`` (clipped to ``bounds``).

    scipy's ``diff_step`` is relative to ``|x|`` and falls back to 1.5e-8 at ``x = 0``
    (every start): the solver works on ``z + _Z_OFFSET`` so that its finite differences
    step ~0.02 of a scale everywhere. Returns scipy's result with ``x`` in ``z`` units
    (``jac`` is ``d residual / d z`` either way).
    """
    z_lo, z_hi = bounds
    sol = optimize.least_squares(
        lambda w: residual(w - _Z_OFFSET),
        np.clip(z, z_lo, z_hi) + _Z_OFFSET,
        bounds=(z_lo + _Z_OFFSET, z_hi + _Z_OFFSET),
        diff_step=0.02 / _Z_OFFSET,
        x_scale=1.0,
        xtol=1e-8,
        ftol=1e-9,
        max_nfev=max_nfev,
    )
    sol.x = sol.x - _Z_OFFSET
    return sol


def _standard_errors(
    names: tuple[str, ...],
    jacobian: np.ndarray | None,
    z: np.ndarray,
    z_lo: np.ndarray,
    z_hi: np.ndarray,
) -> dict[str, float]:
    """Standard errors of the pixel fit's nonlinear parameters (``FitResult``).

    ``jacobian`` is the last weighted solve's ``d r / d z`` (``r`` the residual over the
    camera's standard deviation, the intensities solved inside it), so ``J^T J`` is the
    Fisher information of ``z``; a parameter is ``start + _SCALE * z``. Parameters
    within 0.1 % of their range of a bound are left out of the inversion (NaN).
    """
    errors = dict.fromkeys(names, math.nan)
    if jacobian is None or not names:
        return errors
    margin = 1e-3 * (z_hi - z_lo)
    free = (z > z_lo + margin) & (z < z_hi - margin)
    info = np.asarray(jacobian, float).T @ np.asarray(jacobian, float)
    sub = info[np.ix_(free, free)]
    if not free.any() or np.linalg.cond(sub) > 1e12:
        return errors
    variances = np.diag(np.linalg.inv(sub))
    for name, variance in zip(np.array(names)[free], variances):
        if variance > 0:
            errors[str(name)] = float(_SCALE[str(name)] * math.sqrt(variance))
    return errors


def fit_warnings(
    render: RenderSettings,
    names: tuple[str, ...],
    bounds: list[tuple[float, float]],
    objective_before: float,
    objective_after: float,
    *,
    separate: bool = False,
) -> tuple[str, ...]:
    """Warnings about a fitted result (see :attr:`FitResult.warnings`).

    Parameters
    ----------
    render
        The fitted settings.
    names, bounds
        The free nonlinear parameters and their bounds.
    objective_before, objective_after
        The objective at the start and at the end.
    separate
        Whether the phase amplitudes were fitted (checked against
        :data:`MAX_PHASE_OVER_MEDIA`).
    """
    out = []
    for name, (lo, hi) in zip(names, bounds):
        value = _value(render, name)
        tol = 1e-3 * (hi - lo)
        side = "lower" if value <= lo + tol else "upper" if value >= hi - tol else None
        if side is not None:
            bound = lo if side == "lower" else hi
            out.append(
                f"{name} = {value:.4g} ended at its {side} bound ({bound:.4g}): the model "
                "cannot reach the image inside its physical range there (check the "
                "scene, the microscope settings and the labels)"
            )
    if separate and render.media_intensity > 0:
        for name, value in zip(_PHASE_AMPLITUDES, render.phase_amplitudes()):
            ratio = value / render.media_intensity
            if ratio > MAX_PHASE_OVER_MEDIA:
                out.append(
                    f"{name} = {value:.4g} ADU is {ratio:.1f} x the media level, beyond the "
                    f"physical bound {MAX_PHASE_OVER_MEDIA:g} (plate transmission >= 4 %, "
                    "n_cell - n_media <= 0.1)"
                )
    if np.isfinite(objective_before) and objective_after > objective_before * (1 + 1e-9):
        out.append(
            f"the fit ended worse than its start (objective {objective_before:.4g} -> "
            f"{objective_after:.4g}): keep the starting settings or give a better start"
        )
    return tuple(out)


def _weights(terms: tuple[str, ...] | Mapping[str, float]) -> dict[str, float]:
    weights = dict(terms) if isinstance(terms, Mapping) else dict.fromkeys(terms, 1.0)
    unknown = sorted(set(weights) - set(TERM_NAMES))
    if unknown:
        raise ValueError(f"unknown objective term(s) {unknown}; choose from {TERM_NAMES}")
    if not weights:
        raise ValueError("terms must name at least one objective term")
    for name, w in weights.items():
        if not (math.isfinite(w) and w >= 0):
            raise ValueError(f"the weight of {name!r} must be zero or positive, got {w!r}")
    return weights


def _grid_start(
    names: tuple[str, ...],
    z: np.ndarray,
    start: Mapping[str, float],
    bounds: list[tuple[float, float]],
    cost: Callable[[np.ndarray], float],
) -> np.ndarray:
    """Global step: a coarse grid over apodisation x defocus, others at their start.

    Apodisation takes 5 log-spaced values from the eq. 13 bound to 4x the bound,
    defocus 0, 0.1, 0.2 and 0.35 um; the best grid point (or the start, if better)
    is returned in the optimiser's scaled units.
    """
    axes = []
    for name in ("apodisation_sigma_um", "defocus_sigma_um"):
        if name in names:
            i = names.index(name)
            lo, hi = bounds[i]
            if name == "apodisation_sigma_um":
                values = np.geomspace(lo * 1.02, min(4 * lo, hi), 5)
            else:
                values = np.array([0.0, 0.1, 0.2, 0.35])
            values = np.clip(values, lo, hi)
            axes.append((i, (values - start[name]) / _SCALE[name]))
    if not axes:
        return z
    best, best_cost = z.copy(), cost(z)
    grids = np.meshgrid(*[values for _, values in axes], indexing="ij")
    for point in zip(*(g.ravel() for g in grids)):
        trial = z.copy()
        for (i, _), value in zip(axes, point):
            trial[i] = value
        c = cost(trial)
        if c < best_cost:
            best, best_cost = trial, c
    return best
