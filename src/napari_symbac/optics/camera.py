"""Camera noise (supplement section 6, eq. 17-19; EMVA1288 linear model)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from napari_symbac.settings import Camera

__all__ = [
    "DarkCalibration",
    "apply_camera_noise",
    "apply_gaussian_noise",
    "calibrate_camera",
    "quantise",
]


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if not np.all(np.isfinite(image)):
        raise ValueError("image contains NaN or infinite values")
    return image


def quantise(image_adu: np.ndarray, camera: Camera) -> np.ndarray:
    """Round to whole ADU and clip to ``[0, 2**bit_depth - 1]``; returns uint16."""
    return np.clip(np.rint(image_adu), 0, camera.max_adu).astype(np.uint16)


def apply_camera_noise(
    signal_adu: np.ndarray, camera: Camera, rng: np.random.Generator
) -> np.ndarray:
    """EMVA1288 linear camera, eq. 17.

    With ``s`` the sensitivity (ADU/e-), the photo-electrons are
    ``A ~ Poisson(S / s)``, the dark signal ``B ~ N(0, sigma_d^2)`` (electrons) and
    the output ``s (A + B) + mu_d``, rounded and clipped to the bit depth. Here
    ``S`` is the noise-free signal in ADU above the baseline ``mu_d``
    (``Camera.baseline_adu``); eq. 17 writes the baseline inside ``B`` in electrons,
    which is the same thing. Negative signal is treated as zero light. The
    temporal variance is therefore ``s (mean - mu_d) + (s sigma_d)^2``: a
    photon-transfer line of slope ``s`` and intercept the dark noise variance.

    Returns
    -------
    numpy.ndarray
        uint16 image.
    """
    signal = _check_image(signal_adu)
    s = camera.sensitivity_adu_per_e
    electrons = rng.poisson(np.maximum(signal, 0.0) / s).astype(np.float64)
    dark = rng.normal(0.0, camera.dark_noise_e, size=signal.shape)
    return quantise(s * (electrons + dark) + camera.baseline_adu, camera)


def apply_gaussian_noise(
    signal_adu: np.ndarray, camera: Camera, sd_adu: float, rng: np.random.Generator
) -> np.ndarray:
    """The plain alternative: ``S + mu_d + N(0, sd^2)``, rounded and clipped (uint16)."""
    signal = _check_image(signal_adu)
    if not (math.isfinite(sd_adu) and sd_adu >= 0):
        raise ValueError(f"sd_adu must be zero or positive, got {sd_adu!r}")
    return quantise(signal + camera.baseline_adu + rng.normal(0.0, sd_adu, signal.shape), camera)


@dataclass(frozen=True)
class DarkCalibration:
    """Camera parameters estimated from dark frames (eq. 18-19).

    Attributes
    ----------
    baseline_adu
        Mean dark level ``s mu_d`` in ADU (eq. 18 times ``s``).
    dark_noise_e
        Dark noise ``sigma_d`` in electrons.
    dark_noise_adu
        Dark noise in ADU (``s sigma_d``).
    sensitivity_adu_per_e
        The sensitivity the estimate assumed.
    n_frames
        Number of dark frames used.
    """

    baseline_adu: float
    dark_noise_e: float
    dark_noise_adu: float
    sensitivity_adu_per_e: float
    n_frames: int

    def to_camera(self, bit_depth: int = 16) -> Camera:
        """A :class:`~napari_symbac.settings.Camera` with these parameters."""
        return Camera(
            baseline_adu=self.baseline_adu,
            sensitivity_adu_per_e=self.sensitivity_adu_per_e,
            dark_noise_e=self.dark_noise_e,
            bit_depth=bit_depth,
        )


def calibrate_camera(dark_frames: np.ndarray, sensitivity_adu_per_e: float) -> DarkCalibration:
    """Estimate baseline and dark noise from your own dark images (eq. 18-19).

    Parameters
    ----------
    dark_frames
        ``(K, M, N)`` stack (or a single ``(M, N)`` frame) taken with the shutter
        closed, in ADU.
    sensitivity_adu_per_e
        The camera's sensitivity ``s`` (from its data sheet or a photon-transfer
        measurement); it converts ADU to electrons.

    Notes
    -----
    Eq. 18: the mean dark level ``mu_d`` is the mean of all dark pixels (divided by
    ``s`` for electrons). Eq. 19 takes the dark variance from the spatial spread of a
    single frame; written with consistent units, ``sigma_d = sd(D_0) / s`` electrons.
    With ``K >= 2`` frames the per-pixel temporal variance (averaged over pixels) is
    used instead: it is the same quantity under eq. 19's assumption of stationary,
    homogeneous noise, but it is not inflated by fixed-pattern offsets between
    pixels.
    """
    frames = np.asarray(dark_frames, dtype=np.float64)
    if frames.ndim == 2:
        frames = frames[None]
    if frames.ndim != 3 or frames.shape[1] < 2 or frames.shape[2] < 2:
        raise ValueError(f"dark_frames must be (K, M, N) or (M, N), got shape {frames.shape}")
    if not np.all(np.isfinite(frames)):
        raise ValueError("dark_frames contain NaN or infinite values")
    s = float(sensitivity_adu_per_e)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"sensitivity_adu_per_e must be positive, got {sensitivity_adu_per_e!r}")
    baseline = float(frames.mean())  # eq. 18 (in ADU)
    if frames.shape[0] >= 2:
        variance = float(frames.var(axis=0, ddof=1).mean())
    else:
        variance = float(frames[0].var(ddof=1))  # eq. 19
    sd_adu = math.sqrt(variance)
    return DarkCalibration(
        baseline_adu=baseline,
        dark_noise_e=sd_adu / s,
        dark_noise_adu=sd_adu,
        sensitivity_adu_per_e=s,
        n_frames=int(frames.shape[0]),
    )
