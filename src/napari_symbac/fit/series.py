"""A time series fitted jointly: shared optics and camera, cells per frame.

The frames of one recording are taken through the same optics and camera, while
each frame holds its own cells. :func:`fit_series` fits every frame alone first
(:func:`~napari_symbac.fit.scene_fit.fit_scene`: start, rounds, moves), then
refines all frames together: the cost is the sum of the frames' costs, the
optical parameters are one set shared by every frame (their Jacobian columns are
the frames' columns stacked, so their normal-equation block is the sum of the
frames' blocks), and each frame keeps its own cells, cell width, trench placement
(drift between frames is allowed) and intensities (solved in closed form per
frame, as in a single-frame fit). The camera is measured once from the pooled
frames when it is not given.

At the joint optimum the cells are linked from frame to frame
(:func:`~napari_symbac.fit.lineage.link_cells`): each cell gets a track id that
it keeps while it grows, a division ends the mother's track and starts one per
daughter, and :attr:`SeriesFit.lineage` holds the Cell Tracking Challenge's
``L B E P`` table (track, first frame, last frame, parent).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from skimage.registration import phase_cross_correlation

from napari_symbac.fit.camera_estimate import censored_pixels, image_bit_depth
from napari_symbac.fit.lineage import Lineage, LinkSettings, link_cells
from napari_symbac.fit.lm import State, damped_step, evaluate, normal_equations
from napari_symbac.fit.moves import dispersion
from napari_symbac.fit.overlap import overlap_terms
from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.fit.scene_fit import (
    _INTENSITIES,
    LENS_AMPLITUDE,
    SceneFit,
    _baseline_guess,
    _frame_result,
    _FrameRun,
    _measured_camera,
    _run_frame,
)
from napari_symbac.fit.start import WideStartError
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

__all__ = ["SeriesFit", "fit_series"]


@dataclass(frozen=True)
class SeriesFit:
    """Outcome of :func:`fit_series`.

    Attributes
    ----------
    frames
        One :class:`~napari_symbac.fit.SceneFit` per frame at the joint optimum (its
        standard errors are the frame's own, with the shared parameters as if only
        that frame had measured them).
    frame_by_frame
        The fits of every frame alone, before the joint refinement.
    shared_names
        The shared (optical) parameters.
    shared_values, shared_standard_errors
        Their joint values and standard errors (inverse of the summed Fisher
        information of all frames, every frame's cells and intensities included).
    frame_values, frame_standard_errors
        ``(T, S)``: the same parameters from each frame's fit alone.
    camera
        The camera shared by all frames (given, or measured from the pooled frames;
        ``None`` when each frame measured its own).
    cost_frame_by_frame, cost_joint
        The summed cost of the frames (chi-square plus priors) of the frame-by-frame
        fits and of the joint fit. The joint fit has fewer free parameters (one set of
        optics instead of one per frame), so its cost is not lower.
    iterations
        Joint Levenberg-Marquardt iterations taken.
    warnings
        Plain words on what did not converge.
    lineage
        Identities of the cells at the joint optimum
        (:class:`~napari_symbac.fit.lineage.Lineage`): ``lineage.track_ids[t]`` gives
        the track of each cell of ``frames[t].cells`` (same order), ``lineage.tracks``
        one ``(track, first frame, last frame, parent track)`` row per track, frames
        numbered from 0 within the series.
    carried
        Per frame: whether the fit that was kept started from the previous frame's
        cells (``carry_cells``); False for the first frame.
    frame_correlation
        Per frame: the correlation of its overlap with the previous frame, once
        registered (:func:`_registered_correlation`; NaN for the first frame); below
        :data:`CARRY_MIN_CORRELATION` the two are taken for different fields (a warning
        says so).
    """

    frames: tuple[SceneFit, ...]
    frame_by_frame: tuple[SceneFit, ...] = field(repr=False)
    shared_names: tuple[str, ...]
    shared_values: np.ndarray
    shared_standard_errors: np.ndarray
    frame_values: np.ndarray = field(repr=False)
    frame_standard_errors: np.ndarray = field(repr=False)
    camera: Camera | None = None
    cost_frame_by_frame: float = math.nan
    cost_joint: float = math.nan
    iterations: int = 0
    warnings: tuple[str, ...] = ()
    lineage: Lineage | None = field(default=None, repr=False)
    carried: tuple[bool, ...] = ()
    frame_correlation: tuple[float, ...] = ()

    @property
    def track_ids(self) -> tuple[np.ndarray, ...]:
        """Track id of each fitted cell, one array per frame (see :attr:`lineage`)."""
        if self.lineage is None:
            raise ValueError("this series fit holds no lineage")
        return self.lineage.track_ids

    def shared(self) -> dict[str, tuple[float, float]]:
        """``{name: (value, standard error)}`` of the shared parameters."""
        return {
            name: (float(v), float(se))
            for name, v, se in zip(
                self.shared_names, self.shared_values, self.shared_standard_errors
            )
        }


def _per_frame(array: np.ndarray | None, t: int, n: int, name: str) -> np.ndarray | None:
    if array is None:
        return None
    array = np.asarray(array)
    if array.ndim == 3:
        if array.shape[0] != n:
            raise ValueError(f"{name} has {array.shape[0]} frames but the series has {n}")
        return array[t]
    return array


def _pooled_camera(stack: np.ndarray) -> Camera | None:
    """The camera of all frames at once (photon transfer on the pooled high-pass), the
    baseline placed as a single frame's fit places it (:func:`_measured_camera`: found
    as a user, ColiCoords ds3's four frames, every pixel above 1717 ADU, were fitted
    jointly with the 100 ADU guess, reduced chi-square 0.22-0.25, and their exported
    dataset was 3x too noisy, where one frame alone measured 1757 ADU)."""
    valid = ~censored_pixels(stack)
    guess = Camera(baseline_adu=_baseline_guess(stack, valid), bit_depth=image_bit_depth(stack))
    return _measured_camera(stack, valid, guess)


class _SeriesProgress:
    """One count over a series' frame fits, each of which reports its own steps from 0
    (found as a user: the piped lines of a series fit ran 1346, 300, 1703 of 6804, like
    restarts): the steps of the fits done plus this one's, of a total that takes the
    frames left to cost what this one does. The count never goes back: a finished fit's
    later calls (its problem kept for the joint refinement) are not counted, nor steps
    reported after a fit's end report."""

    def __init__(self, progress: Callable[[int, int], None] | None) -> None:
        self.progress = progress
        self.done_before = 0  # steps of the fits that have ended
        self.last = 0  # the running fit's steps so far
        self.running = 0  # which fit is running

    def run(self, frames_left: int) -> Callable[[int, int], None] | None:
        """The ``progress`` of the next frame fit, ``frames_left`` frames (it included)."""
        if self.progress is None:
            return None
        self.done_before += self.last
        self.last = 0
        self.running += 1
        mine = self.running

        def update(done: int, total: int) -> None:
            if mine != self.running:
                return
            self.last = max(self.last, done)  # a fit's end report (total) may come early
            whole = self.done_before + max(total * frames_left, self.last)
            self.progress(self.done_before + self.last, whole)

        return update


