"""A fluorescence stain in the cell envelope that the model draws filling the cell."""

from __future__ import annotations

from typing import Any

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry

__all__ = ["EnvelopeStain"]


class EnvelopeStain(Effect):
    """More of the stain in the envelope than the base model draws: ``mu + df I_c E``.

    ``E`` is the cells' envelope image less their volume image through the fitted
    optics, at unit cell intensity (:attr:`Geometry.envelope_component`: the scene's
    cells drawn by :func:`~napari_symbac.scene.envelope_stain` with fraction 1, less
    the scene's cells, convolved), and ``I_c`` the fitted cell intensity (eq. 3), so
    ``df`` is a change of the fraction itself: the image is linear in it. The fraction
    ``f0 + df`` (``f0`` the base model's, :attr:`Geometry.envelope_fraction`, 0 unless
    the scene fit drew one) is kept in ``[0, 1]`` and reported; in the settings it
    becomes ``RenderSettings.envelope_stain_fraction``. Without an envelope component
    (a geometry from labels alone) the effect has no parameter.
    """

    name = "envelope_stain"
    explanation = (
        "The stain sits in the cell envelope (a membrane, periplasmic or surface dye), not "
        "throughout the cell: each cell is brighter at its rim than on its centre line, "
        "where the model's stain, filling the cell, is brightest."
    )
    signature = (
        "residual negative on the cells' centre lines and positive in a ring just inside "
        "their edges (mean residual against signed distance to the nearest cell edge)"
    )
    modalities = ("fluorescence",)

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._envelope = geometry.envelope_component
        own = geometry.cell_components
        self._probe, self._probe_value = 0, 0.0
        if self._envelope is not None and own is not None and len(own):
            total = own.sum(axis=0)
            # where the cells' part is largest: I_c = parts[0] / C there (exact, eq. 3)
            self._probe = int(np.argmax(np.abs(total)))
            self._probe_value = float(total.ravel()[self._probe])

    def n_params(self) -> int:
        return 1 if self._envelope is not None and self._probe_value != 0 else 0

    def steps(self, theta: np.ndarray) -> np.ndarray:
        return np.full(len(theta), 0.01)

    def clip(self, theta: np.ndarray) -> np.ndarray:
        base = self.geometry.envelope_fraction
        return np.clip(theta, -base, 1.0 - base)

    def mean(
        self, theta: np.ndarray, mu: np.ndarray, parts: np.ndarray, geo: Geometry
    ) -> np.ndarray:
        if not len(theta):
            return mu
        intensity = parts[0].ravel()[self._probe] / self._probe_value
        return mu + theta[0] * intensity * self._envelope

    def summary(self, theta: np.ndarray, mu: np.ndarray) -> dict[str, Any]:
        change = float(theta[0]) if len(theta) else 0.0
        return {"fraction": self.geometry.envelope_fraction + change}

    def magnitude(self, summary: dict[str, Any]) -> float:
        return summary["fraction"]

    def direction(self, rng: np.random.Generator) -> np.ndarray:
        return np.ones(self.n_params())
