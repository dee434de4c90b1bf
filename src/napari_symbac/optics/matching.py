"""Fourier-spectrum and histogram matching (supplement sections 6-7).

Use these to make *training images* look like a real recording; never inside a
likelihood or a fit, where they would hide exactly the effects being measured.
"""

from __future__ import annotations

import numpy as np

__all__ = ["match_fourier_spectrum", "match_histogram", "rotational_spectrum"]


def _as_image(image: np.ndarray, name: str) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return image


def _radial_bins(shape: tuple[int, int], n_bins: int) -> np.ndarray:
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    radius = np.hypot(fy, fx)  # cycles per pixel, 0 .. ~0.707
    return np.minimum((radius / (np.sqrt(0.5) + 1e-12) * n_bins).astype(int), n_bins - 1)


def rotational_spectrum(image: np.ndarray, n_bins: int = 64) -> np.ndarray:
    """Rotational average of the power spectrum per pixel, in ``n_bins`` radial bins.

    Bins are in cycles per pixel (so images of different shapes compare) and the
    power is divided by the number of pixels (Parseval), the mean removed.
    """
    image = _as_image(image, "image")
    power = np.abs(np.fft.fft2(image - image.mean())) ** 2 / image.size
    bins = _radial_bins(image.shape, n_bins)
    total = np.bincount(bins.ravel(), power.ravel(), minlength=n_bins)
    count = np.bincount(bins.ravel(), minlength=n_bins)
    return total / np.maximum(count, 1)


def match_fourier_spectrum(
    image: np.ndarray, reference: np.ndarray, n_bins: int = 64
) -> np.ndarray:
    """Give ``image`` the rotationally averaged amplitude spectrum of ``reference``.

    Written from the method of the SHINE toolbox (``sfMatch``; Willenbockel et al.
    2010): every ring of spatial frequency of the image's Fourier transform is
    scaled so that its mean power equals that of the reference's ring; phases are
    kept, and so is the image's mean. Frequencies are in cycles per pixel, so the
    two images may differ in shape.

    Returns
    -------
    numpy.ndarray
        float32 image.
    """
    x = _as_image(image, "image")
    target = rotational_spectrum(reference, n_bins)
    current = rotational_spectrum(x, n_bins)
    gain = np.sqrt(np.divide(target, current, out=np.zeros_like(target), where=current > 0))
    spectrum = np.fft.fft2(x - x.mean())
    spectrum *= gain[_radial_bins(x.shape, n_bins)]
    return (np.fft.ifft2(spectrum).real + x.mean()).astype(np.float32)


def match_histogram(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Match the intensity histogram of ``image`` to ``reference`` (scikit-image).

    Integer images come back rounded in their own dtype; others as float32.
    """
    from skimage.exposure import match_histograms

    original = np.asarray(image)
    x = _as_image(original, "image")
    ref = _as_image(reference, "reference")
    matched = match_histograms(x, ref)
    if np.issubdtype(original.dtype, np.integer):
        info = np.iinfo(original.dtype)
        return np.clip(np.rint(matched), info.min, info.max).astype(original.dtype)
    return matched.astype(np.float32)
