"""Camera noise (supplement section 6, eq. 17-19; EMVA1288 linear model)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from napari_symbac.settings import Camera

__all__ = [
    "GAUSSIAN_SKEWNESS_MAX",
    "DarkCalibration",
    "apply_camera_noise",
    "apply_gaussian_noise",
    "calibrate_camera",
    "exact_poisson_range",
    "quantise",
    "shot_read_skewness",
    "standard_normal_f32",
]


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if not np.all(np.isfinite(image)):
        raise ValueError("image contains NaN or infinite values")
    return image


def quantise(image_adu: np.ndarray, camera: Camera) -> np.ndarray:
    """Round to whole ADU and clip to ``[0, 2**bit_depth - 1]``; returns uint16."""
    rounded = np.rint(image_adu)
    np.clip(rounded, 0, camera.max_adu, out=rounded)
    return rounded.astype(np.uint16)


#: Largest skewness of a pixel's exact count distribution (Poisson shot noise plus
#: Gaussian read noise) for which :func:`apply_camera_noise` draws one Gaussian of the
#: same mean and variance instead: the two distributions' CDFs then differ by at most
#: ``0.0665 * 0.05 = 0.0033`` (the first Edgeworth term, ``skewness / (6 sqrt(2 pi))``).
GAUSSIAN_SKEWNESS_MAX = 0.05


def shot_read_skewness(electrons: np.ndarray, dark_noise_e: float) -> np.ndarray:
    """Skewness of ``Poisson(lambda) + N(0, sigma_d^2)``: ``lambda / (lambda + sigma_d^2)^1.5``.

    The third cumulant of the Poisson part is ``lambda``, the Gaussian adds none; 0
    where the variance is 0 (no light, no read noise: the count is exactly 0).
    """
    lam = np.asarray(electrons, dtype=np.float64)
    var = lam + float(dark_noise_e) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        skew = lam / (var * np.sqrt(var))
    return np.where(var > 0, skew, 0.0)


@functools.lru_cache(maxsize=64)
def exact_poisson_range(dark_noise_e: float, max_skewness: float) -> tuple[float, float] | None:
    """Expected electrons ``(low, high)`` between which the skewness exceeds ``max_skewness``.

    :func:`shot_read_skewness` rises from 0 at ``lambda = 0`` to its largest value,
    ``2 / (3^1.5 sigma_d)`` at ``lambda = 2 sigma_d^2``, and falls as ``lambda^-0.5``
    beyond, so the pixels that need an exact Poisson draw are those with ``low <
    lambda < high``; ``None`` when there are none (``sigma_d >= 0.385 / max_skewness``,
    7.7 e- for the default 0.05). Both ends are found by bisection to float64
    precision.
    """
    from scipy.optimize import brentq

    sd2 = float(dark_noise_e) ** 2
    if max_skewness <= 0:
        return (0.0, math.inf)
    peak = 2.0 * sd2
    if sd2 > 0 and float(shot_read_skewness(peak, dark_noise_e)) <= max_skewness:
        return None

    def excess(lam: float) -> float:
        return float(shot_read_skewness(lam, dark_noise_e)) - max_skewness

    low = 0.0 if sd2 == 0 else brentq(excess, 0.0, peak, xtol=1e-12, rtol=1e-15)
    far = max(peak, 1.0)
    while excess(far) > 0:
        far *= 4.0
    high = brentq(excess, max(peak, 1e-300) if sd2 > 0 else 1e-300, far, xtol=1e-12, rtol=1e-15)
    return (low, high)


def apply_camera_noise(
    signal_adu: np.ndarray,
    camera: Camera,
    rng: np.random.Generator,
    *,
    max_skewness: float = GAUSSIAN_SKEWNESS_MAX,
) -> np.ndarray:
    """EMVA1288 linear camera, eq. 17.

    With ``s`` the sensitivity (ADU/e-), the photo-electrons are
    ``A ~ Poisson(lambda)``, ``lambda = S / s``, the dark signal ``B ~ N(0,
    sigma_d^2)`` (electrons) and the output ``s (A + B) + mu_d``, rounded and clipped
    to the bit depth. Here ``S`` is the noise-free signal in ADU above the baseline
    ``mu_d`` (``Camera.baseline_adu``); eq. 17 writes the baseline inside ``B`` in
    electrons, which is the same thing. Negative signal is treated as zero light. The
    temporal variance is therefore ``s (mean - mu_d) + (s sigma_d)^2``: a
    photon-transfer line of slope ``s`` and intercept the dark noise variance.

    Where ``A + B`` is indistinguishable from a Gaussian (its skewness ``lambda /
    (lambda + sigma_d^2)^1.5``, :func:`shot_read_skewness`, at most ``max_skewness``;
    with the default 0.05 the CDFs differ by at most 0.0033) it is drawn as one
    Gaussian of the same mean and variance, ``lambda + sqrt(lambda + sigma_d^2) Z``;
    elsewhere (low counts with little read noise, e.g. dim fluorescence) ``A`` is an
    exact Poisson draw and ``B = sigma_d Z`` (:func:`exact_poisson_range`). ``Z`` is
    one float32 standard normal per pixel (:func:`standard_normal_f32`), drawn first
    for the whole image, then the Poisson counts of the exact pixels in row-major
    order: the same seed gives the same image. The arithmetic is float32 (ADU up to
    65535 are exact; rounding moves a value by about 1e-4 ADU). ``max_skewness=0``
    draws every pixel's Poisson count (the approximation off). With the default
    camera (``sigma_d = 8`` e-) the skewness never exceeds 0.048, whatever the
    signal, so every pixel takes the single Gaussian draw.

    Returns
    -------
    numpy.ndarray
        uint16 image.
    """
    signal = np.asarray(signal_adu, dtype=np.float32)
    if not math.isfinite(np.add.reduce(signal, axis=None)) and not np.all(np.isfinite(signal)):
        raise ValueError("image contains NaN or infinite values")
    if not (math.isfinite(max_skewness) and max_skewness >= 0):
        raise ValueError(f"max_skewness must be zero or positive, got {max_skewness!r}")
    s = camera.sensitivity_adu_per_e
    dark_e = float(camera.dark_noise_e)
    # in ADU: mean s lambda (the lit signal), spread s sqrt(lambda + sigma_d^2)
    z = standard_normal_f32(rng, (signal.size,))
    mean = np.maximum(signal.reshape(-1), np.float32(0.0))
    spread = mean * np.float32(s)
    spread += np.float32((s * dark_e) ** 2)
    np.sqrt(spread, out=spread)
    exact_range = exact_poisson_range(dark_e, float(max_skewness))
    if exact_range is not None:
        exact = (mean > exact_range[0] * s) & (mean < exact_range[1] * s)
        if exact.any():
            # s (A + B), A ~ Poisson(lambda), B = sigma_d Z
            counts = rng.poisson(mean[exact].astype(np.float64) / s)
            mean[exact] = (s * counts).astype(np.float32)
            spread[exact] = np.float32(s * dark_e)
    spread *= z
    spread += mean
    spread += np.float32(camera.baseline_adu)
    return quantise(spread, camera).reshape(signal.shape)


def standard_normal_f32(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal float32 numbers by the Box-Muller transform of float32 uniforms.

    ``Z = sqrt(-2 ln(1 - U1)) (cos, sin)(2 pi U2)`` on pairs of ``rng.random(dtype=
    float32)`` (24-bit) uniforms, in numpy's vectorised float32 ``log``, ``sin`` and
    ``cos``: about three times the speed of ``rng.standard_normal(dtype=float32)``
    (the camera stage's largest cost). ``|Z| <= 5.77`` (``1 - U1 >= 2^-24``), which
    cuts a tail of probability ``8e-9``; elsewhere the distribution is the normal one
    (tests/optics/test_camera.py: moments, quantiles and a KS test on 10^6 numbers).
    The same generator state gives the same numbers.
    """
    n = math.prod(shape)
    half = (n + 1) // 2
    uniform = rng.random((2, half), dtype=np.float32)
    radius = np.log1p(-uniform[0])
    radius *= np.float32(-2.0)
    np.sqrt(radius, out=radius)
    angle = uniform[1]
    angle *= np.float32(2.0 * math.pi)
    z = np.empty(2 * half, np.float32)
    np.cos(angle, out=z[:half])
    np.sin(angle, out=z[half:])
    z[:half] *= radius
    z[half:] *= radius
    return z[:n].reshape(shape)


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
