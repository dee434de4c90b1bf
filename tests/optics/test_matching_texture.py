"""Fourier / histogram matching (section 6-7) and Perlin texture (13.2.1)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from napari_symbac.optics import (
    match_fourier_spectrum,
    match_histogram,
    perlin_texture,
    random_perlin_texture,
)
from napari_symbac.optics.matching import rotational_spectrum


def test_fourier_matching_copies_rotational_spectrum():
    rng = np.random.default_rng(0)
    image = rng.normal(100, 10, (128, 96))  # white
    reference = gaussian_filter(rng.normal(0, 10, (160, 160)), 3)  # smooth, another shape
    matched = match_fourier_spectrum(image, reference, n_bins=32)
    assert matched.dtype == np.float32
    assert matched.mean() == pytest.approx(image.mean(), abs=1e-3)
    want = rotational_spectrum(reference, 32)
    got = rotational_spectrum(matched, 32)
    before = rotational_spectrum(image, 32)
    useful = want > want.max() * 1e-3
    assert np.allclose(got[useful], want[useful], rtol=0.05)
    assert not np.allclose(before[useful], want[useful], rtol=0.5)


def test_histogram_matching():
    rng = np.random.default_rng(1)
    image = rng.normal(1000, 50, (64, 64)).astype(np.uint16)
    reference = rng.exponential(300, (80, 80)) + 500
    matched = match_histogram(image, reference)
    assert matched.dtype == np.uint16
    q = [10, 50, 90]
    np.testing.assert_allclose(np.percentile(matched, q), np.percentile(reference, q), rtol=0.02)
    with pytest.raises(ValueError, match="2-D"):
        match_histogram(np.zeros(5), reference)


def test_perlin_texture_is_smooth_and_seeded():
    a = perlin_texture((96, 64), np.random.default_rng(2), scale_px=24, octaves=3)
    b = perlin_texture((96, 64), np.random.default_rng(2), scale_px=24, octaves=3)
    np.testing.assert_array_equal(a, b)
    assert a.dtype == np.float32
    assert a.mean() == pytest.approx(0, abs=1e-5)
    assert a.std() == pytest.approx(1, rel=1e-4)
    # Spatially correlated (unlike white noise): neighbour correlation is high.
    assert np.corrcoef(a[:, :-1].ravel(), a[:, 1:].ravel())[0, 1] > 0.9
    c = random_perlin_texture((50, 70), np.random.default_rng(3))
    d = random_perlin_texture((50, 70), np.random.default_rng(4))
    assert c.shape == (50, 70)
    assert not np.allclose(c, d)
    with pytest.raises(ValueError, match="octaves"):
        perlin_texture((10, 10), np.random.default_rng(0), octaves=0)
