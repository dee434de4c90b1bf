"""One scene-fit problem: data, weights, bounds and priors for any number of cells.

The moves of :mod:`napari_symbac.fit.moves` change the number of cells; every
cell has the same bounds and priors, so a :class:`Problem` builds the model, the
bounds and the prior widths of a parameter vector for any ``n``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from napari_symbac.fit.engine import Layout, SceneModel
from napari_symbac.fit.lm import State, evaluate, levenberg_marquardt
from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.settings import Camera, Microscope, RenderSettings

__all__ = ["Problem"]


@dataclass
class Problem:
    """Data and constraints of a scene fit (see :func:`~napari_symbac.fit.fit_scene`).

    Attributes
    ----------
    y
        Real image minus the camera baseline, flattened (ADU).
    w
        Inverse variance per pixel, 0 at censored pixels.
    cell_lower, cell_upper, cell_prior_sd
        Bounds and prior s.d. (inf: none) of one cell's parameters (:class:`Layout`).
    global_lower, global_upper, global_prior_sd
        The same for the shared parameters.
    """

    shape: tuple[int, int]
    microscope: Microscope
    render: RenderSettings
    camera: Camera
    placement: TrenchPlacement | None
    depth_um: float
    layout: Layout
    y: np.ndarray
    w: np.ndarray
    cell_lower: np.ndarray
    cell_upper: np.ndarray
    cell_prior_sd: np.ndarray
    global_lower: np.ndarray
    global_upper: np.ndarray
    global_prior_sd: np.ndarray
    tick: Callable[[], None] | None = None
    on_step: Callable[[State], None] | None = None

    def __post_init__(self) -> None:
        self._models: dict[int, SceneModel] = {}

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.w))

    @property
    def bic_per_cell(self) -> float:
        """BIC price of one cell: its parameter count times ``ln N`` (valid pixels)."""
        return self.layout.per_cell * math.log(max(self.n_valid, 2))

    def model(self, n: int) -> SceneModel:
        """The scene model for ``n`` cells (the forward model's caches are shared)."""
        if n not in self._models:
            self._models[n] = SceneModel(
                self.shape,
                self.microscope,
                self.render,
                self.camera,
                self.placement,
                self.depth_um,
                self.layout.with_cells(n),
                self.tick,
            )
        return self._models[n]

    def _per_cell(self, n: int, cell: np.ndarray, shared: np.ndarray) -> np.ndarray:
        return np.concatenate([np.tile(cell, n), shared])

    def lower(self, n: int) -> np.ndarray:
        return self._per_cell(n, self.cell_lower, self.global_lower)

    def upper(self, n: int) -> np.ndarray:
        return self._per_cell(n, self.cell_upper, self.global_upper)

    def prior_sd(self, n: int) -> np.ndarray:
        return self._per_cell(n, self.cell_prior_sd, self.global_prior_sd)

    def n_cells(self, x: np.ndarray) -> int:
        return (x.size - len(self.layout.global_names)) // self.layout.per_cell

    def evaluate(self, x: np.ndarray) -> State:
        n = self.n_cells(x)
        x = np.clip(x, self.lower(n), self.upper(n))
        return evaluate(self.model(n), x, self.y, self.w, self.prior_sd(n))

    def refit(
        self, state: State, free: np.ndarray | None = None, max_iterations: int = 25
    ) -> tuple[State, bool]:
        """Levenberg-Marquardt from ``state`` over ``free`` (default: every parameter)."""
        n = self.n_cells(state.x)
        if free is None:
            free = np.ones(state.x.size, bool)
        return levenberg_marquardt(
            self.model(n),
            state,
            self.lower(n),
            self.upper(n),
            self.y,
            self.w,
            self.prior_sd(n),
            free,
            max_iterations,
            self.on_step,
        )

    def with_weights(self, w: np.ndarray, camera: Camera | None = None) -> Problem:
        """The same problem with new weights (IRLS) and, optionally, another camera."""
        out = dataclasses.replace(self, w=w, camera=self.camera if camera is None else camera)
        out._models = self._models
        return out

    def with_placement(self, placement: TrenchPlacement) -> Problem:
        """The same problem with another trench placement (its own scene models), that
        reports no steps (for a trial of the other closed end)."""
        return dataclasses.replace(self, placement=placement, on_step=None)

    def without_history(self) -> Problem:
        """The same problem that reports no steps (for trial refits of proposed moves)."""
        return self.reporting_to(None)

    def reporting_to(self, on_step: Callable[[State], None] | None) -> Problem:
        """The same problem (its scene models shared) that reports its steps to ``on_step``."""
        out = dataclasses.replace(self, on_step=on_step)
        out._models = self._models
        return out

    def blocks(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(n, per_cell)`` cell blocks and the shared parameters of ``x``."""
        n, pc = self.n_cells(x), self.layout.per_cell
        return x[: n * pc].reshape(n, pc).copy(), x[n * pc :].copy()

    @staticmethod
    def join(blocks: np.ndarray, shared: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(blocks, float).ravel(), shared])