def fit_series(
    frames: np.ndarray,
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera | None = None,
    *,
    geometry: Literal["trench", "open", "field"] = "trench",
    labels: np.ndarray | None = None,
    masks: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    trench: TrenchPlacement | TrenchGeometry | None = None,
    closed_end: Literal["square", "round"] | None = None,
    fit_optics: tuple[str, ...] | None = None,
    joint_iterations: int = 15,
    linking: LinkSettings | None = None,
    growth_prior_sd_um: float = 0.0,
    carry_cells: bool = True,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    frame_numbers: Sequence[int] | None = None,
    **frame_options,
) -> SeriesFit:
    """Fit a ``(T, Y, X)`` series with optics (and camera) shared by all frames.

    Parameters
    ----------
    frames
        ``(T, Y, X)`` frames of one recording (ADU, camera baseline included), T >= 2.
    microscope, render, camera, geometry, trench, closed_end, fit_optics
        As :func:`~napari_symbac.fit.fit_scene`. ``camera=None``: measured once from
        the pooled frames (:func:`~napari_symbac.fit.camera_estimate.estimate_camera`),
        else per frame when the pooled estimate fails.
    labels, masks, valid
        ``None``, one 2D array for every frame, or a ``(T, Y, X)`` stack (``valid``
        as :func:`~napari_symbac.fit.fit_scene`'s, default: not censored).
    joint_iterations
        Levenberg-Marquardt iterations of the joint refinement.
    growth_prior_sd_um
        0 (default): each frame's cells are refined on their own. > 0: the cells are
        linked after the frame-by-frame fits and the joint refinement ties each linked
        cell's length to its predecessor's grown length (``L' = g L``, ``g`` the measured
        growth per frame) and two daughters' summed length to their mother's (plus a
        third of her width) by a Gaussian prior of this s.d.: a cell cut by the image's
        edge borrows its length from its past.
    carry_cells
        True (default, when no masks are given): each frame after the first is also
        fitted from the previous frame's fitted cells, moved by the drift between the
        two frames (phase correlation), and the fit whose BIC is lower (both scored
        with the first fit's weights and residual dispersion, the price of a cell as
        in the moves) is kept: where the image alone hides a boundary (two touching
        cells without a valley), the previous frame still knows it, and a division
        since then is a split move away. False: every frame from its own start.
    linking
        How cells are linked between frames
        (:class:`~napari_symbac.fit.lineage.LinkSettings`; default: its defaults). In a
        trench the per-frame trench placements take up the drift and cells are pushed
        down the trench; in an open field one shift per frame is measured.
    progress
        ``progress(done, total)`` in the frame fits' steps, one count over the series
        (:class:`_SeriesProgress`).
    cancel
        As :func:`~napari_symbac.fit.fit_scene`, per frame fit.
    frame_numbers
        The frames' numbers in the recording, for the messages and warnings (found as
        a user: ``--frames 1-2`` warned of "frames 0 and 1"); default ``0..T-1``.
    **frame_options
        Passed to each frame's :func:`~napari_symbac.fit.fit_scene` (``irls_rounds``,
        ``max_iterations``, ``moves``, ``per_cell_brightness``, ...).

    Returns
    -------
    SeriesFit
    """
    geometry = "open" if geometry == "field" else geometry  # `fit --geometry field`'s word
    stack = np.asarray(frames)
    if stack.ndim != 3 or stack.shape[0] < 2:
        raise ValueError(
            f"fit_series needs a (T, Y, X) series of at least 2 frames, got shape {stack.shape}: "
            "fit a single frame with fit_scene"
        )
    if joint_iterations < 1:
        raise ValueError(f"joint_iterations must be at least 1, got {joint_iterations}")
    if not (math.isfinite(growth_prior_sd_um) and growth_prior_sd_um >= 0):
        raise ValueError(
            f"growth_prior_sd_um must be zero (off) or positive, got {growth_prior_sd_um!r}"
        )
    n_frames = stack.shape[0]
    number = list(range(n_frames)) if frame_numbers is None else [int(k) for k in frame_numbers]
    if len(number) != n_frames:
        raise ValueError(f"frame_numbers names {len(number)} frames, the series has {n_frames}")
    shared_camera = camera if camera is not None else _pooled_camera(stack)
    runs: list[_FrameRun] = []
    carried_from: list[bool] = []
    # each pair registered once: for carrying cells across it and for the warning
    registered = [(np.zeros(2), math.nan)] + [
        _registered_correlation(stack[t - 1], stack[t]) for t in range(1, n_frames)
    ]
    steps = _SeriesProgress(progress)
    for t in range(n_frames):
        frame_run = functools.partial(
            _run_frame,
            stack[t],
            microscope,
            render,
            shared_camera,
            geometry=geometry,
            labels=_per_frame(labels, t, n_frames, "labels"),
            masks=_per_frame(masks, t, n_frames, "masks"),
            valid=_per_frame(valid, t, n_frames, "valid"),
            trench=trench,
            closed_end=closed_end,
            fit_optics=fit_optics,
            cancel=cancel,
            **frame_options,
        )
        carry = carry_cells and t > 0 and masks is None
        try:
            try:
                run = frame_run(progress=steps.run(n_frames - t))
            except WideStartError as refused:
                # a colony grown dense: its own start is refused, the last frame's cells
                # are not (below); without them the refusal stands
                if not carry:
                    raise
                run, wide = None, refused
            if t == 0 and closed_end is None and run.problem.placement is not None:
                closed_end = run.problem.placement.closed_end  # one trench: one end
            carried = False
            if carry:
                moved = _carried_cells(
                    runs[-1], registered[t], stack[t].shape, microscope.pixel_size_um
                )
                if moved is not None and len(moved.ids):
                    other = frame_run(start_cells=moved, progress=steps.run(n_frames - t))
                    carried = run is None or _lower_bic(other, run)
                    run = other if carried else run
            if run is None:
                raise wide
        except ValueError as err:
            advice = (
                ". A series fit needs cells in every frame: fit the frames before and "
                f"after frame {number[t]} as separate series"
                if "no cells" in str(err)
                else ""
            )
            raise ValueError(f"frame {number[t]} of the series: {err}{advice}") from err
        runs.append(run)
        carried_from.append(carried)
    alone = tuple(_frame_result(run) for run in runs)
    optics = runs[0].problem.layout.optics
    names = tuple(optics)
    frame_values = np.array(
        [[fit.parameters[fit.parameter_names.index(k)] for k in names] for fit in alone]
    ).reshape(n_frames, len(names))
    frame_se = np.array([[fit.standard_error(k) for k in names] for fit in alone]).reshape(
        n_frames, len(names)
    )
    warnings: list[str] = []
    correlation = [float(c) for _, c in registered]
    unrelated = [t for t in range(1, n_frames) if correlation[t] < CARRY_MIN_CORRELATION]
    warnings += [  # found as a user: 0 tracks linked on ColiCoords ds3, and no word why
        f"frames {number[t - 1]} and {number[t]} correlate {correlation[t]:.2f} where they "
        f"overlap, once registered (below {CARRY_MIN_CORRELATION}): they look like "
        f"different fields (a stage jump?), so frame {number[t]}'s cells were fitted from "
        f"its own start and start new tracks (none continues frame {number[t - 1]}'s)"
        for t in unrelated
    ]
    cost_before = sum(run.state.cost for run in runs)
    iterations = 0
    px = microscope.pixel_size_um
    size_um = (stack.shape[1] * px, stack.shape[2] * px)
    ties = None
    if growth_prior_sd_um > 0:
        early = _link(alone, linking, geometry, size_um, unrelated)
        ties = _GrowthTies.from_lineage(early, alone, growth_prior_sd_um)
    if names or ties is not None:
        states, iterations, converged = _joint_refine(
            runs, len(names), joint_iterations, ties
        )
        if not converged:
            warnings.append(
                f"the joint fit stopped at the iteration limit ({joint_iterations}) before "
                "converging"
            )
        runs = [dataclasses.replace(run, state=state) for run, state in zip(runs, states)]
    joint = tuple(_frame_result(run) for run in runs)
    cost_after = sum(run.state.cost for run in runs)
    values, se = _joint_uncertainty(joint, runs, names)
    lineage = _link(joint, linking, geometry, size_um, unrelated)
    return SeriesFit(
        frames=joint,
        frame_by_frame=alone,
        shared_names=names,
        shared_values=values,
        shared_standard_errors=se,
        frame_values=frame_values,
        frame_standard_errors=frame_se,
        camera=shared_camera,
        cost_frame_by_frame=float(cost_before),
        cost_joint=float(cost_after),
        iterations=iterations,
        warnings=tuple(warnings),
        lineage=lineage,
        carried=tuple(carried_from),
        frame_correlation=tuple(correlation),
    )


