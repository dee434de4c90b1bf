"""Photon transfer differing from the declared camera (gain, read noise)."""

from __future__ import annotations

import math

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.settings import Camera

__all__ = ["CameraNoise", "updated_camera"]


class CameraNoise(Effect):
    """Pixel variance ``g s mu + h (s sigma_d)^2`` instead of eq. 17's ``g = h = 1``.

    ``g`` scales the photon-transfer slope (the camera's sensitivity, or an EM/excess
    noise factor) and ``h`` the read-noise variance.
    """

    name = "camera_noise"
    explanation = (
        "The camera is noisier (or quieter) than the gain and read noise given (or measured "
        "from the image before the fit): the pixel-to-pixel scatter grows with brightness at "
        "a different rate (photon transfer)."
    )
    signature = "variance of the standardised residual against the mean level (photon transfer)"
    kind = "variance"

    def n_params(self) -> int:
        return 2

    def summary(self, theta, mu):
        return {"gain_ratio": float(theta[0]), "read_variance_ratio": float(theta[1])}

    def magnitude(self, summary):
        return summary["gain_ratio"] - 1.0


def updated_camera(camera: Camera, parameters: dict) -> Camera:
    """The camera whose eq. 17 variance has the fitted slope and intercept."""
    s = camera.sensitivity_adu_per_e * float(parameters["gain_ratio"])
    read_adu = camera.sensitivity_adu_per_e * camera.dark_noise_e
    read_adu *= math.sqrt(max(float(parameters["read_variance_ratio"]), 1e-6))
    return Camera(
        baseline_adu=camera.baseline_adu,
        sensitivity_adu_per_e=s,
        dark_noise_e=read_adu / s,
        bit_depth=camera.bit_depth,
    )


def score(
    r: np.ndarray, v: np.ndarray, mu: np.ndarray, camera: Camera
) -> tuple[np.ndarray, np.ndarray]:
    """Score and information of ``(g, h)`` at ``g = h = 1`` for Gaussian pixels."""
    s = camera.sensitivity_adu_per_e
    dv = np.stack([s * np.maximum(mu, 0.0), np.full_like(mu, (s * camera.dark_noise_e) ** 2)])
    u = 0.5 * dv @ (r**2 / v**2 - 1.0 / v)
    info = 0.5 * (dv / v) @ (dv / v).T
    return u, info
