"""Photon transfer differing from the declared camera (gain, read noise).

The pixel variance is judged on the **high-pass residual**, not on the residual itself:
a misfit of the mean (a cell outline the model lacks, a smooth background it does not
carry) inflates ``r^2`` and would be named "camera noise". The high-pass
(:func:`high_pass_matrix`) removes every cosine mode of the frame (DCT-II) whose frequency
along the rows **or** along the columns is below :data:`CUTOFF_CYCLES_PER_PX`: misfit
smooth in either direction (an edge along a cell's side, a background level) goes,
independent pixel noise keeps a known share of its variance (the projection's diagonal),
and the squared high-pass residuals lose little information to their correlation (the
projection is idempotent). On the real SyMBac trench 75 % of the residual's power lies
below 0.1 cycles/px (docs/fitting.md), the noise above it.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import fft, optimize

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.settings import Camera

__all__ = [
    "CUTOFF_CYCLES_PER_PX",
    "CameraNoise",
    "fit_factors",
    "high_pass",
    "high_pass_matrix",
    "updated_camera",
]

#: Cosine modes below this frequency along either axis are removed from the residual
#: before its variance is compared with the camera's (0.15: wavelengths above 6.7 px).
CUTOFF_CYCLES_PER_PX = 0.15


@lru_cache(maxsize=16)
def high_pass_matrix(n: int) -> np.ndarray:
    """``I - P`` along one axis of ``n`` pixels: ``P`` projects on the orthonormal DCT-II
    modes ``k < 2 n CUTOFF`` (mode ``k`` has ``k / 2n`` cycles per pixel). Symmetric and
    idempotent."""
    basis = fft.dct(np.eye(n), type=2, norm="ortho", axis=0)  # rows: modes
    low = basis[: min(n, math.ceil(2 * n * CUTOFF_CYCLES_PER_PX))]
    return np.eye(n) - low.T @ low


class CameraNoise(Effect):
    """Pixel variance ``g s mu + g^2 (s sigma_d)^2`` instead of eq. 17's ``g = 1``.

    ``g`` is the ratio of the camera's true sensitivity (ADU per electron) to the one
    given: the photon-transfer slope scales by ``g`` and the read-noise variance in ADU^2
    by ``g^2`` (the read noise in electrons unchanged). One parameter: on the high-pass
    residual a free read-noise factor beside it trades off against ``g`` (the two were
    recovered to 30-60 % on the concealed benchmark's 12 % gain error, ``g`` alone to
    ~10 %).
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
        return 1

    def summary(self, theta, mu):
        return {"gain_ratio": float(theta[0]), "read_variance_ratio": float(theta[1])}

    def magnitude(self, summary):
        return summary["gain_ratio"] - 1.0


def updated_camera(camera: Camera, parameters: dict) -> Camera:
    """The camera whose eq. 17 variance has the fitted slope and intercept (with the
    fitted ``gain_ratio`` alone: its sensitivity times the ratio, the same read noise in
    electrons)."""
    s = camera.sensitivity_adu_per_e * float(parameters["gain_ratio"])
    read_adu = camera.sensitivity_adu_per_e * camera.dark_noise_e
    read_adu *= math.sqrt(max(float(parameters["read_variance_ratio"]), 1e-6))
    return Camera(
        baseline_adu=camera.baseline_adu,
        sensitivity_adu_per_e=s,
        dark_noise_e=read_adu / s,
        bit_depth=camera.bit_depth,
    )


