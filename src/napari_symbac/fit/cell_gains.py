"""Each cell's own optical path (phase) or stain (fluorescence), fitted to a real image.

The optics fit (:func:`~napari_symbac.fit.fit_parameters`) gives every cell of a scene
the same material per unit thickness: one ``cell_phase_rad`` in phase contrast. Real
cells differ (thickness, dry-mass density, a little focus): on the Omnipose colony of
long cells (Sample000252) the medians of the 77 cells span 80-141 ADU against 85-124 in
the fitted image, and one phase for all left the cells 0.085 too dark in the normalised
class medians (docs/rendering.md). :func:`fit_cell_gains` fits a gain ``g_k`` per cell
that multiplies its material (:func:`~napari_symbac.scene.scale_cells`, the same scaling
as the export's ``RenderSettings.cell_brightness_cv``) by Levenberg-Marquardt on the
pixel residual in ADU. In the partially coherent model the image is not linear in the
phase, and a cell's halo reaches its neighbours, so the Jacobian is taken by finite
differences: the cells are coloured so that cells of one colour lie at least
``2 reach_um`` apart, one render per colour perturbs all of them, and each pixel's change
is credited to the nearest perturbed cell (a handful of renders per step instead of one
per cell).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, sparse

from napari_symbac.fit.parameters import _Budget
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import Scene, scale_cells
from napari_symbac.settings import Camera, Microscope, RenderSettings

__all__ = ["MAX_CELL_GAIN", "CellGainFit", "fit_cell_gains"]

#: Largest gain a cell may take: three times the mean cell's optical path (a cell as
#: thick as three is no longer one cell of a monolayer); the smallest is 0.
MAX_CELL_GAIN = 3.0
_STEP = 0.05  # finite-difference step of a gain
_DELTA_FLOOR = 1e-3  # ADU per unit gain below which a pixel is not credited to a cell


@dataclass(frozen=True)
class CellGainFit:
    """Outcome of :func:`fit_cell_gains`.

    Attributes
    ----------
    gains
        Cell id -> fitted gain (1 = the fitted render's own cell).
    scene
        The scene with the gains applied (render it with the same settings).
    image
        Its noise-free image, in ADU above the camera baseline (the fit's last render).
    rms_before_adu, rms_after_adu
        Root-mean-square pixel residual with all gains 1 and with the fitted ones.
    n_evaluations
        Renders of the forward model used.
    standard_errors
        Cell id -> standard error of its gain: ``s sqrt([(J^T J)^-1]_kk)`` with the
        last step's Jacobian and ``s`` the residual rms (misfit counted as noise, so
        the errors are not optimistic where the model misses structure).
    warnings
        Plain-language problems: gains at a bound.
    """

    gains: dict[int, float]
    scene: Scene = field(repr=False)
    image: np.ndarray = field(repr=False)
    rms_before_adu: float
    rms_after_adu: float
    n_evaluations: int
    standard_errors: dict[int, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    @property
    def cv(self) -> float:
        """The cells' own spread of gains (``RenderSettings.cell_brightness_cv``): the
        variance of the fitted gains less their mean squared standard error (the spread
        that estimation noise alone gives identical cells), over the mean gain; 0 when
        the noise explains it all."""
        values = np.array(list(self.gains.values()))
        if values.size < 2 or values.mean() <= 0:
            return 0.0
        errors = np.array([self.standard_errors.get(i, 0.0) for i in self.gains])
        spread = float(np.var(values, ddof=1) - np.mean(np.nan_to_num(errors) ** 2))
        return math.sqrt(max(spread, 0.0)) / float(values.mean())

    @property
    def improved(self) -> bool:
        """Whether the gains lowered the residual (else they are all 1)."""
        return self.rms_after_adu < self.rms_before_adu

    def render_with_spread(self, render: RenderSettings) -> RenderSettings:
        """``render`` drawing cells as varied as these: :attr:`cv` as
        ``cell_brightness_cv`` (at most 2) and the largest gain over the mean as
        ``cell_brightness_max_gain``; ``render`` itself when no gain was fitted."""
        values = np.array(list(self.gains.values()))
        if not values.size or values.mean() <= 0:
            return render
        return dataclasses.replace(
            render,
            cell_brightness_cv=min(self.cv, 2.0),
            cell_brightness_max_gain=max(float(values.max() / values.mean()), 1.0),
        )


def _colours(labels: np.ndarray, ids: np.ndarray, reach_px: int) -> np.ndarray:
    """A colour per id (1, 2, ...) such that two cells within ``2 reach_px`` differ."""
    colour = np.zeros(int(labels.max()) + 1, np.int64)
    boxes = ndimage.find_objects(labels)
    pad = 2 * reach_px
    for k in ids:
        box = boxes[k - 1]
        window = tuple(slice(max(s.start - pad, 0), s.stop + pad) for s in box)
        near = ndimage.binary_dilation(labels[window] == k, iterations=pad)
        used = set(colour[np.unique(labels[window][near])].tolist())
        c = 1
        while c in used:
            c += 1
        colour[k] = c
    return colour


def _owners(labels: np.ndarray, members: np.ndarray) -> np.ndarray:
    """For each pixel, the id of its nearest cell among ``members``."""
    chosen = np.isin(labels, members)
    _, (iy, ix) = ndimage.distance_transform_edt(~chosen, return_indices=True)
    return labels[iy, ix]


def fit_cell_gains(
    image: np.ndarray,
    scene: Scene,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera,
    *,
    max_evaluations: int = 80,
    reach_um: float = 1.0,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> CellGainFit:
    """Fit each cell's gain (its optical path or stain relative to the others).

    Parameters
    ----------
    image
        Real 2-D image in ADU above the camera baseline, the scene's camera shape.
    scene
        The fitted scene (e.g. :func:`~napari_symbac.scene.scene_from_masks`).
    microscope, render, camera
        The fitted optics (``fit_parameters(...).render``), kept fixed.
    max_evaluations
        Renders allowed (each step takes one per colour and one to try it).
    reach_um
        Distance over which a cell's change of gain moves the image noticeably; cells
        closer than twice it are perturbed in different renders.
    progress
        Called with ``(renders done, max_evaluations)``.
    cancel
        Called before each render; when it returns True the fit raises
        :class:`~napari_symbac.fit.FitCancelled`.

    Returns
    -------
    CellGainFit
    """
    image = np.asarray(image, np.float64)
    if image.shape != tuple(scene.camera_shape):
        raise ValueError(
            f"the image is {image.shape[0]} x {image.shape[1]} px but the scene's camera "
            f"is {scene.camera_shape[0]} x {scene.camera_shape[1]}: draw the scene from "
            "the image's own masks"
        )
    if not np.all(np.isfinite(image)):
        raise ValueError("the image has NaN or infinite pixels: fill or crop them first")
    if not (np.isfinite(reach_um) and reach_um > 0):
        raise ValueError(f"reach_um must be positive, got {reach_um!r}")
    labels = scene.camera_labels().astype(np.int64)
    ids = np.unique(labels[labels > 0])
    model = ForwardModel(microscope, render, camera)
    budget = _Budget(max_evaluations, progress, cancel)

    def draw(gains: np.ndarray) -> np.ndarray:
        budget.tick()
        return model.render_clean(scale_cells(scene, ids, gains), cache=False).astype(np.float64)

    gains = np.ones(ids.size)
    current = draw(gains)
    cost = float(np.sum((image - current) ** 2))
    rms_before = float(np.sqrt(cost / image.size))
    if ids.size == 0:
        return CellGainFit({}, scene, current, rms_before, rms_before, budget.done)
    reach_px = max(1, round(reach_um / microscope.pixel_size_um))
    colour = _colours(labels, ids, reach_px)
    groups = [ids[colour[ids] == c] for c in range(1, int(colour[ids].max()) + 1)]
    column = np.zeros(int(labels.max()) + 1, np.int64)
    column[ids] = np.arange(ids.size)
    owners = [column[_owners(labels, members)].ravel() for members in groups]
    damping = 1.0
    normal = np.zeros((ids.size, ids.size))
    while budget.done + len(groups) + 1 <= max_evaluations:
        rows, cols, values = [], [], []
        for members, owner in zip(groups, owners):
            stepped = gains.copy()
            stepped[column[members]] += _STEP
            change = ((draw(stepped) - current) / _STEP).ravel()
            where = np.flatnonzero(np.abs(change) > _DELTA_FLOOR)
            rows.append(where)
            cols.append(owner[where])
            values.append(change[where])
        jac = sparse.csr_matrix(
            (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
            shape=(image.size, ids.size),
        )
        normal = (jac.T @ jac).toarray()
        gradient = jac.T @ (image - current).ravel()
        scale = np.diag(normal) + 1e-12
        improved = False
        while budget.done < max_evaluations:
            step = np.linalg.solve(normal + damping * np.diag(scale), gradient)
            trial = np.clip(gains + step, 0.0, MAX_CELL_GAIN)
            image_trial = draw(trial)
            trial_cost = float(np.sum((image - image_trial) ** 2))
            if trial_cost < cost:
                improved = cost - trial_cost > 1e-4 * cost
                gains, current, cost = trial, image_trial, trial_cost
                damping = max(damping / 3, 1e-3)
                break
            damping *= 4
        if not improved:
            break
    warnings = []
    for bound, word in ((0.0, "no optical path (gain 0)"), (MAX_CELL_GAIN, "the upper bound")):
        at = ids[np.isclose(gains, bound)]
        if at.size:
            warnings.append(
                f"{at.size} cell(s) ended at {word}: ids {', '.join(map(str, at[:10]))}"
                " (a mask that is not one cell, or a cell out of focus)"
            )
    rms_after = float(np.sqrt(cost / image.size))
    known = np.diag(normal) > 0
    errors = np.full(ids.size, np.nan)
    if known.any():
        inverse = np.linalg.pinv(normal[np.ix_(known, known)])
        errors[known] = rms_after * np.sqrt(np.maximum(np.diag(inverse), 0.0))
    return CellGainFit(
        gains={int(i): float(g) for i, g in zip(ids, gains)},
        scene=scale_cells(scene, ids, gains),
        image=current,
        rms_before_adu=rms_before,
        rms_after_adu=rms_after,
        n_evaluations=budget.done,
        standard_errors={int(i): float(e) for i, e in zip(ids, errors)},
        warnings=tuple(warnings),
    )