#: Correlation of two registered frames below which a series fit takes them for
#: different fields and does not carry cells from one to the other: 0.88-0.95 between
#: the frames of a drifting fluorescent colony, 0.15-0.48 between the four unrelated
#: fields of ColiCoords ds3 (docs/fitting.md).
CARRY_MIN_CORRELATION = 0.6


def _registered_correlation(before: np.ndarray, after: np.ndarray) -> tuple[np.ndarray, float]:
    """The shift (px) that registers ``after`` onto ``before`` (phase correlation, to a
    tenth of a pixel: minus the stage's drift) and the correlation of their overlap so
    registered; NaN when the overlap is under 100 px or flat."""
    a, b = before.astype(np.float64), after.astype(np.float64)
    shift_px = phase_cross_correlation(a, b, upsample_factor=10, normalization=None)[0]
    dy, dx = (round(float(v)) for v in shift_px)
    rows, cols = a.shape
    overlap_a = a[max(dy, 0) : rows + min(dy, 0), max(dx, 0) : cols + min(dx, 0)]
    overlap_b = b[max(-dy, 0) : rows + min(-dy, 0), max(-dx, 0) : cols + min(-dx, 0)]
    if overlap_a.size < 100 or overlap_a.std() == 0 or overlap_b.std() == 0:
        return shift_px, math.nan
    return shift_px, float(np.corrcoef(overlap_a.ravel(), overlap_b.ravel())[0, 1])


