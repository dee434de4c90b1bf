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
from scipy import ndimage

from napari_symbac.settings import Camera

__all__ = ["LEVEL_BOX_PX", "expected_level", "variance"]


def variance(clean_adu: np.ndarray, camera: Camera) -> np.ndarray:
    """Per-pixel variance (ADU^2) of eq. 17 for a clean signal above the baseline."""
    s = camera.sensitivity_adu_per_e
    return s * np.maximum(clean_adu, 0.0) + (s * camera.dark_noise_e) ** 2 + 1 / 12


#: Side (camera pixels) of the box whose mean stands for a pixel's expected level in the
#: first round's weights: 3 x 3 divides a pixel's noise by 3 and keeps most of a septum's
#: 1-2 px dip between touching fluorescent cells (a 5 x 5 box spread the bright cells'
#: level over the dip, and the fit of a touching synthetic colony merged two of its
#: four cells: tests/fit/test_lineage.py).
LEVEL_BOX_PX = 3


def expected_level(y: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each pixel's expected signal above the baseline (ADU, flat, >= 0) for the first
    round's variance: the mean of the valid pixels in a :data:`LEVEL_BOX_PX` box.

    The pixel's own value is a noisy stand-in for its mean: where it falls below the
    baseline, eq. 17 gives it the read noise alone, and with no measurable read noise
    1/12 ADU^2, so a few hundred low background pixels outweighed the whole frame
    (found on ColiCoords ds3 frame 0: the media intensity solved to 0 against a
    background 168 ADU above the baseline, the moves then judged with a dispersion of
    1.2e5 and a real cell removed).
    """
    image = y.reshape(valid.shape)
    inside = valid.astype(np.float64)
    total = ndimage.uniform_filter(np.where(valid, image, 0.0), LEVEL_BOX_PX, mode="nearest")
    count = ndimage.uniform_filter(inside, LEVEL_BOX_PX, mode="nearest")
    level = np.divide(total, count, out=np.maximum(image, 0.0), where=count > 0)
    return np.maximum(level, 0.0).ravel()
