"""Focus that changes across the field (a tilted sample or coverslip)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.optics.forward import Stage

__all__ = ["DefocusGradient"]


def _laplacian(mu: np.ndarray) -> np.ndarray:
    return np.stack([ndimage.laplace(frame, mode="nearest") for frame in mu])


class DefocusGradient(Effect):
    """Extra blur whose variance varies linearly over the field (eq. 14 per position).

    A Gaussian blur of small variance ``s2`` changes the image by ``s2 / 2 * lap(mu)``
    (heat equation), so ``mu + (t_x x + t_y y) / 2 * lap(mu)`` with ``x, y`` in
    [-1, 1] and ``t`` the change of blur variance (px^2) from the field's centre to
    its edge. The mean blur is the base fit's defocus (a nuisance parameter).
    """

    name = "defocus_gradient"
    explanation = (
        "The sample is not equally in focus everywhere (a tilted slide, coverslip or "
        "trench): edges are sharper on one side of the field than on the other."
    )
    signature = "edge-band residual (cell edges) changing sign along the field"

    def n_params(self) -> int:
        return 2

    def steps(self, theta):
        return np.full(2, 0.05)

    def mean(self, theta, mu, parts, geo):
        plane = theta[0] * geo.xn + theta[1] * geo.yn
        return mu + 0.5 * plane[None] * _laplacian(mu)

    def summary(self, theta, mu):
        return {
            "blur_variance_slope_x_px2": float(theta[0]),
            "blur_variance_slope_y_px2": float(theta[1]),
            "blur_variance_change_px2": float(np.hypot(theta[0], theta[1])),
        }

    def magnitude(self, summary):
        return summary["blur_variance_change_px2"]


def stage(parameters: dict) -> Stage:
    """Forward-model stage blurring the clean image by the fitted position-dependent amount."""
    tx = float(parameters["blur_variance_slope_x_px2"])
    ty = float(parameters["blur_variance_slope_y_px2"])

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        rows, cols = image.shape[-2:]
        plane = tx * np.linspace(-1, 1, cols)[None, :] + ty * np.linspace(-1, 1, rows)[:, None]
        return (image + 0.5 * plane * ndimage.laplace(image, mode="nearest")).astype(np.float32)

    return Stage(DefocusGradient.name, False, dict(parameters), apply)
