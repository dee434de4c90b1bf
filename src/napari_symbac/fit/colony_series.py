"""A time-lapse of a phase colony with its masks: optics shared, cells tracked.

:func:`fit_colony` fits the partially coherent optics to one frame drawn from its
masks. In a time-lapse the optics are the microscope's and do not change between
frames, so :func:`fit_colony_series` fits them once, on the frame whose masks cover the
most pixels (the most cells, edges and halo: the most information), and draws every
other frame through them with its own media level (the lamp may drift), solved in
closed form. Each frame's cells are its masks'; :func:`~napari_symbac.fit.link_cells`
links them into tracks and a lineage as in :func:`~napari_symbac.fit.fit_series`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from napari_symbac.fit.colony import ColonyFit, colony_start, fit_colony
from napari_symbac.fit.lineage import Lineage, LinkSettings, link_cells
from napari_symbac.settings import Camera, Microscope, RenderSettings

__all__ = ["ColonySeriesFit", "fit_colony_series", "refit_colony_level"]


@dataclass(frozen=True)
class ColonySeriesFit:
    """Outcome of :func:`fit_colony_series`.

    Attributes
    ----------
    frames
        One :class:`~napari_symbac.fit.ColonyFit` per frame, in time order: the
        reference frame's is its own fit, the others' are drawn with its optics and
        their own media level.
    reference
        Index in ``frames`` of the frame the optics were fitted on.
    lineage
        The masks' cells linked into tracks (:class:`~napari_symbac.fit.Lineage`):
        ``lineage.track_ids[t]`` is the track of each cell of ``frames[t].cells``.
    """

    frames: tuple[ColonyFit, ...]
    reference: int
    lineage: Lineage = field(repr=False)

    @property
    def render(self) -> RenderSettings:
        """The shared optics (the reference frame's fitted render settings)."""
        return self.frames[self.reference].render

    @property
    def warnings(self) -> tuple[str, ...]:
        """The optics fit's warnings (a parameter at a bound, a fit worse than its start)."""
        return self.frames[self.reference].warnings

    @property
    def camera(self) -> Camera:
        """The camera of the likelihood (baseline and bit depth), shared."""
        return self.frames[self.reference].camera

    def shared(self) -> dict[str, tuple[float, float]]:
        """The shared optics: ``{name: (value, standard error)}`` (the media level is
        each frame's own and is left out)."""
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


def refit_colony_level(
    image: np.ndarray,
    microscope: Microscope,
    masks: np.ndarray,
    optics: ColonyFit,
) -> ColonyFit:
    """One frame drawn from its masks with ``optics``' fitted optics, its media level
    solved in closed form (least squares; the noise is Gaussian and uniform).

    The result reads as :func:`fit_colony`'s: the optics' values and standard errors
    (shared, not refitted here), this frame's level (standard error NaN, as there), the
    pixel term before (:func:`~napari_symbac.fit.colony.colony_start`'s optics) and
    after, both weighed with this frame's noise. Two renders.
    """
    from napari_symbac.fit.colony import checked_colony_frame, colony_result, rendered_start
    from napari_symbac.fit.objectives import measured_noise_sd_adu, objective_terms
    from napari_symbac.fit.parameters import scene_classes, with_media_level
    from napari_symbac.optics import ForwardModel

    real, masks, camera, noise = checked_colony_frame(image, microscope, masks, optics.camera)
    level = float(np.percentile(real, 50))
    start, scene = colony_start(masks, microscope, level, noise)
    y = real - camera.baseline_adu
    unit = ForwardModel(microscope, optics.render, camera).phase_image(scene)
    media = max(float(np.sum(unit * y) / np.sum(unit * unit)), 0.0)  # as fit_colony's NNLS
    sd = measured_noise_sd_adu(real)  # as fit_colony's last round
    render = dataclasses.replace(
        with_media_level(optics.render, media), gaussian_noise_sd_adu=sd
    )
    synthetic = media * unit + camera.baseline_adu
    before = rendered_start(microscope, start, camera, scene)
    variance = sd**2 + 1 / 12
    classes = scene_classes(scene)

    def pixel_term(model: np.ndarray) -> float:
        terms = objective_terms(model, real, classes, terms=("pixel",), variance=variance)
        return float(terms["pixel"])

    after_term, before_term = pixel_term(synthetic), pixel_term(before)
    values = np.array([*optics.parameters[:-1], media])
    return colony_result(
        real,
        masks,
        microscope,
        camera,
        scene,
        render,
        synthetic=synthetic,
        before=before,
        objective=(before_term, after_term),
        parameter_names=optics.parameter_names,
        parameters=values,
        standard_errors=optics.standard_errors,
        warnings=(),
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
        Renders of the optics fit on the reference frame.
    linking
        :class:`~napari_symbac.fit.LinkSettings` of the tracking (default its defaults).
    progress, cancel
        As :func:`~napari_symbac.fit.fit_colony`; ``progress(done, total)`` counts the
        optics fit's renders and then two per other frame.

    Raises
    ------
    ValueError
        Fewer than two frames, as many masks as frames not given, or what
        :func:`~napari_symbac.fit.fit_colony` refuses.
    """
    frames = [np.asarray(frame) for frame in stack]
    all_masks = [np.asarray(m) for m in masks]
    if len(frames) < 2:
        raise ValueError("fit_colony_series fits a time-lapse of at least 2 frames: use fit_colony")
    if len(all_masks) != len(frames):
        raise ValueError(
            f"{len(all_masks)} masks for {len(frames)} frames: give each frame its masks"
        )
    covered = [int(np.count_nonzero(m)) for m in all_masks]
    reference = int(np.argmax(covered))
    total = max_evaluations + 2 * (len(frames) - 1)

    def optics_progress(done: int, _total: int) -> None:
        if progress is not None:
            progress(min(done, max_evaluations), total)

    optics = fit_colony(
        frames[reference],
        microscope,
        all_masks[reference],
        camera,
        max_evaluations=max_evaluations,
        progress=optics_progress,
        cancel=cancel,
    )
    fits: list[ColonyFit] = []
    done = max_evaluations
    for t, (frame, frame_masks) in enumerate(zip(frames, all_masks, strict=True)):
        if t == reference:
            fits.append(optics)
            continue
        if cancel is not None and cancel():
            from napari_symbac.fit.parameters import FitCancelled

            raise FitCancelled("fit cancelled")
        fits.append(refit_colony_level(frame, microscope, frame_masks, optics))
        done += 2
        if progress is not None:
            progress(done, total)
    height, width = frames[0].shape
    pixel_um = microscope.pixel_size_um
    lineage = link_cells(
        [fit.cells for fit in fits], linking, image_size_um=(height * pixel_um, width * pixel_um)
    )
    return ColonySeriesFit(frames=tuple(fits), reference=reference, lineage=lineage)
