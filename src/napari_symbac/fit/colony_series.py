"""A time-lapse of a phase colony with its masks: optics fitted jointly, cells tracked.

:func:`fit_colony` fits the partially coherent optics to one frame drawn from its
masks. In a time-lapse the optics are the microscope's and do not change between
frames, so :func:`fit_colony_series` fits them to all frames together: first alone on
the frame whose masks cover the most pixels (the most cells, edges and halo: the most
information; its global start), then jointly, by least squares over every frame's
pixels, each frame weighed by its own noise and drawn with its own media level (the lamp
may drift), solved in closed form inside the fit. The standard errors come from the
joint Fisher information. Each frame's cells are its masks';
:func:`~napari_symbac.fit.link_cells` links them into tracks and a lineage as in
:func:`~napari_symbac.fit.fit_series`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from napari_symbac.fit.colony import ColonyFit, colony_start, fit_colony
from napari_symbac.fit.lineage import Lineage, LinkSettings, link_cells
from napari_symbac.fit.start import cut_by_edge
from napari_symbac.settings import Camera, Microscope, RenderSettings

__all__ = ["ColonySeriesFit", "fit_colony_series"]


@dataclass(frozen=True)
class ColonySeriesFit:
    """Outcome of :func:`fit_colony_series`.

    Attributes
    ----------
    frames
        One :class:`~napari_symbac.fit.ColonyFit` per frame, in time order, each drawn
        with the jointly fitted optics and its own media level; their parameters and
        standard errors are the joint fit's (the media level each frame's own).
    reference
        Index in ``frames`` of the frame whose fit alone started the joint fit.
    joint_objective
        The reduced pixel chi-square over all frames' pixels (each over its own noise)
        at the start of the joint fit (the reference frame's optics) and at its end.
    lineage
        The masks' cells linked into tracks (:class:`~napari_symbac.fit.Lineage`):
        ``lineage.track_ids[t]`` is the track of each cell of ``frames[t].cells``.
    """

    frames: tuple[ColonyFit, ...]
    reference: int
    lineage: Lineage = field(repr=False)
    joint_objective: tuple[float, float] = (math.nan, math.nan)

    @property
    def render(self) -> RenderSettings:
        """The shared optics (with the reference frame's media level)."""
        return self.frames[self.reference].render

    @property
    def warnings(self) -> tuple[str, ...]:
        """The joint fit's warnings (a parameter at a bound, a fit worse than its start)."""
        return self.frames[self.reference].warnings

    @property
    def camera(self) -> Camera:
        """The camera of the likelihood (baseline and bit depth), shared."""
        return self.frames[self.reference].camera

    def shared(self) -> dict[str, tuple[float, float]]:
        """The shared optics: ``{name: (value, standard error)}`` from the joint fit
        (the media level is each frame's own and is left out)."""
        fit = self.frames[self.reference]
        return {
            name: (float(value), float(se))
            for name, value, se in zip(
                fit.parameter_names, fit.parameters, fit.standard_errors, strict=True
            )
            if name != "media_intensity"
        }

    def media_levels(self) -> np.ndarray:
        """Each frame's fitted media level (ADU above the baseline)."""
        return np.array([fit.render.media_intensity for fit in self.frames])


@dataclass(frozen=True)
class _Frame:
    """One frame ready for the joint fit: the checked image, its masks' scene and the
    starting optics of :func:`~napari_symbac.fit.colony.colony_start`, its noise."""

    real: np.ndarray
    masks: np.ndarray
    scene: Any
    start: RenderSettings
    noise_sd_adu: float  # measured on the frame (the render's noise)

    @property
    def sd_adu(self) -> float:
        """The likelihood's pixel s.d.: the measured noise and quantisation, as
        :func:`~napari_symbac.fit.fit_colony`'s."""
        return math.sqrt(self.noise_sd_adu**2 + 1 / 12)

    @classmethod
    def of(cls, image: np.ndarray, microscope: Microscope, masks: np.ndarray, camera: Camera):
        from napari_symbac.fit.colony import checked_colony_frame
        from napari_symbac.fit.objectives import measured_noise_sd_adu

        real, masks, camera, noise = checked_colony_frame(image, microscope, masks, camera)
        start, scene = colony_start(masks, microscope, float(np.percentile(real, 50)), noise)
        return cls(real, masks, scene, start, measured_noise_sd_adu(real))


def _media_level(unit: np.ndarray, y: np.ndarray) -> float:
    """The media level that draws ``y`` best as ``level * unit``: least squares (uniform
    Gaussian noise), at least 0, as :func:`~napari_symbac.fit.fit_colony`'s NNLS."""
    return max(float(np.sum(unit * y) / np.sum(unit * unit)), 0.0)


def _joint_optics(
    frames: list[_Frame],
    microscope: Microscope,
    camera: Camera,
    optics: ColonyFit,
    max_evaluations: int,
    tick: Callable[[], None],
) -> tuple[ColonyFit, tuple[float, float]]:
    """The optics that ``optics`` fitted on one frame, refined on all ``frames`` at once.

    Least squares over the frames' pixels, each over its noise, each frame's media level
    solved in closed form at every step (profiled out); ``max_evaluations`` evaluations
    of all frames (finite differences counted), ``tick()`` after every render. Returns
    ``optics`` with the joint values, standard errors (the stacked residuals' Jacobian:
    the summed Fisher information), warnings and bounds, and the reduced chi-square over
    all frames' pixels before and after.
    """
    from napari_symbac.fit.parameters import (
        _SCALE,
        _render_with,
        _standard_errors,
        fit_warnings,
        parameter_bounds,
        scaled_least_squares,
    )
    from napari_symbac.optics import ForwardModel

    names = tuple(n for n in optics.parameter_names if n != "media_intensity")
    start = dict(zip(names, (float(v) for v in optics.parameters)))
    bounds = [parameter_bounds(n, microscope, coherent=True) for n in names]
    z_lo = np.array([(lo - start[n]) / _SCALE[n] for n, (lo, _) in zip(names, bounds)])
    z_hi = np.array([(hi - start[n]) / _SCALE[n] for n, (_, hi) in zip(names, bounds)])
    targets = [(f.real - camera.baseline_adu).ravel() for f in frames]
    first: list[float] = []  # the chi-square at the start: least squares' first call

    def residual(z: np.ndarray) -> np.ndarray:
        render = _render_with(optics.render, names, z, start)
        model = ForwardModel(microscope, render, camera)
        parts = []
        for frame, y in zip(frames, targets, strict=True):
            tick()
            unit = model.phase_image(frame.scene).ravel()
            parts.append((y - _media_level(unit, y) * unit) / frame.sd_adu)
        out = np.concatenate(parts)
        if not first:
            first.append(chi2(out))
        return out

    def chi2(r: np.ndarray) -> float:
        return float(r @ r) / r.size

    sol = scaled_least_squares(
        residual,
        np.zeros(len(names)),
        (z_lo, z_hi),
        max(max_evaluations // (len(names) + 1), 1),
    )
    z = sol.x
    before, after = first[0], chi2(sol.fun)
    render = _render_with(optics.render, names, z, start)
    errors = _standard_errors(names, sol.jac, z, z_lo, z_hi)
    warnings = fit_warnings(render, names, bounds, before, after)
    values = [start[n] + _SCALE[n] * zi for n, zi in zip(names, z)]
    joint = dataclasses.replace(
        optics,
        render=render,
        parameters=np.array([*values, optics.parameters[-1]]),
        standard_errors=np.array([errors[n] for n in names] + [math.nan]),
        warnings=warnings,
        at_bounds=tuple(n for n in names if any(w.startswith(f"{n} =") for w in warnings)),
    )
    return joint, (before, after)


def _drawn_with(frame: _Frame, microscope: Microscope, optics: ColonyFit) -> ColonyFit:
    """``frame`` drawn from its masks with ``optics``' (shared) optics and its own media
    level, read as :func:`fit_colony`'s result: the shared values, standard errors and
    warnings, this frame's level (standard error NaN, as there), the pixel term before
    (:func:`~napari_symbac.fit.colony.colony_start`'s optics) and after, both weighed with
    this frame's noise. Two renders."""
    from napari_symbac.fit.colony import colony_result, rendered_start
    from napari_symbac.fit.objectives import objective_terms
    from napari_symbac.fit.parameters import scene_classes, with_media_level
    from napari_symbac.optics import ForwardModel

    camera = optics.camera
    y = frame.real - camera.baseline_adu
    unit = ForwardModel(microscope, optics.render, camera).phase_image(frame.scene)
    media = _media_level(unit, y)
    render = dataclasses.replace(
        with_media_level(optics.render, media),
        gaussian_noise_sd_adu=frame.noise_sd_adu,
    )
    synthetic = media * unit + camera.baseline_adu
    before = rendered_start(microscope, frame.start, camera, frame.scene)
    classes = scene_classes(frame.scene)

    def pixel_term(model: np.ndarray) -> float:
        terms = objective_terms(
            model, frame.real, classes, terms=("pixel",), variance=frame.sd_adu**2
        )
        return float(terms["pixel"])

    return colony_result(
        frame.real,
        frame.masks,
        microscope,
        camera,
        frame.scene,
        render,
        synthetic=synthetic,
        before=before,
        objective=(pixel_term(before), pixel_term(synthetic)),
        parameter_names=optics.parameter_names,
        parameters=np.array([*optics.parameters[:-1], media]),
        standard_errors=optics.standard_errors,
        warnings=optics.warnings,
        at_bounds=optics.at_bounds,
        n_evaluations=2,
    )


def fit_colony_series(
    stack: np.ndarray | Sequence[np.ndarray],
    microscope: Microscope,
    masks: np.ndarray | Sequence[np.ndarray],
    camera: Camera | None = None,
    *,
    max_evaluations: int = 40,
    joint_evaluations: int = 16,
    linking: LinkSettings | None = None,
    progress: Any = None,
    cancel: Any = None,
) -> ColonySeriesFit:
    """Fit a ``(T, Y, X)`` phase-colony time-lapse drawn from its masks (module notes).

    Parameters
    ----------
    stack
        The frames in time order (ADU).
    microscope
        Pixel size, wavelength, numerical aperture; modality phase.
    masks
        Instance masks of each frame (``(T, Y, X)``, 0 background); the labels need not
        be tracked: the tracks come from :func:`~napari_symbac.fit.link_cells`.
    camera
        Its baseline and bit depth; default baseline 0 and the images' bit depth.
    max_evaluations
        Renders of the optics fit on the reference frame alone.
    joint_evaluations
        Evaluations of every frame in the joint fit (finite differences included: each
        is ``T`` renders).
    linking
        :class:`~napari_symbac.fit.LinkSettings` of the tracking (default its defaults).
    progress, cancel
        As :func:`~napari_symbac.fit.fit_colony`; ``progress(done, total)`` counts the
        renders: the reference frame's fit, the joint fit's, then two per frame.

    Raises
    ------
    ValueError
        Fewer than two frames, as many masks as frames not given, or what
        :func:`~napari_symbac.fit.fit_colony` refuses.
    """
    from napari_symbac.fit.parameters import FitCancelled

    images = [np.asarray(frame) for frame in stack]
    all_masks = [np.asarray(m) for m in masks]
    if len(images) < 2:
        raise ValueError("fit_colony_series fits a time-lapse of at least 2 frames: use fit_colony")
    if len(all_masks) != len(images):
        raise ValueError(
            f"{len(all_masks)} masks for {len(images)} frames: give each frame its masks"
        )
    covered = [int(np.count_nonzero(m)) for m in all_masks]
    reference = int(np.argmax(covered))
    n_frames = len(images)
    total = max_evaluations + (joint_evaluations + 2) * n_frames
    done = 0

    def tick() -> None:
        nonlocal done
        if cancel is not None and cancel():
            raise FitCancelled("fit cancelled")
        done += 1
        if progress is not None:
            progress(min(done, total), total)

    def optics_progress(renders: int, _total: int) -> None:
        nonlocal done
        done = min(renders, max_evaluations)
        if progress is not None:
            progress(done, total)

    optics = fit_colony(
        images[reference],
        microscope,
        all_masks[reference],
        camera,
        max_evaluations=max_evaluations,
        cell_gains=False,  # the frames' cells are drawn again below, without gains
        progress=optics_progress,
        cancel=cancel,
    )
    frames = [_Frame.of(i, microscope, m, optics.camera) for i, m in zip(images, all_masks)]
    joint, objective = _joint_optics(
        frames, microscope, optics.camera, optics, joint_evaluations, tick
    )
    fits = []
    for frame in frames:
        fits.append(_drawn_with(frame, microscope, joint))
        tick()
        tick()
    if progress is not None:
        progress(done, done)  # the fits may converge well within their bound
    height, width = images[0].shape
    pixel_um = microscope.pixel_size_um
    lineage = link_cells(
        [fit.cells for fit in fits],
        linking,
        image_size_um=(height * pixel_um, width * pixel_um),
        cut_by_edge=[cut_by_edge(f.masks, fit.cells.ids) for f, fit in zip(frames, fits)],
    )
    return ColonySeriesFit(
        frames=tuple(fits), reference=reference, lineage=lineage, joint_objective=objective
    )