def _carried_cells(
    previous: _FrameRun,
    registration: tuple[np.ndarray, float],
    shape: tuple[int, int],
    pixel_um: float,
) -> FrameCells | None:
    """The previous frame's fitted cells moved by the drift between the two frames
    (of ``shape``), given by their ``registration`` (:func:`_registered_correlation`).

    The drift is the phase correlation of the two frames (to a tenth of a pixel);
    cells the move takes wholly off the image (centre beyond half a length) are
    dropped. None when the frames' overlap, so registered, correlates less than
    :data:`CARRY_MIN_CORRELATION`: two different fields, whose cells the previous
    frame does not know.
    """
    shift_px, correlation = registration
    if not correlation >= CARRY_MIN_CORRELATION:
        return None
    rows, cols = shape
    problem, x = previous.problem, previous.state.x
    cells = problem.model(problem.n_cells(x)).unpack(x)[0]
    dy_um, dx_um = -shift_px[0] * pixel_um, -shift_px[1] * pixel_um
    x_um, y_um = cells.x_um + dx_um, cells.y_um + dy_um
    reach = 0.5 * np.asarray(cells.length_um)  # a cell cut by the edge still shows
    keep = (x_um >= -reach) & (x_um <= cols * pixel_um + reach)
    keep &= (y_um >= -reach) & (y_um <= rows * pixel_um + reach)
    return FrameCells(
        ids=np.asarray(cells.ids)[keep],
        x_um=x_um[keep],
        y_um=y_um[keep],
        angle_rad=np.asarray(cells.angle_rad)[keep],
        length_um=np.asarray(cells.length_um)[keep],
        width_um=np.asarray(cells.width_um)[keep],
    )


