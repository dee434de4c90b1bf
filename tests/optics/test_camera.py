"""Camera model (eq. 17) and dark-frame calibration (eq. 18-19)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from napari_symbac.optics.camera import (
    GAUSSIAN_SKEWNESS_MAX,
    apply_camera_noise,
    apply_gaussian_noise,
    calibrate_camera,
    exact_poisson_range,
    shot_read_skewness,
    standard_normal_f32,
)
from napari_symbac.settings import Camera


def test_photon_transfer_line():
    """Variance vs mean: slope = sensitivity, intercept = dark noise variance (ADU^2)."""
    cam = Camera(baseline_adu=100.0, sensitivity_adu_per_e=2.2, dark_noise_e=6.0)
    rng = np.random.default_rng(0)
    means, variances = [], []
    for level in (0.0, 200.0, 800.0, 2000.0, 5000.0, 9000.0):
        frames = apply_camera_noise(np.full((2, 200, 200), level), cam, rng).astype(float)
        diff = frames[0] - frames[1]  # removes any fixed pattern
        means.append(frames.mean() - cam.baseline_adu)
        variances.append(diff.var() / 2)
    # a variance estimate's error grows with the variance: weight by 1 / variance
    slope, intercept = np.polyfit(means, variances, 1, w=1 / np.array(variances))
    assert slope == pytest.approx(2.2, rel=0.03)
    assert intercept == pytest.approx((2.2 * 6.0) ** 2, rel=0.05)


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


def _skewness(values: np.ndarray) -> float:
    centred = values - values.mean()
    return float((centred**3).mean() / centred.var() ** 1.5)


def test_shot_and_read_noise_mean_variance_and_skewness_per_level():
    """Each level: mean and photon-transfer variance; skewness near the exact one.

    The default camera (sigma_d = 8 e-) takes the single Gaussian draw at every level
    (skewness 0 instead of at most 0.048); ``max_skewness=0`` draws Poisson counts,
    whose skewness ``lambda / (lambda + sigma_d^2)^1.5`` shows.
    """
    cam = Camera(baseline_adu=100.0, sensitivity_adu_per_e=2.9, dark_noise_e=8.0)
    assert exact_poisson_range(8.0, GAUSSIAN_SKEWNESS_MAX) is None
    rng = np.random.default_rng(2)
    n = 400_000
    for electrons in (0.0, 20.0, 128.0, 300.0, 900.0):
        level = np.full(n, electrons * 2.9)
        theory_var = 2.9 * level[0] + (2.9 * 8.0) ** 2 + 1 / 12
        exact_skew = float(shot_read_skewness(electrons, 8.0))
        for max_skewness, skew in ((GAUSSIAN_SKEWNESS_MAX, 0.0), (0.0, exact_skew)):
            counts = apply_camera_noise(level, cam, rng, max_skewness=max_skewness)
            residual = counts.astype(float) - cam.baseline_adu - level
            assert abs(residual.mean()) < 5 * np.sqrt(theory_var / n)
            assert residual.var() == pytest.approx(theory_var, rel=0.015)
            # standard error of a skewness: sqrt(6 / n) = 0.0039
            assert _skewness(residual) == pytest.approx(skew, abs=0.016)


def test_low_counts_with_little_read_noise_stay_poisson():
    """Dim pixels of a camera with 0.3 e- read noise keep whole-electron counts."""
    cam = Camera(baseline_adu=100.0, sensitivity_adu_per_e=1.0, dark_noise_e=0.3)
    low, high = exact_poisson_range(0.3, GAUSSIAN_SKEWNESS_MAX)
    assert low < 3.0 < high
    counts = apply_camera_noise(np.full(200_000, 3.0), cam, np.random.default_rng(4))
    electrons = counts.astype(float) - 100.0
    assert _skewness(electrons) == pytest.approx(float(shot_read_skewness(3.0, 0.3)), abs=0.03)
    # P(output rounds to 0): A = k ~ Poisson(3) with |k + 0.3 Z| < 0.5
    k = np.arange(12)
    rounds_to_0 = np.diff(stats.norm.cdf(([-0.5], [0.5]) - k, 0, 0.3), axis=0)
    p0 = float(np.sum(stats.poisson.pmf(k, 3.0) * rounds_to_0))
    assert np.mean(electrons == 0) == pytest.approx(p0, abs=5 * np.sqrt(p0 / 200_000))
    # below -0.5 only from A = 0 (0.24 %); a Gaussian of variance 3.09 would put 4 % there
    assert np.mean(electrons < -0.5) < 0.005
    # bright pixels of the same camera take the Gaussian (skewness below the limit)
    bright = apply_camera_noise(np.full(200_000, 5000.0), cam, np.random.default_rng(4))
    assert high < 5000.0
    assert bright.astype(float).var() == pytest.approx(5000.0 + 0.09 + 1 / 12, rel=0.015)


def test_exact_poisson_range_ends_and_determinism():
    for dark in (0.0, 0.5, 3.0, 7.0):
        low, high = exact_poisson_range(dark, 0.05)
        assert float(shot_read_skewness(high, dark)) == pytest.approx(0.05, rel=1e-9)
        if dark > 0:
            assert float(shot_read_skewness(low, dark)) == pytest.approx(0.05, rel=1e-9)
            assert low < 2 * dark**2 < high  # the peak lies between them
        else:
            assert low == 0.0
            assert high == pytest.approx(400.0)  # lambda^-0.5 = 0.05
    assert exact_poisson_range(7.8, 0.05) is None  # peak 0.385 / 7.8 = 0.049
    assert exact_poisson_range(8.0, 0.0) == (0.0, np.inf)
    # a mixed image (exact and Gaussian pixels): same seed, same bits
    cam = Camera(dark_noise_e=1.0)
    signal = np.linspace(0.0, 3000.0, 4096).reshape(64, 64)
    a = apply_camera_noise(signal, cam, np.random.default_rng(9))
    b = apply_camera_noise(signal, cam, np.random.default_rng(9))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, apply_camera_noise(signal, cam, np.random.default_rng(10)))
    with pytest.raises(ValueError, match="max_skewness"):
        apply_camera_noise(signal, cam, np.random.default_rng(0), max_skewness=-1.0)
    # any shape, a scalar and an empty image included
    assert apply_camera_noise(500.0, cam, np.random.default_rng(0)).shape == ()
    assert apply_camera_noise(np.zeros((0, 5)), cam, np.random.default_rng(0)).shape == (0, 5)
    stacked = apply_camera_noise(signal[None], cam, np.random.default_rng(9))
    assert stacked.shape == (1, 64, 64)
    np.testing.assert_array_equal(stacked[0], a)  # the same numbers whatever the shape


def test_standard_normal_f32_is_standard_normal():
    rng = np.random.default_rng(12)
    z = standard_normal_f32(rng, (1000, 1000))
    assert z.dtype == np.float32
    assert z.shape == (1000, 1000)
    flat = z.ravel().astype(np.float64)
    assert abs(flat.mean()) < 5e-3  # standard error 1e-3
    assert flat.var() == pytest.approx(1.0, abs=5e-3)  # standard error 1.4e-3
    assert abs(_skewness(flat)) < 0.012
    kurtosis = ((flat - flat.mean()) ** 4).mean() / flat.var() ** 2
    assert kurtosis == pytest.approx(3.0, abs=0.025)  # standard error 0.005
    assert stats.kstest(flat, "norm").pvalue > 1e-3
    for k, tail in ((2, 0.0455), (3, 0.0027), (4, 6.3e-5)):
        assert np.mean(np.abs(flat) > k) == pytest.approx(tail, abs=5 * np.sqrt(tail / 1e6))
    assert np.abs(flat).max() <= 5.78
    # odd sizes, same state same numbers
    a = standard_normal_f32(np.random.default_rng(1), (7, 3))
    np.testing.assert_array_equal(a, standard_normal_f32(np.random.default_rng(1), (7, 3)))
    assert a.shape == (7, 3)


@pytest.mark.parametrize(("electrons", "dark_e"), [(2, 1.5), (30, 3.0), (128, 8.0), (2000, 8.0)])
def test_gaussian_draw_error_bound(electrons, dark_e):
    """The CDF of ``Poisson(lambda) + N(0, sigma_d^2)`` against the Gaussian of the same
    mean and variance: 0.0665 x its skewness (the first Edgeworth term; up to 0.0672 x at
    a skewness of 0.23), 0.0033 at the limit of 0.05 that ``apply_camera_noise`` uses."""
    k = np.arange(int(electrons + 12 * np.sqrt(electrons + 1) + 10))
    sd = np.sqrt(electrons + dark_e**2)
    x = np.linspace(electrons - 8 * sd, electrons + 8 * sd, 4001)
    exact = (stats.poisson.pmf(k, electrons)[:, None] * stats.norm.cdf(x - k[:, None], 0, dark_e))
    gaussian = stats.norm.cdf(x, electrons, sd)
    distance = np.abs(exact.sum(axis=0) - gaussian).max()
    skew = float(shot_read_skewness(electrons, dark_e))
    assert distance <= 0.068 * skew
    assert distance >= 0.066 * skew  # the first Edgeworth term: the bound is not loose
    if skew <= GAUSSIAN_SKEWNESS_MAX:
        assert distance <= 0.0034
