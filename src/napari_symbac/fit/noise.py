"""Pixel weights of the scene fit: censored pixels and the camera's variance (eq. 17-19).

The likelihood of the scene fit is Gaussian with the camera's variance
``var = K mu + sigma_0^2`` (``mu`` the clean signal above the baseline in ADU, ``K``
the system gain in ADU per electron, ``sigma_0^2 = (K sigma_d)^2 + 1/12`` the read
and quantisation noise, eq. 17-19). Clipped pixels carry no Gaussian information
and are censored (left out).
"""

from __future__ import annotations

import math

import numpy as np

from napari_symbac.settings import Camera

__all__ = ["camera_from_residuals", "default_valid", "variance"]


def default_valid(image: np.ndarray, modality: str, bit_depth: int = 16) -> np.ndarray:
    """Pixels to use in the likelihood (False = censored).

    Left out: pixels at the image's maximum when that value is the bit-depth
    maximum or holds more than 0.1 % of the pixels (saturated or clipped by
    processing), and, in fluorescence, pixels at 0 when they hold more than 0.1 %
    of the pixels (background subtraction clipped at zero).
    """
    image = np.asarray(image)
    valid = np.ones(image.shape, bool)
    top = image.max()
    at_top = image == top
    if top >= 2**bit_depth - 1 or at_top.mean() > 1e-3:
        valid &= ~at_top
    if modality == "fluorescence":
        at_zero = image <= 0
        if at_zero.mean() > 1e-3:
            valid &= ~at_zero
    if not valid.any():
        raise ValueError("every pixel of the image is clipped: no pixel is left to fit")
    return valid


def variance(clean_adu: np.ndarray, camera: Camera) -> np.ndarray:
    """Per-pixel variance (ADU^2) of eq. 17 for a clean signal above the baseline."""
    s = camera.sensitivity_adu_per_e
    return s * np.maximum(clean_adu, 0.0) + (s * camera.dark_noise_e) ** 2 + 1 / 12


def camera_from_residuals(
    clean_adu: np.ndarray, residual_adu: np.ndarray, baseline_adu: float, bit_depth: int = 16
) -> Camera:
    """Gain and read noise from the residual variance against the model mean.

    The squared residuals are averaged in 20 bins of equal pixel count along the
    clean signal ``mu`` and the line ``var = K mu + sigma_0^2`` (eq. 17) is fitted to
    the bin means, weighted by their precision (``count / var^2``). ``K`` is the
    system gain; ``sigma_0^2 = (K sigma_d)^2 + 1/12`` gives the read noise. With one
    frame the offset is not separable from the read noise, so ``baseline_adu`` is
    taken as given. When the image spans too narrow a range of ``mu`` to see a
    slope, the variance is taken as constant (gain from the shot-noise floor is not
    identifiable: ``K`` is set so that the read noise carries it all).

    Parameters
    ----------
    clean_adu
        Model mean above the baseline at the used pixels.
    residual_adu
        ``real - model`` at the same pixels.
    baseline_adu, bit_depth
        Kept in the returned :class:`Camera`.
    """
    mu = np.asarray(clean_adu, float).ravel()
    r2 = np.asarray(residual_adu, float).ravel() ** 2
    order = np.argsort(mu, kind="stable")
    bins = np.array_split(order, 20)
    m = np.array([mu[b].mean() for b in bins if b.size])
    v = np.array([r2[b].mean() for b in bins if b.size])
    n = np.array([b.size for b in bins if b.size], float)
    w = n / np.maximum(v, 1e-12) ** 2
    design = np.stack([m, np.ones_like(m)], axis=1)
    gain, floor = np.linalg.lstsq(design * np.sqrt(w)[:, None], v * np.sqrt(w), rcond=None)[0]
    if not (math.isfinite(gain) and gain > 1e-6) or m.max() - m.min() < 1e-6:
        gain, floor = 1e-3, float(np.mean(r2))
    floor = max(float(floor), 1 / 12)
    dark_e = math.sqrt(max(floor - 1 / 12, 0.0)) / gain
    return Camera(
        baseline_adu=float(baseline_adu),
        sensitivity_adu_per_e=float(gain),
        dark_noise_e=float(dark_e),
        bit_depth=int(bit_depth),
    )