def _lower_bic(candidate: _FrameRun, incumbent: _FrameRun) -> bool:
    """Whether ``candidate``'s fit has the lower BIC, both scored on ``incumbent``'s terms.

    Scored with the incumbent's weights (its camera variance of the last round) and
    the dispersion of its residual, each cell priced as in the moves
    (:func:`~napari_symbac.fit.moves.dispersion`, ``Problem.bic_per_cell``).
    """
    problem = incumbent.problem
    phi = dispersion(problem, incumbent.state)
    rescored = problem.evaluate(candidate.state.x)

    def bic(state: State) -> float:
        return state.cost / phi + problem.n_cells(state.x) * problem.bic_per_cell

    return bic(rescored) < bic(incumbent.state)


def _link(
    fits: tuple[SceneFit, ...],
    linking: LinkSettings | None,
    geometry: str,
    size_um: tuple[float, float],
    unrelated: list[int],
) -> Lineage:
    """The fitted cells of the frames linked into tracks (trench placements in a
    trench); no track crosses into a frame of ``unrelated`` (another field)."""
    return link_cells(
        [fit.cells for fit in fits],
        linking,
        trench=[fit.trench for fit in fits] if geometry == "trench" else None,
        image_size_um=size_um,
        unrelated_frames=unrelated,
    )


def _split(runs: list[_FrameRun], n_shared: int) -> tuple[list[int], np.ndarray]:
    """Lengths of each frame's own parameters and the joint start vector.

    The joint vector is every frame's own parameters (cells, width, trench) in
    turn, then the shared ones, started at their mean over the frames.
    """
    own = [run.state.x.size - n_shared for run in runs]
    shared = (
        np.mean([run.state.x[run.state.x.size - n_shared :] for run in runs], axis=0)
        if n_shared
        else np.zeros(0)
    )
    z = np.concatenate([*(run.state.x[:k] for run, k in zip(runs, own)), shared])
    return own, z


def _frame_x(z: np.ndarray, own: list[int], t: int, n_shared: int) -> np.ndarray:
    start = sum(own[:t])
    return np.concatenate([z[start : start + own[t]], z[z.size - n_shared :]])


def _n_amplitudes(runs: list[_FrameRun]) -> int:
    """Amplitudes each frame solves in closed form: the three intensities, and bright
    field's lens amplitude (:attr:`~napari_symbac.fit.engine.SceneModel.n_amplitudes`)."""
    problem = runs[0].problem
    return problem.model(problem.n_cells(runs[0].state.x)).n_amplitudes


