"""Checks of a real recording that need no model.

They come first in a diagnosis: clipped pixels, gaps in the pixel values (bit depth or
rescaling), hot pixels, and a single-image Poisson-Gaussian noise fit (Foi et al.
2008) that estimates the camera's gain and read noise from the image itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy import ndimage

from napari_symbac.fit.inputs import as_image_stack

__all__ = ["ImageChecks", "NoiseFit", "check_image", "estimate_noise_sd", "fit_poisson_gaussian"]


@dataclass(frozen=True)
class NoiseFit:
    """Pixel variance as a linear function of the mean: ``var = gain * mean + offset``.

    For a linear camera ``gain`` is the sensitivity in ADU/e- (the EMVA1288 photon
    transfer slope) and ``offset = sigma_d^2 s^2 - gain * baseline``.
    """

    gain: float
    offset: float
    n_bins: int


@dataclass(frozen=True)
class ImageChecks:
    """Findings of :func:`check_image`.

    Attributes
    ----------
    clipped_high_fraction, clipped_low_fraction
        Fraction of pixels sitting exactly at the image maximum / minimum when that
        value holds a spike of the histogram (saturation, background subtraction).
    unused_value_fraction
        For integer images, the fraction of values between min and max that never
        occur (gaps from rescaling or a coarse digitiser).
    hot_pixels
        ``(row, column)`` of pixels far above their neighbourhood in every frame
        (needs at least 3 frames; empty otherwise).
    noise
        Photon-transfer fit, or ``None`` when the image has too little flat area.
    """

    clipped_high_fraction: float
    clipped_low_fraction: float
    unused_value_fraction: float
    hot_pixels: tuple[tuple[int, int], ...]
    noise: NoiseFit | None

    def summary(self) -> list[str]:
        """Human-readable findings, one line each."""
        lines = []
        if self.clipped_high_fraction > 1e-3:
            lines.append(f"{100 * self.clipped_high_fraction:.1f} % of pixels clipped high")
        if self.clipped_low_fraction > 1e-3:
            lines.append(f"{100 * self.clipped_low_fraction:.1f} % of pixels clipped low")
        if self.unused_value_fraction > 0.5:
            lines.append(
                f"{100 * self.unused_value_fraction:.0f} % of grey values between min and max "
                "never occur (rescaled or coarsely digitised data)"
            )
        if self.hot_pixels:
            lines.append(f"{len(self.hot_pixels)} hot pixel(s)")
        if self.noise is not None:
            lines.append(
                f"noise: variance = {self.noise.gain:.3g} x mean + {self.noise.offset:.3g}"
            )
        return lines


def _spike_fraction(stack: np.ndarray, value: float) -> float:
    """Fraction of pixels equal to ``value`` if that value is a spike of the histogram.

    A spike holds over five times as many pixels as the median of the ten nearest
    other grey values (clipping piles pixels onto one value; a smooth tail does not).
    """
    values, counts = np.unique(stack, return_counts=True)
    index = int(np.searchsorted(values, value))
    others = counts[max(0, index - 10) : index] if index else counts[1:11]
    if index and index < len(values) - 1:
        others = np.concatenate([others, counts[index + 1 : index + 11]])
    if others.size == 0 or counts[index] < 10:
        return 0.0
    return counts[index] / stack.size if counts[index] > 5 * np.median(others) else 0.0


def fit_poisson_gaussian(
    stack: np.ndarray, *, n_bins: int = 20, clipped: np.ndarray | None = None
) -> NoiseFit | None:
    """Fit ``variance = gain * mean + offset`` from one image (photon transfer).

    Local means and variances are taken in flat 5 x 5 neighbourhoods (those whose
    smoothed gradient is in the lowest third and that hold no clipped pixel), binned
    by mean, and the per-bin mean variance is fitted by least squares. The gradient is
    taken at a scale of 3 pixels so that the selection does not favour patches that
    happen to be quiet, which would bias the slope low.
    """
    means, variances = [], []
    for index, frame in enumerate(stack):
        local_mean = ndimage.uniform_filter(frame, 5)
        local_var = ndimage.uniform_filter(frame**2, 5) - local_mean**2
        gradient = ndimage.gaussian_gradient_magnitude(frame, 3.0)
        flat = gradient <= np.quantile(gradient, 1 / 3)
        if clipped is not None:
            flat &= ~ndimage.binary_dilation(clipped[index], np.ones((5, 5), bool))
        flat[:3] = flat[-3:] = False
        flat[:, :3] = flat[:, -3:] = False
        means.append(local_mean[flat])
        variances.append(local_var[flat] * 25 / 24)
    mean = np.concatenate(means)
    variance = np.concatenate(variances)
    if mean.size < 10 * n_bins:
        return None
    edges = np.quantile(mean, np.linspace(0.02, 0.98, n_bins + 1))
    centres, medians = [], []
    for low, high in pairwise(edges):
        inside = (mean >= low) & (mean < high)
        if inside.sum() >= 10:
            centres.append(mean[inside].mean())
            medians.append(variance[inside].mean())
    if len(centres) < 3 or np.ptp(centres) <= 0:
        return None
    design = np.column_stack([centres, np.ones(len(centres))])
    (gain, offset), *_ = np.linalg.lstsq(design, np.asarray(medians), rcond=None)
    return NoiseFit(gain=float(gain), offset=float(offset), n_bins=len(centres))


def estimate_noise_sd(image: np.ndarray) -> float:
    """Standard deviation of white noise in one 2D image (Immerkaer 1996).

    ``sigma = sqrt(pi / 2) / (6 (H - 2)(W - 2)) * sum |I * N|`` with ``N`` the 3 x 3
    difference of two Laplacians, which cancels smooth structure; robust to edges
    when they cover a small part of the image.
    """
    frame = as_image_stack(image)
    if frame.shape[0] != 1:
        raise ValueError(f"estimate_noise_sd needs one 2D frame, got {frame.shape[0]} frames")
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float)
    response = ndimage.convolve(frame[0], kernel)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) * np.abs(response).mean() / 6)


def check_image(image: np.ndarray, *, hot_pixel_sigma: float = 8.0) -> ImageChecks:
    """Run every model-free check on a 2D image or ``(T, Y, X)`` stack."""
    raw = np.asarray(image)
    stack = as_image_stack(raw)
    high = _spike_fraction(stack, stack.max())
    low = _spike_fraction(stack, stack.min())
    unused = 0.0
    if np.issubdtype(raw.dtype, np.integer):
        values = np.unique(raw)
        span = int(values[-1]) - int(values[0]) + 1
        unused = 1.0 - values.size / span
    clipped = np.zeros(stack.shape, bool)
    if high:
        clipped |= stack == stack.max()
    if low:
        clipped |= stack == stack.min()
    hot_pixels: tuple[tuple[int, int], ...] = ()
    if stack.shape[0] >= 3:  # one frame cannot tell a hot pixel from a small bright object
        residual = stack - ndimage.median_filter(stack, size=(1, 3, 3))
        local_sd = 1.4826 * ndimage.median_filter(np.abs(residual), size=(1, 9, 9))
        hot = residual > hot_pixel_sigma * np.maximum(local_sd, 1e-6)
        hot = np.all(hot & ~clipped, axis=0)
        hot_pixels = tuple((int(r), int(c)) for r, c in zip(*np.nonzero(hot)))
    return ImageChecks(
        clipped_high_fraction=high,
        clipped_low_fraction=low,
        unused_value_fraction=unused,
        hot_pixels=hot_pixels,
        noise=fit_poisson_gaussian(stack, clipped=clipped),
    )
