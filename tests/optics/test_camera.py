"""Camera model (eq. 17) and dark-frame calibration (eq. 18-19)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.optics.camera import (
    apply_camera_noise,
    apply_gaussian_noise,
    calibrate_camera,
)
from napari_symbac.settings import Camera


def test_photon_transfer_line():
    """Variance vs mean: slope = sensitivity, intercept = dark noise variance (ADU^2)."""
    cam = Camera(baseline_adu=100.0, sensitivity_adu_per_e=2.2, dark_noise_e=6.0)
    rng = np.random.default_rng(0)
    means, variances = [], []
    for level in (200.0, 800.0, 2000.0, 5000.0, 9000.0):
        frames = apply_camera_noise(np.full((2, 200, 200), level), cam, rng).astype(float)
        diff = frames[0] - frames[1]  # removes any fixed pattern
        means.append(frames.mean() - cam.baseline_adu)
        variances.append(diff.var() / 2)
    slope, intercept = np.polyfit(means, variances, 1)
    assert slope == pytest.approx(2.2, rel=0.03)
    assert intercept == pytest.approx((2.2 * 6.0) ** 2, rel=0.15)


def test_dark_frame_calibration_recovers_parameters():
    truth = Camera(baseline_adu=412.0, sensitivity_adu_per_e=1.7, dark_noise_e=3.5)
    rng = np.random.default_rng(1)
    dark = apply_camera_noise(np.zeros((8, 128, 128)), truth, rng)
    cal = calibrate_camera(dark, 1.7)
    assert cal.baseline_adu == pytest.approx(412.0, abs=0.2)
    assert cal.dark_noise_e == pytest.approx(3.5, rel=0.02)
    single = calibrate_camera(dark[0], 1.7)  # eq. 19 from one frame
    assert single.dark_noise_e == pytest.approx(3.5, rel=0.03)
    assert single.n_frames == 1
    cam = cal.to_camera(bit_depth=12)
    assert cam.bit_depth == 12
    with pytest.raises(ValueError, match="sensitivity"):
        calibrate_camera(dark, -1.0)
    with pytest.raises(ValueError, match="NaN"):
        calibrate_camera(np.full((2, 4, 4), np.nan), 1.0)


def test_clipping_dtype_and_determinism():
    cam = Camera(bit_depth=12)
    signal = np.array([[-50.0, 100.0], [5000.0, 1e6]])
    a = apply_camera_noise(signal, cam, np.random.default_rng(5))
    b = apply_camera_noise(signal, cam, np.random.default_rng(5))
    c = apply_camera_noise(signal, cam, np.random.default_rng(6))
    assert a.dtype == np.uint16
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.max() == 4095
    g = apply_gaussian_noise(np.full((300, 300), 1000.0), cam, 25.0, np.random.default_rng(0))
    assert g.dtype == np.uint16
    assert g.std() == pytest.approx(25.0, rel=0.03)
    assert g.mean() == pytest.approx(1000 + cam.baseline_adu, abs=0.5)
    with pytest.raises(ValueError, match="NaN"):
        apply_camera_noise(np.array([np.nan]), cam, np.random.default_rng(0))
