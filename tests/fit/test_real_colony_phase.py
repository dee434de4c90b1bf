"""Fitting the partially coherent phase model to a real colony (Omnipose, MIT)."""

from __future__ import annotations

import math

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.fit import fit_parameters
from napari_symbac.fit.masks import (
    cell_widths_px,
    class_medians,
    estimate_pixel_size_um,
    normalise_percentiles,
)
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import scene_from_masks
from napari_symbac.settings import Camera, Microscope, RenderSettings

CROP = (slice(280, 460), slice(40, 220))  # the colony's left edge and the pad beside it
CAMERA = Camera(baseline_adu=0.0, sensitivity_adu_per_e=1.0, dark_noise_e=0.0, bit_depth=8)


@pytest.fixture(scope="module")
def colony(real_data_dir):
    folder = real_data_dir / "omnipose"
    image = iio.imread(folder / "Sample000193.png")[..., 0].astype(np.float64)
    labels = tifffile.imread(folder / "Sample000193_cp_masks.tif").astype(np.int64)
    return image, labels


def test_pixel_size_from_the_cell_widths(colony):
    _, labels = colony
    widths = cell_widths_px(labels)
    assert widths.size == len(np.unique(labels)) - 1
    px = estimate_pixel_size_um(labels, cell_width_um=1.0)
    assert px == pytest.approx(1.0 / np.median(widths))
    assert 0.06 < px < 0.09  # cells ~13 px wide


def test_rectangle_width_is_measured_exactly():
    labels = np.zeros((40, 60), np.int64)
    labels[10:19, 5:50] = 1  # 9 px wide
    assert cell_widths_px(labels)[0] == pytest.approx(9.0)
    with pytest.raises(ValueError, match="no cell"):
        cell_widths_px(np.zeros((5, 5), np.int64))


@pytest.mark.slow
def test_fit_on_a_real_crop_reproduces_the_class_medians(colony):
    image, labels = colony
    image, labels = image[CROP], labels[CROP]
    px = estimate_pixel_size_um(colony[1])
    microscope = Microscope(pixel_size_um=px, wavelength_um=0.55, numerical_aperture=1.45)
    render = RenderSettings(
        upsample=1, psf_radius_px=math.ceil(3.0 / px), cell_intensity=80.0,
        media_intensity=80.0, device_intensity=80.0, apodisation_sigma_um=2.0,
        phase_model="partially_coherent", cell_phase_rad=0.8, plate_transmission=0.2,
        source_points=16, noise_model="gaussian",
    )  # fmt: skip
    scene = scene_from_masks(labels, microscope, render)
    result = fit_parameters(
        image, None, scene, microscope, render, CAMERA, terms=("pixel",), max_evaluations=40
    )
    assert result.fitted == ("cell_phase_rad", "apodisation_sigma_um", "phase_ring_width_scale")
    assert result.warnings == ()  # nothing at a bound, better than the start
    assert result.objective_after < result.objective_before
    synthetic = ForwardModel(microscope, result.render, CAMERA).render(
        scene, np.random.default_rng(0)
    )
    far = 2.0 / px
    real = class_medians(image, labels, far)
    fitted = class_medians(synthetic.astype(np.float64), labels, far)
    for name in ("cells", "background"):
        assert fitted[name] == pytest.approx(real[name], abs=0.05), (name, real, fitted)
    # the halo is the brightest class in both, well above the background
    assert fitted["halo"] > fitted["background"] + 0.2
    assert real["halo"] > real["background"] + 0.2
    # and the start (default-like optics) was far from it
    start = ForwardModel(microscope, render, CAMERA).render(scene, np.random.default_rng(0))
    assert np.abs(normalise_percentiles(start) - normalise_percentiles(synthetic)).mean() > 0.02


def test_fit_warnings_name_bounds_and_a_worse_end():
    from napari_symbac.fit.parameters import fit_warnings

    render = RenderSettings(defocus_sigma_um=0.5, psf_offset=0.1)
    bounds = [(0.0, 0.5), (-0.5, 0.5)]
    names = ("defocus_sigma_um", "psf_offset")
    warnings = fit_warnings(render, names, bounds, 2.0, 1.0)
    assert len(warnings) == 1
    assert "defocus_sigma_um" in warnings[0]
    assert "upper bound" in warnings[0]
    worse = fit_warnings(RenderSettings(defocus_sigma_um=0.2), names, bounds, 1.0, 1.5)
    assert len(worse) == 1
    assert "worse than its start" in worse[0]
    assert fit_warnings(RenderSettings(defocus_sigma_um=0.2), names, bounds, 2.0, 1.0) == ()
    strong = RenderSettings(media_intensity=100.0, cell_phase_adu=2000.0)
    assert "physical bound" in fit_warnings(strong, (), [], 1.0, 1.0, separate=True)[0]


def test_distance_profile_and_class_medians_on_a_known_image():
    from napari_symbac.fit.masks import distance_profile

    labels = np.zeros((60, 60), np.int64)
    labels[20:40, 20:40] = 1
    image = np.where(labels > 0, 0.0, 10.0)
    image[19, 20:40] = 20.0  # a bright line just outside the top edge
    profile = distance_profile(image, labels > 0, np.array([-3.0, -1.0, 0.0, 1.0, 3.0]))
    assert profile[0] == 0.0
    assert profile[1] == 0.0
    assert profile[2] > 10.0  # the bright line is in the first bin outside
    assert profile[3] == 10.0
    medians = class_medians(image, labels, far_px=10)
    assert medians["cells"] == 0.0
    assert medians["background"] == pytest.approx(1.0)  # the 99th percentile: the line is < 1 %
    with pytest.raises(ValueError, match="far_px"):
        class_medians(image, labels, far_px=100)


def test_fit_scene_sends_a_dense_colony_with_masks_to_fit_colony(colony):
    """Found as an API user: fit_scene given an Omnipose crop's masks removed 43 of its
    45 cells and ended worse than its start; fit_colony keeps them (the CLI and
    calibrate already chose it)."""
    from napari_symbac.fit import fit_scene

    image, labels = colony
    crop = (slice(200, 328), slice(200, 328))
    microscope = Microscope(pixel_size_um=0.077, wavelength_um=0.55)
    with pytest.raises(ValueError, match=r"dense phase-contrast colony.*fit_colony"):
        fit_scene(image[crop], microscope, RenderSettings(upsample=1), geometry="open",
                  masks=labels[crop])
