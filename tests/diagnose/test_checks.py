"""Model-free checks of a recording: clipping, value gaps, hot pixels, photon transfer."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_symbac.diagnose import check_image


def _camera_frames(rng: np.random.Generator, n_frames: int = 1) -> np.ndarray:
    """Smooth scene through a linear camera: gain 2 ADU/e-, read noise 3 e-, offset 100."""
    y, x = np.mgrid[:128, :128]
    electrons = 50 + 1500 * (x / 127) * (0.5 + 0.5 * y / 127)
    frames = [
        2.0 * (rng.poisson(electrons) + rng.normal(0, 3, electrons.shape)) + 100
        for _ in range(n_frames)
    ]
    return np.round(np.stack(frames)).astype(np.uint16)


def test_photon_transfer_slope_is_the_gain():
    checks = check_image(_camera_frames(np.random.default_rng(0)))
    assert checks.noise is not None
    assert checks.noise.gain == pytest.approx(2.0, rel=0.1)
    assert checks.clipped_high_fraction == 0
    assert checks.hot_pixels == ()


def test_saturation_and_hot_pixels_are_found():
    frames = _camera_frames(np.random.default_rng(1), n_frames=3)
    frames[:, :, 100:] = np.minimum(frames[:, :, 100:], 1500)
    frames = np.minimum(frames, 1500)
    frames[:, 40, 2] = 1000  # dark region, below saturation
    checks = check_image(frames)
    expected = np.mean(frames == 1500)
    assert checks.clipped_high_fraction == pytest.approx(expected)
    assert checks.hot_pixels == ((40, 2),)
    assert any("clipped high" in line for line in checks.summary())


def test_colicoords_fields_show_their_known_processing(real_data_dir):
    """The README of the data: 9-12 % of brightfield pixels clipped at 65535, 17-19 % of
    background-subtracted fluorescence pixels at 0."""
    folder = real_data_dir / "colicoords" / "test_data" / "ds1"
    brightfield = check_image(tifffile.imread(folder / "brightfield" / "00001.tif"))
    fluorescence = check_image(tifffile.imread(folder / "fluorescence" / "00001.tif"))
    assert 0.09 <= brightfield.clipped_high_fraction <= 0.12
    assert 0.17 <= fluorescence.clipped_low_fraction <= 0.19
    assert brightfield.clipped_low_fraction == 0


@pytest.mark.parametrize("sd", [5.0, 40.0])
def test_noise_sd_of_a_smooth_scene(sd):
    from napari_symbac.diagnose import estimate_noise_sd

    rng = np.random.default_rng(int(sd))
    y, x = np.mgrid[:200, :160]
    scene = 1000 + 3 * x + 0.01 * (y - 100) ** 2
    assert estimate_noise_sd(scene + rng.normal(0, sd, scene.shape)) == pytest.approx(sd, rel=0.05)
