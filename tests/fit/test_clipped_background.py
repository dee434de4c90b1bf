"""A background clipped at zero by background subtraction, fitted as censored."""

from __future__ import annotations

import math

import numpy as np
import pytest

from napari_symbac.fit.camera_estimate import censored_pixels
from napari_symbac.fit.clipped_background import clipped_background, drawn_clipped
from napari_symbac.settings import Camera, PipelineSettings


def _subtracted_field(seed: int, debris: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A 200 x 200 field whose background ~ N(20, 30) was clipped at 0 (25 % of it),
    with two bright cells (and, optionally, 3 % bright debris pixels)."""
    rng = np.random.default_rng(seed)
    field = rng.normal(20.0, 30.0, (200, 200))
    cells = np.zeros(field.shape, bool)
    cells[40:50, 30:70] = cells[120:160, 100:110] = True
    field[cells] += 800.0
    if debris:
        field[rng.random(field.shape) < 0.03] += 400.0
    return np.maximum(np.round(field), 0).astype(np.uint16), cells


@pytest.mark.parametrize("debris", [False, True])
def test_the_clipped_background_is_fitted_as_censored(debris):
    image, cells = _subtracted_field(seed=1, debris=debris)
    clipped = clipped_background(image, cells, censored_pixels(image))
    assert clipped is not None
    assert clipped.level_adu == 0
    assert clipped.fraction == pytest.approx(0.25, abs=0.02)  # P(N(20, 30) < 0.5)
    # the mean of the pixels above 0 (what a fit that leaves them out sees) is 35 ADU
    above = image[(image > 0) & ~cells]
    assert not debris or above.mean() > 40
    assert clipped.mean_adu == pytest.approx(20.0, abs=1.5)
    assert clipped.sd_adu == pytest.approx(30.0, abs=1.5)


def test_an_unclipped_background_is_left_as_it_is():
    rng = np.random.default_rng(2)
    image = np.round(rng.normal(300.0, 20.0, (100, 100))).astype(np.uint16)
    assert clipped_background(image, np.zeros(image.shape, bool), censored_pixels(image)) is None


def test_the_drawn_background_has_the_fitted_mean_spread_and_clip():
    image, cells = _subtracted_field(seed=3)
    clipped = clipped_background(image, cells, censored_pixels(image))
    camera = Camera(baseline_adu=1.0, sensitivity_adu_per_e=4.0, dark_noise_e=0.5)
    settings, sentence = drawn_clipped(PipelineSettings(camera=camera), clipped)
    media = settings.render.media_intensity
    assert media == pytest.approx(clipped.mean_adu - 1.0)
    # shot noise of the media level plus read noise: the fitted variance
    read = settings.camera.dark_noise_e * 4.0
    assert math.sqrt(4.0 * media + read**2) == pytest.approx(clipped.sd_adu, rel=1e-9)
    assert settings.extra_stages[-1].name == "saturation"
    assert settings.extra_stages[-1].parameters == {"clip_level_adu": 0.0, "high": False}
    assert "background clipped at 0 ADU (25" in sentence


def test_a_given_camera_keeps_its_read_noise():
    image, cells = _subtracted_field(seed=4)
    clipped = clipped_background(image, cells, censored_pixels(image))
    camera = Camera(baseline_adu=1.0, sensitivity_adu_per_e=4.0, dark_noise_e=0.5)
    settings, sentence = drawn_clipped(PipelineSettings(camera=camera), clipped, noise=False)
    assert settings.camera == camera
    assert settings.render.media_intensity == pytest.approx(clipped.mean_adu - 1.0)
    assert "read noise" not in sentence


def test_the_clip_at_zero_replaces_a_low_clip_and_keeps_a_saturated_top():
    """diagnose may accept a camera saturated at its top beside the background clipped at
    0: the settings draw both (the clip at 0 once)."""
    from napari_symbac.fit.clipped_background import ClippedBackground, with_clip
    from napari_symbac.settings import ExtraStage

    top = ExtraStage("saturation", {"clip_level_adu": 4095.0, "high": True})
    low = ExtraStage("saturation", {"clip_level_adu": 3.0, "high": False})
    stages = with_clip([top, low], ClippedBackground(0.0, 0.2, 20.0, 9.0))
    assert [dict(s.parameters) for s in stages] == [
        {"clip_level_adu": 4095.0, "high": True},
        {"clip_level_adu": 0.0, "high": False},
    ]
