"""Projected Levenberg-Marquardt over the scene parameters, intensities solved exactly.

The cost is ``chi^2 = sum_valid w (y - mu)^2 + sum_k (x_k / sd_k)^2 + sum_pairs o^2``
(Gaussian likelihood with the camera's variance ``1 / w``, eq. 17, Gaussian priors
on the curvature and per-cell widths, and the overlap penalty of
:mod:`~napari_symbac.fit.overlap`). Each iteration builds the Jacobian once (per-cell
patches, :meth:`SceneModel.jacobian`), takes the damped Gauss-Newton step on the
parameters and the intensities jointly, and re-solves the intensities exactly at
the trial point (variable projection), keeping the step only if ``chi^2`` falls.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse
from threadpoolctl import ThreadpoolController

from napari_symbac.fit.engine import SceneModel, solve_intensities
from napari_symbac.fit.overlap import overlap_terms
from napari_symbac.scene import Scene
from napari_symbac.settings import RenderSettings

__all__ = ["State", "damped_step", "evaluate", "levenberg_marquardt", "normal_equations"]

#: A Jacobian of at most this many entries is multiplied as a dense array: the
#: intensities', the trench's and the optics' columns fill it, and BLAS then beats the
#: sparse product (a 256 x 46 trench with 7 cells: 0.5 M entries).
DENSE_JACOBIAN_ENTRIES = 4_000_000
#: BLAS is held to one thread for those products: a threaded OpenBLAS spins when the
#: cores are busy (the DeLTA trench's fit took 51 s with the default threads and 32 s
#: with one, beside a test suite on the 2-core machine), and they are small.
_BLAS = ThreadpoolController()


@dataclass
class State:
    """One evaluated point: parameters, design, intensities, cost."""

    x: np.ndarray
    a: np.ndarray
    intensities: np.ndarray
    scene: Scene
    render: RenderSettings
    chi2: float
    prior: float

    @property
    def cost(self) -> float:
        return self.chi2 + self.prior

    @property
    def mu(self) -> np.ndarray:
        return self.a @ self.intensities


def evaluate(
    model: SceneModel, x: np.ndarray, y: np.ndarray, w: np.ndarray, prior_sd: np.ndarray
) -> State:
    """Render ``x``, solve the intensities (weights ``w``, 0 = censored) and the cost."""
    a, scene, r = model.design(x)
    use = w > 0
    lens = model.lens  # bright field: the lens amplitude, and cells that absorb
    intensities = solve_intensities(a[use], y[use], w[use], signed=int(lens), transmitted=lens)
    res = y - a @ intensities
    chi2 = float(np.sum(w * res * res))
    prior = float(np.sum((x / prior_sd) ** 2))
    prior += float(np.sum(overlap_terms(x, model.layout)[0] ** 2))
    return State(x, a, intensities, scene, r, chi2, prior)


def normal_equations(
    jac: sparse.spmatrix, sw: np.ndarray, res_w: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """``J^T W J`` (dense) and, with ``res_w = sqrt(w) r``, ``J^T W r``.

    ``sw`` is ``sqrt(w)`` per pixel. Small Jacobians are multiplied dense
    (:data:`DENSE_JACOBIAN_ENTRIES`), large ones sparse; the results are the same.
    """
    if jac.shape[0] * jac.shape[1] <= DENSE_JACOBIAN_ENTRIES:
        jw = jac.toarray() * sw[:, None]
        with _BLAS.limit(limits=1, user_api="blas"):
            jtj = jw.T @ jw
    else:
        jw = sparse.diags(sw) @ jac
        jtj = (jw.T @ jw).toarray()
    return jtj, None if res_w is None else np.asarray(jw.T @ res_w)


def levenberg_marquardt(
    model: SceneModel,
    state: State,
    lower: np.ndarray,
    upper: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    prior_sd: np.ndarray,
    free: np.ndarray,
    max_iterations: int,
    on_step: Callable[[State], None] | None = None,
) -> tuple[State, bool]:
    """Minimise the cost over the ``free`` parameters from ``state``.

    ``on_step`` is called with every accepted point (the fit's convergence history).

    Steps are clipped to the bounds; the damping ``lambda diag(J^T W J)`` (Marquardt
    scaling) shrinks after an accepted step and grows after a rejected one. Stops
    after ``max_iterations`` Jacobians or when the cost falls by less than 1e-6
    relative.

    Returns
    -------
    state, converged
        The final point and whether the relative-decrease test stopped the loop
        (False: the iteration limit did).
    """
    scales = model.layout.scales()
    free = np.asarray(free, bool)
    idx = np.flatnonzero(free)
    sw = np.sqrt(w)
    lam = 1e-2
    converged = False
    if idx.size == 0:
        return state, True
    m = idx.size

    def trial_from(start: State, delta: np.ndarray) -> tuple[State, float]:
        trial_x = start.x.copy()
        trial_x[idx] = np.clip(start.x[idx] + delta[:m] * scales[idx], lower[idx], upper[idx])
        model.layout.wrap_angles(trial_x)  # the same rods: the angles stay in [-pi/2, pi/2)
        trial = evaluate(model, trial_x, y, w, prior_sd)
        return trial, trial.cost

    for _ in range(max_iterations):
        jac = model.jacobian(
            state.x, state.a, state.intensities, state.scene, state.render, free, upper=upper
        )
        jtj, jtr = normal_equations(jac, sw, sw * (y - state.mu))
        grad = -jtr
        # priors on the parameters (z = x / scale)
        tie = scales[idx] / prior_sd[idx]
        jtj[np.arange(m), np.arange(m)] += tie**2
        grad[:m] += tie * (state.x[idx] / prior_sd[idx])
        pen, pen_jac = overlap_terms(state.x, model.layout, scales)
        if pen.size:
            pj = pen_jac[:, idx]
            jtj[:m, :m] += pj.T @ pj
            grad[:m] += pj.T @ pen
        trial, lam, gain = damped_step(
            jtj, grad, lam, state.cost, functools.partial(trial_from, state)
        )
        if trial is not None:
            state = trial
            if on_step is not None:
                on_step(state)
        if trial is None or gain < 1e-6:
            converged = True
            break
    return state, converged


def damped_step(
    normal: np.ndarray,
    grad: np.ndarray,
    lam: float,
    cost: float,
    trial_at: Callable[[np.ndarray], tuple[Any, float]],
) -> tuple[Any, float, float]:
    """One Levenberg-Marquardt step on the normal equations ``normal delta = -grad``.

    The damping ``lam`` scales the diagonal (Marquardt); a step is tried with
    ``trial_at(delta) -> (trial, cost)`` and taken when it lowers ``cost``, else the
    damping grows 4-fold, 8 tries at most (a singular system counts as a failed try).
    Returns ``(trial, lam, relative gain)``, the damping a third smaller after a
    success; ``(None, lam, 0.0)`` when no try lowered the cost.
    """
    diag = np.diag(normal) + 1e-9 * max(float(np.mean(np.diag(normal))), 1e-12)
    for _attempt in range(8):
        try:
            delta = np.linalg.solve(normal + lam * np.diag(diag), -grad)
        except np.linalg.LinAlgError:
            lam *= 4
            continue
        trial, trial_cost = trial_at(delta)
        if trial_cost < cost:
            return trial, max(lam / 3, 1e-7), (cost - trial_cost) / max(cost, 1e-300)
        lam *= 4
    return None, lam, 0.0
