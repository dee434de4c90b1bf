"""Uneven illumination (vignetting, a tilted lamp or condenser)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry, weighted_sum
from napari_symbac.optics.forward import Stage

__all__ = ["UnevenIllumination"]


def _basis(yn: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """Low-order surface ``x, y, x^2, y^2, xy`` (centred squares), ``(5, Y, X)``."""
    x2, y2 = xn**2, yn**2
    return np.stack([xn, yn, x2 - x2.mean(), y2 - y2.mean(), xn * yn])


class UnevenIllumination(Effect):
    """The light reaching the sample is not flat: ``mu (1 + sum_k c_k P_k(x, y))``.

    ``P_k`` are the low-order polynomials ``x, y, x^2, y^2, xy`` over the field
    (coordinates scaled to [-1, 1]); ``c`` are fractions of the local brightness.
    """

    name = "uneven_illumination"
    explanation = (
        "The illumination is brighter on one side or in the middle of the field (vignetting, "
        "a tilted lamp or condenser): every pixel, cell or background, is scaled by a smooth "
        "surface."
    )
    signature = "row/column trends of the standardised residual in media and cells alike"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._basis = _basis(geometry.yn, geometry.xn)

    def n_params(self) -> int:
        return 5

    def mean(self, theta, mu, parts, geo):
        return mu * (1.0 + weighted_sum(theta, self._basis))[None]

    def summary(self, theta, mu):
        surface = weighted_sum(theta, self._basis)
        return {
            "peak_to_peak_fraction": float(surface.max() - surface.min()),
            "coefficients": [float(c) for c in theta],
            "terms": ["x", "y", "x^2", "y^2", "xy"],
        }

    def magnitude(self, summary):
        return summary["peak_to_peak_fraction"]


def stage(parameters: dict) -> Stage:
    """Forward-model stage multiplying the clean image by the fitted surface."""
    coeffs = np.asarray(parameters["coefficients"], float)

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        rows, cols = image.shape[-2:]
        yn = np.broadcast_to(np.linspace(-1, 1, rows)[:, None], (rows, cols))
        xn = np.broadcast_to(np.linspace(-1, 1, cols)[None, :], (rows, cols))
        return image * (1.0 + np.tensordot(coeffs, _basis(yn, xn), axes=1)).astype(np.float32)

    return Stage(UnevenIllumination.name, False, dict(parameters), apply)
