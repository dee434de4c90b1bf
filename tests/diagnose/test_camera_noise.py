"""camera_noise judges the noise on the high-pass residual: a misfit of the mean is not noise."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.diagnose.effects import camera_noise
from napari_symbac.diagnose.effects.camera_noise import fit_factors, high_pass_matrix, score
from napari_symbac.diagnose.model import variance
from napari_symbac.settings import Camera

CAMERA = Camera()  # 2.9 ADU/e-, 8 e-


def _frame(gain: float, misfit_sd: float, seed: int):
    """A 128 x 96 frame of mean 1500-3000 ADU, noise of ``gain`` x the camera's
    sensitivity, and a mean misfit of ``misfit_sd`` noise s.d. (a smooth bump and an
    edge smooth along one axis, as a cell's side the model lacks)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:128, 0:96].astype(float)
    mu = 1500.0 + 1500.0 * (xx / 95.0)
    noisy = Camera(sensitivity_adu_per_e=CAMERA.sensitivity_adu_per_e * gain)
    sd = np.sqrt(variance(mu, noisy))
    bump = np.cos(2 * np.pi * yy / 40) * np.cos(2 * np.pi * xx / 25)
    edge = np.tanh((xx - 48) / 1.5) * np.exp(-(((yy - 64) / 30) ** 2))
    misfit = misfit_sd * sd * (bump + edge) / 1.4
    residual = rng.normal(0.0, sd) + misfit
    return residual[None], mu[None], np.ones((1, *mu.shape), bool)


def _evidence(u: float, info: float) -> float:
    from napari_symbac.diagnose.statistics import neg_log10_p_chi2

    return neg_log10_p_chi2(u * u / info, 1)


def test_high_pass_is_an_orthogonal_projection():
    k = high_pass_matrix(46)
    np.testing.assert_allclose(k, k.T, atol=1e-12)
    np.testing.assert_allclose(k @ k, k, atol=1e-10)
    # modes below 0.15 cycles/px removed: 14 of 46
    assert np.trace(k) == pytest.approx(46 - 14)
    ramp = np.linspace(-1, 1, 46)  # a gradient across the frame: 1 % of it is left
    assert np.abs(k @ ramp).max() < 0.02


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_mean_misfit_three_times_the_noise_is_not_camera_noise(seed):
    residual, mu, valid = _frame(1.0, 3.0, seed)
    raw = float(np.mean(residual**2 / variance(mu, CAMERA)))
    assert raw > 3.0  # the plain residual is 3-4x the noise's variance
    gain, read = fit_factors(residual, mu, CAMERA, valid)
    assert gain == pytest.approx(1.0, abs=0.05)
    assert read == pytest.approx(gain**2)
    assert _evidence(*score(residual, mu, CAMERA, valid)) < 2.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_twelve_percent_gain_error_is_found_and_measured(seed):
    residual, mu, valid = _frame(1.12, 0.0, seed)
    gain, _ = fit_factors(residual, mu, CAMERA, valid)
    assert gain == pytest.approx(1.12, abs=0.04)
    assert _evidence(*score(residual, mu, CAMERA, valid)) > 5.0
    # beside a misfit of the mean as well
    residual, mu, valid = _frame(1.12, 3.0, seed)
    gain, _ = fit_factors(residual, mu, CAMERA, valid)
    assert gain == pytest.approx(1.12, abs=0.05)


def test_updated_camera_keeps_the_read_noise_in_electrons():
    camera = camera_noise.updated_camera(CAMERA, {"gain_ratio": 1.2, "read_variance_ratio": 1.44})
    assert camera.sensitivity_adu_per_e == pytest.approx(CAMERA.sensitivity_adu_per_e * 1.2)
    assert camera.dark_noise_e == pytest.approx(CAMERA.dark_noise_e)
