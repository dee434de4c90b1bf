"""Bright-field transmissions of the partially coherent phase model as fitted parameters."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from napari_symbac.fit import fit_parameters
from napari_symbac.fit.parameters import parameter_bounds
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import scene_from_masks
from napari_symbac.settings import Camera, Microscope, RenderSettings

CAMERA = Camera(baseline_adu=0.0, sensitivity_adu_per_e=1.0, dark_noise_e=0.0, bit_depth=16)
MICROSCOPE = Microscope(pixel_size_um=0.08, wavelength_um=0.55, numerical_aperture=1.45)


def _scene_and_truth():
    labels = np.zeros((48, 48), np.int64)
    labels[14:26, 6:42] = 1  # a 1 um wide rod
    labels[30:42, 10:30] = 2
    truth = RenderSettings(
        upsample=1, psf_radius_px=math.ceil(2.0 / MICROSCOPE.pixel_size_um),
        cell_intensity=700.0, media_intensity=1000.0, device_intensity=1000.0,
        apodisation_sigma_um=2.0, phase_model="partially_coherent", cell_phase_rad=0.5,
        plate_transmission=0.25, source_points=8, noise_model="none",
    )  # fmt: skip
    return scene_from_masks(labels, MICROSCOPE, truth), truth


def test_the_cells_transmission_is_recovered_from_a_synthetic_image():
    scene, truth = _scene_and_truth()
    image = ForwardModel(MICROSCOPE, truth, CAMERA).phase_image(scene) * truth.media_intensity
    start = dataclasses.replace(truth, cell_intensity=900.0, media_intensity=800.0)
    result = fit_parameters(
        image, None, scene, MICROSCOPE, start, CAMERA, terms=("pixel",),
        fit=("cell_transmission",), max_evaluations=30, global_search=False,
    )  # fmt: skip
    r = result.render
    assert result.fitted == ("cell_transmission",)
    # started at 0.9 (the step from there used to be 1.5e-8 and left it in place)
    assert r.cell_intensity / r.media_intensity == pytest.approx(0.7, abs=0.01)
    assert r.media_intensity == pytest.approx(1000.0, rel=0.01)
    assert result.objective_after < 0.01 * result.objective_before
    assert result.warnings == ()
    assert "cell_transmission" in result.report()


def test_transmissions_are_refused_by_the_linear_model_and_bounded_by_one():
    scene, truth = _scene_and_truth()
    linear = dataclasses.replace(truth, phase_model="linear")
    image = np.arange(48.0 * 48).reshape(48, 48)
    with pytest.raises(ValueError, match="partially coherent"):
        fit_parameters(
            image, None, scene, MICROSCOPE, linear, CAMERA, terms=("pixel",),
            fit=("device_transmission",),
        )  # fmt: skip
    for name in ("cell_transmission", "device_transmission"):
        low, high = parameter_bounds(name, MICROSCOPE)
        assert 0 < low < high == 1.0