def high_pass(
    residual: np.ndarray,
    mu: np.ndarray,
    camera: Camera,
    valid: np.ndarray,
    centres: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Squared high-pass residual, its expectation's two parts and its correlation factor.

    Each frame's residual ``R`` becomes ``Ky R Kx`` (:func:`high_pass_matrix`; invalid
    pixels enter as 0), whose expected square at a pixel is ``sum Ky^2 v Kx^2`` (squares
    taken element by element) for independent pixel noise of variance ``v`` (eq. 17).

    Parameters
    ----------
    residual, mu, valid
        ``(T, Y, X)``: data minus model mean, the mean above the baseline (ADU), and
        the pixels that are data (not clipped).
    centres
        The pixels whose high-pass values count (default: the valid ones). A fit on
        three of the four held-out folds passes its own pixels: their high-pass values
        still mix in the held-out fold's residuals, which the held-out check's parametric
        bootstrap repeats, so its null bound includes that.

    Returns
    -------
    r2, shot, unit, overlap
        On the counted pixels: the squared high-pass residual; its expectation's photon
        part (from ``s mu``) and its part per unit of a constant pixel variance, so that
        ``E[r2] = g shot + (g^2 (s sigma_d)^2 + 1/12) unit`` with the factor of
        :class:`CameraNoise` (read noise, then rounding); and ``1 / diag(K)``, by which
        neighbouring squares' correlation inflates the variance of a sum of them.
    """
    s = camera.sensitivity_adu_per_e
    counted = valid if centres is None else valid & centres
    out: list[list[np.ndarray]] = [[], [], [], []]
    for r, m, ok, keep in zip(residual, mu, valid, counted, strict=True):
        ky, kx = high_pass_matrix(r.shape[0]), high_pass_matrix(r.shape[1])
        ky2, kx2 = ky**2, kx**2
        filtered = ky @ np.where(ok, r, 0.0) @ kx
        shot = ky2 @ np.where(ok, s * np.maximum(m, 0.0), 0.0) @ kx2
        read = ky2 @ ok.astype(float) @ kx2  # per unit of pixel variance
        diag = np.outer(np.diag(ky), np.diag(kx))
        for part, values in zip(out, (filtered**2, shot, read, 1.0 / diag), strict=True):
            part.append(values[keep])
    r2, shot, unit, overlap = (np.concatenate(part) for part in out)
    return r2, shot, unit, overlap


def score(
    residual: np.ndarray, mu: np.ndarray, camera: Camera, valid: np.ndarray
) -> tuple[float, float]:
    """Score of ``g`` at ``g = 1`` and its variance, from the high-pass residual.

    The Gaussian score of the squared high-pass residuals (:func:`high_pass`); its
    variance is the usual information with each pixel's term times its ``overlap``,
    since neighbouring squares are correlated.
    """
    r2, shot, unit, overlap = high_pass(residual, mu, camera, valid)
    read = unit * (camera.sensitivity_adu_per_e * camera.dark_noise_e) ** 2
    v = shot + read + unit / 12.0
    dv = shot + 2.0 * read  # d/dg of g shot + g^2 read at g = 1
    u = 0.5 * float(np.sum(dv * (r2 / v**2 - 1.0 / v)))
    info = 0.5 * float(np.sum(overlap * (dv / v) ** 2))
    return u, info


def fit_factors(
    residual: np.ndarray,
    mu: np.ndarray,
    camera: Camera,
    valid: np.ndarray,
    centres: np.ndarray | None = None,
) -> tuple[float, float]:
    """The sensitivity ratio ``g`` fitted to the high-pass residual, as the variance's
    photon and read-noise factors ``(g, g^2)``.

    Gaussian pseudo-likelihood of the squared high-pass residuals (unbiased: ``E[r2] =
    g shot + g^2 read + q`` whatever the correlation of neighbours); ``valid`` and
    ``centres`` as in :func:`high_pass`.
    """
    r2, shot, unit, _ = high_pass(residual, mu, camera, valid, centres)
    if r2.size == 0:
        return 1.0, 1.0
    read = unit * (camera.sensitivity_adu_per_e * camera.dark_noise_e) ** 2
    quantisation = unit / 12.0

    def nll(log_g: float) -> float:
        g = math.exp(log_g)
        v = g * shot + g * g * read + quantisation
        return float(np.sum(r2 / v + np.log(v)))

    res = optimize.minimize_scalar(nll, bounds=(-3.0, 3.0), method="bounded")
    g = math.exp(float(res.x))
    return g, g * g