def _frame_index(own: list[int], t: int, n_shared: int, n_amp: int = 3) -> np.ndarray:
    """Joint positions of frame ``t``'s parameters and then its ``n_amp`` amplitudes
    (the three intensities, and bright field's lens amplitude)."""
    start, total = sum(own[:t]), sum(own) + n_shared
    return np.concatenate(
        [
            np.arange(start, start + own[t]),
            np.arange(total - n_shared, total),
            total + n_amp * t + np.arange(n_amp),
        ]
    )


def _evaluate_all(runs: list[_FrameRun], z: np.ndarray, own: list[int], n_shared: int):
    states = []
    for t, run in enumerate(runs):
        p = run.problem
        x = _frame_x(z, own, t, n_shared)
        n = p.n_cells(x)
        x = np.clip(x, p.lower(n), p.upper(n))
        states.append(evaluate(p.model(n), x, p.y, p.w, p.prior_sd(n)))
    return states


@dataclass(frozen=True)
class _GrowthTies:
    """Gaussian priors tying linked cells' lengths across frames (``growth_prior_sd_um``).

    Each tie is ``(sum_k c_k L_k - offset) / sd`` over cells given as ``(frame, cell
    index)``: a link ``L' - g L``, a division ``L_a + L_b - g L_m - w_m / 3``.
    """

    cells: tuple[tuple[tuple[int, int], ...], ...]
    coefficients: tuple[tuple[float, ...], ...]
    offsets: np.ndarray
    sd_um: float

    @classmethod
    def from_lineage(
        cls, lineage: Lineage, fits: tuple[SceneFit, ...], sd_um: float
    ) -> _GrowthTies | None:
        g = lineage.growth_per_frame
        cells, coefficients, offsets = [], [], []
        for t in range(len(fits) - 1):
            before, after = lineage.track_ids[t], lineage.track_ids[t + 1]
            for j, track in enumerate(after.tolist()):
                hit = np.flatnonzero(before == track)
                if hit.size:
                    cells.append(((t, int(hit[0])), (t + 1, j)))
                    coefficients.append((-g, 1.0))
                    offsets.append(0.0)
            for mother, daughters in lineage.divisions().items():
                k = np.flatnonzero(before == mother)
                d = [int(i) for i in np.flatnonzero(np.isin(after, daughters))]
                if k.size and len(d) == 2:
                    cells.append(((t, int(k[0])), (t + 1, d[0]), (t + 1, d[1])))
                    coefficients.append((-g, 1.0, 1.0))
                    offsets.append(float(fits[t].cells.width_um[k[0]]) / 3)
        if not cells:
            return None
        return cls(tuple(cells), tuple(coefficients), np.array(offsets), float(sd_um))

    def _where(self, runs: list[_FrameRun], own: list[int]) -> list[np.ndarray]:
        per_cell = [run.problem.layout.per_cell for run in runs]
        return [
            np.array([sum(own[:t]) + c * per_cell[t] + _LENGTH for t, c in tie])
            for tie in self.cells
        ]

    def terms(
        self, z: np.ndarray, runs: list[_FrameRun], own: list[int]
    ) -> tuple[np.ndarray, list[np.ndarray]]:
        """Residuals (in s.d.) and, per tie, the joint positions of its lengths."""
        where = self._where(runs, own)
        r = np.array(
            [
                (np.dot(c, z[w]) - off) / self.sd_um
                for c, w, off in zip(self.coefficients, where, self.offsets)
            ]
        )
        return r, where

    def cost(self, z: np.ndarray, runs: list[_FrameRun], own: list[int]) -> float:
        return float(np.sum(self.terms(z, runs, own)[0] ** 2))


#: Position of the length in a cell's block of parameters (x, y, angle, length, ...).
_LENGTH = 3


