"""Pixel weights of the scene fit: the camera's variance (eq. 17-19).

The likelihood of the scene fit is Gaussian with the camera's variance
``var = K mu + sigma_0^2`` (``mu`` the clean signal above the baseline in ADU, ``K``
the system gain in ADU per electron, ``sigma_0^2 = (K sigma_d)^2 + 1/12`` the read
and quantisation noise, eq. 17-19). Clipped pixels carry no Gaussian information
and are censored (left out): :func:`~napari_symbac.fit.camera_estimate.censored_pixels`
finds them, and :func:`~napari_symbac.fit.camera_estimate.estimate_camera` measures the
camera.
"""

from __future__ import annotations

import numpy as np

from napari_symbac.settings import Camera

__all__ = ["variance"]


def variance(clean_adu: np.ndarray, camera: Camera) -> np.ndarray:
    """Per-pixel variance (ADU^2) of eq. 17 for a clean signal above the baseline."""
    s = camera.sensitivity_adu_per_e
    return s * np.maximum(clean_adu, 0.0) + (s * camera.dark_noise_e) ** 2 + 1 / 12
