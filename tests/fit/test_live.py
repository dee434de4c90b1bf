"""Live tuning: what a slider change recomputes, and what it must not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.fit.live import LivePreview
from napari_symbac.pipeline import iter_scenes
from napari_symbac.settings import PipelineSettings
from napari_symbac.sim import simulate


@pytest.fixture(scope="module")
def preview_parts():
    base = PipelineSettings()
    settings = dataclasses.replace(
        base, simulation=dataclasses.replace(base.simulation, n_frames=3, seed=4)
    )
    scenes = list(iter_scenes(simulate(settings.simulation), settings))
    return settings, scenes


@pytest.fixture
def preview(preview_parts):
    settings, scenes = preview_parts
    return LivePreview(scenes, settings.microscope, settings.render, settings.camera, seed=9)


def test_intensity_change_reuses_cached_convolutions(preview):
    first = preview.frame(0)
    misses = preview.model.cache_info["misses"]
    preview.update(cell_intensity=preview.render_settings.cell_intensity + 500)
    brighter = preview.frame(0)
    assert preview.model.cache_info["misses"] == misses  # no new convolution
    cells = preview.scene(0).camera_labels() > 0
    assert brighter[cells].mean() > first[cells].mean() + 200


def test_psf_change_convolves_again_and_changes_the_image(preview):
    first = preview.frame(1)
    misses = preview.model.cache_info["misses"]
    preview.update(defocus_sigma_um=0.3)
    blurred = preview.frame(1)
    assert preview.model.cache_info["misses"] > misses
    assert np.abs(np.diff(blurred, axis=1)).mean() < np.abs(np.diff(first, axis=1)).mean()


def test_noise_is_stable_per_frame(preview):
    np.testing.assert_array_equal(preview.frame(2), preview.frame(2))
    assert not np.array_equal(preview.frame(1), preview.frame(2))


def test_bad_value_keeps_previous_settings(preview):
    before = preview.render_settings
    with pytest.raises(ValueError, match="apodisation_sigma_um"):
        preview.update(apodisation_sigma_um=0.01)
    with pytest.raises(ValueError, match="unknown parameter"):
        preview.update(contrast=2)
    assert preview.render_settings == before


def test_histogram_matching_to_a_reference(preview):
    frame = preview.frame(0)
    reference = np.random.default_rng(0).normal(5000, 300, frame.shape).astype(np.float32)
    preview.set_reference(reference, histogram=True)
    matched = preview.frame(0)
    assert np.median(matched) == pytest.approx(np.median(reference), rel=0.02)
    with pytest.raises(ValueError, match="one 2D frame"):
        preview.set_reference(np.zeros((2, 4, 4)))