def _joint_refine(
    runs: list[_FrameRun],
    n_shared: int,
    max_iterations: int,
    ties: _GrowthTies | None = None,
) -> tuple[list[State], int, bool]:
    """Levenberg-Marquardt on the summed cost, shared columns summed over frames.

    As :func:`~napari_symbac.fit.lm.levenberg_marquardt` for one frame: the
    Jacobian of every frame (per-cell patches, full renders for the optics), the
    damped Gauss-Newton step on all parameters and intensities, the intensities
    re-solved exactly per frame at the trial point. ``ties``: the growth priors
    between frames, added to the cost and to the normal equations.
    """
    own, z = _split(runs, n_shared)
    states = _evaluate_all(runs, z, own, n_shared)

    def tie_cost(point: np.ndarray) -> float:
        return 0.0 if ties is None else ties.cost(point, runs, own)

    def trial_from(start, scales, lower, upper, delta):
        trial_z = np.clip(start + delta[: scales.size] * scales, lower, upper)
        trial = _evaluate_all(runs, trial_z, own, n_shared)
        return (trial_z, trial), sum(s.cost for s in trial) + tie_cost(trial_z)

    n_amp = _n_amplitudes(runs)
    size = sum(own) + n_shared + n_amp * len(runs)
    lam = 1e-2
    converged = False
    iterations = 0
    for _ in range(max_iterations):
        iterations += 1
        h = np.zeros((size, size))
        g = np.zeros(size)
        scales = np.zeros(sum(own) + n_shared)
        lower = np.zeros_like(scales)
        upper = np.zeros_like(scales)
        for t, (run, state) in enumerate(zip(runs, states)):
            p = run.problem
            n = p.n_cells(state.x)
            model = p.model(n)
            up = p.upper(n)
            jac = model.jacobian(
                state.x,
                state.a,
                state.intensities,
                state.scene,
                state.render,
                np.ones(state.x.size, bool),
                upper=up,
            )
            sw = np.sqrt(p.w)
            jtj, jtr = normal_equations(jac, sw, sw * (p.y - state.mu))
            grad = -jtr
            m = state.x.size
            sc = model.layout.scales()
            sd = p.prior_sd(n)
            tie = sc / sd
            jtj[np.arange(m), np.arange(m)] += tie**2
            grad[:m] += tie * (state.x / sd)
            pen, pen_jac = overlap_terms(state.x, model.layout, sc)
            if pen.size:
                jtj[:m, :m] += pen_jac.T @ pen_jac
                grad[:m] += pen_jac.T @ pen
            index = _frame_index(own, t, n_shared, n_amp)
            h[np.ix_(index, index)] += jtj
            g[index] += grad
            scales[index[:m]] = sc
            lower[index[:m]] = p.lower(n)
            upper[index[:m]] = up
        if ties is not None:
            r, where = ties.terms(z, runs, own)
            for res, idx, coef in zip(r, where, ties.coefficients):
                d = np.asarray(coef) * scales[idx] / ties.sd_um
                h[np.ix_(idx, idx)] += np.outer(d, d)
                g[idx] += d * res
        cost = sum(s.cost for s in states) + tie_cost(z)
        step_to = functools.partial(trial_from, z, scales, lower, upper)
        accepted, lam, gain = damped_step(h, g, lam, cost, step_to)
        if accepted is not None:
            z, states = accepted
        if accepted is None or gain < 1e-6:
            converged = True
            break
    return states, iterations, converged


def _joint_uncertainty(
    fits: tuple[SceneFit, ...], runs: list[_FrameRun], names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Shared values and standard errors from the frames' summed Fisher information.

    Each frame's information (:attr:`SceneFit.information`, physical units, its
    cells, own shared parameters and intensities) is placed into the joint matrix;
    the shared parameters' rows and columns add up over the frames.
    """
    n_shared = len(names)
    own = [run.state.x.size - n_shared for run in runs]
    amplitudes = (*_INTENSITIES, LENS_AMPLITUDE)
    n_amp = _n_amplitudes(runs)
    size = sum(own) + n_shared + n_amp * len(runs)
    info = np.zeros((size, size))
    used = np.zeros(size, bool)
    for t, fit in enumerate(fits):
        index = _frame_index(own, t, n_shared, n_amp)
        m = own[t] + n_shared
        where = [
            index[k] if k < m else index[m + amplitudes.index(name)]
            for k, name in enumerate(fit.parameter_names)
        ]
        info[np.ix_(where, where)] += fit.information
        used[where] = True
    keep = np.flatnonzero(used)
    cov = np.linalg.pinv(info[np.ix_(keep, keep)], rcond=1e-12, hermitian=True)
    se_all = np.zeros(size)
    se_all[keep] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    shared_at = np.arange(sum(own), sum(own) + n_shared)
    values = fits[0].parameters[[fits[0].parameter_names.index(k) for k in names]]
    return np.asarray(values, float), se_all[shared_at]
