"""fit_colony: a dense phase colony drawn from its masks, the partially coherent optics fitted."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from napari_symbac.fit import fit_colony
from napari_symbac.fit.colony import colony_start, is_dense_colony, touching_cells
from napari_symbac.optics import ForwardModel
from napari_symbac.settings import Camera, Microscope

#: A corner of Sample000193 (Omnipose, MIT): half cells (14 masks), half pad with the halo.
CROP = (slice(80, 176), slice(336, 432))
MICROSCOPE = Microscope(pixel_size_um=0.0745, wavelength_um=0.55, modality="phase")


@pytest.fixture(scope="module")
def colony_masks(real_data_dir):
    masks = tifffile.imread(real_data_dir / "omnipose" / "Sample000193_cp_masks.tif")
    return np.asarray(masks[CROP], np.int64)


def _rods(touching: bool) -> np.ndarray:
    masks = np.zeros((60, 80), np.int64)
    gap = 0 if touching else 3
    for k in range(6):
        top = 5 + k * (6 + gap)
        masks[top : top + 6, 10:60] = k + 1
    return masks


def test_touching_cells_make_a_colony_and_separate_ones_do_not():
    assert touching_cells(_rods(True)) == 6
    assert touching_cells(_rods(False)) == 0
    assert is_dense_colony(_rods(True), "phase")
    assert not is_dense_colony(_rods(False), "phase")
    assert not is_dense_colony(_rods(True), "fluorescence")  # no halo to fit
    assert not is_dense_colony(None, "phase")
    few = np.where(_rods(True) <= 4, _rods(True), 0)  # 4 touching cells: too few
    assert not is_dense_colony(few, "phase")


def test_fit_colony_recovers_the_optics_of_a_rendered_colony(colony_masks):
    """Truth known: the real colony's masks rendered with chosen optics and Gaussian
    noise, then fitted from the default start: each optic within 3 standard errors
    (and 5 %) of the truth, the residual at the noise."""
    rng = np.random.default_rng(7)
    start, scene = colony_start(colony_masks, MICROSCOPE, 80.0, 1.0)
    truth = dataclasses.replace(
        start,
        cell_phase_rad=0.45,
        apodisation_sigma_um=2.6,
        phase_ring_width_scale=1.15,
        media_intensity=90.0,
        cell_intensity=90.0,
        device_intensity=90.0,
    )
    clean = ForwardModel(MICROSCOPE, truth, Camera()).render_clean(scene, cache=False)
    image = clean + rng.normal(0.0, 1.0, clean.shape)
    fit = fit_colony(image, MICROSCOPE, colony_masks, Camera(baseline_adu=0.0))
    values = dict(zip(fit.parameter_names, fit.parameters, strict=True))
    errors = dict(zip(fit.parameter_names, fit.standard_errors, strict=True))
    for name in ("cell_phase_rad", "apodisation_sigma_um", "phase_ring_width_scale"):
        true = getattr(truth, name)
        assert errors[name] > 0, name  # NaN fails too
        assert abs(values[name] - true) < max(3 * errors[name], 1e-3), (name, values[name])
        assert values[name] == pytest.approx(true, rel=0.05), name
    assert values["media_intensity"] == pytest.approx(90.0, rel=0.02)
    assert fit.objective_after < 1.3 < fit.objective_before
    assert fit.warnings == ()
    sizes = np.bincount(colony_masks.ravel())[1:]
    measurable = int(np.count_nonzero(sizes * MICROSCOPE.pixel_size_um**2 >= 0.25))
    assert len(fit.cells) == measurable  # the masks' cells, slivers cut by the edge aside
    assert np.std(fit.residual) == pytest.approx(1.0, rel=0.15)


def test_fit_colony_refuses_fluorescence_and_masks_of_another_shape(colony_masks):
    image = np.random.default_rng(1).normal(500.0, 20.0, colony_masks.shape)
    fluorescence = dataclasses.replace(MICROSCOPE, modality="fluorescence")
    with pytest.raises(ValueError, match="fluorescence"):
        fit_colony(image, fluorescence, colony_masks)
    with pytest.raises(ValueError, match="but the image frame has shape"):
        fit_colony(image[:50], MICROSCOPE, colony_masks)
    with pytest.raises(ValueError, match="holds no cell"):
        fit_colony(image, MICROSCOPE, np.zeros_like(colony_masks))
    with pytest.raises(ValueError, match="no background"):
        fit_colony(image, MICROSCOPE, np.ones_like(colony_masks))
    with pytest.raises(ValueError, match="integer cell ids"):
        fit_colony(image, MICROSCOPE, colony_masks.astype(np.float32))
    with pytest.raises(TypeError, match="needs the colony's instance masks"):
        fit_colony(image, MICROSCOPE, None)
    with pytest.raises(TypeError, match=r"fit_colony\(microscope=...\) needs Microscope"):
        fit_colony(image, None, colony_masks)


def test_fit_colony_refuses_images_the_model_cannot_make(colony_masks):
    """Found as an API user: NaN pixels and a shifted image were reported as a negative
    or NaN cell intensity of RenderSettings; an RGBA image and a stack as masks of
    another shape."""
    image = np.random.default_rng(1).normal(500.0, 20.0, colony_masks.shape)
    holes = image.copy()
    holes[4:9, 4:9] = np.nan
    with pytest.raises(ValueError, match="25 NaN or infinite pixels"):
        fit_colony(holes, MICROSCOPE, colony_masks)
    with pytest.raises(ValueError, match="negative values"):
        fit_colony(image - 600, MICROSCOPE, colony_masks)
    with pytest.raises(ValueError, match="RGB"):
        fit_colony(np.stack([image] * 4, axis=-1), MICROSCOPE, colony_masks)
    with pytest.raises(ValueError, match="stack of 2 frames"):
        fit_colony(np.stack([image, image]), MICROSCOPE, colony_masks)


def test_fit_colony_refuses_a_recording_given_as_masks(colony_masks):
    """Found as a user of the API: the recording passed as its own masks was fitted (the
    CLI and fit_scene refused it, fit_colony did not)."""
    grey_levels = np.random.default_rng(0).integers(0, 40, colony_masks.shape, dtype=np.uint16)
    with pytest.raises(ValueError, match="does not look like instance masks"):
        fit_colony(grey_levels.astype(float), MICROSCOPE, grey_levels)


def test_resample_render_keeps_the_optics_and_the_kernel_reach_in_um():
    from napari_symbac.fit.colony import band_upsample, resample_render
    from napari_symbac.settings import RenderSettings

    fitted = RenderSettings(upsample=1, psf_radius_px=40, cell_phase_rad=0.45)  # 0.0745 um px
    coarse = Microscope(pixel_size_um=0.13, wavelength_um=0.55)
    moved = resample_render(fitted, 0.0745, coarse)
    assert moved.upsample == band_upsample(coarse) == 2  # 0.13 um > lambda / 4 NA
    assert moved.psf_radius_px * 0.13 / 2 == pytest.approx(40 * 0.0745, abs=0.065)
    assert moved.psf_radius_px * 0.13 / 2 >= 40 * 0.0745  # never shorter
    assert moved.cell_phase_rad == 0.45


def test_a_colony_below_one_grey_level_of_noise_is_drawn_with_noise(real_data_dir):
    """Found as a user: an 8-bit colony (Omnipose Sample000033) whose pixel noise is
    below one grey level measured 0 ADU, and its fitted settings rendered noiseless
    images. The measured noise is kept for the likelihood; the drawn noise is at least
    MIN_NOISE_ADU, so an image rendered with the fitted settings scatters as the real
    one does (a corner of it: 11 cells, 85 % pad)."""
    import imageio.v3 as iio

    from napari_symbac.fit.colony import MIN_NOISE_ADU

    root = real_data_dir / "omnipose"
    crop = (slice(150, 246), slice(0, 96))
    image = iio.imread(root / "Sample000033.png")[..., 0][crop]
    masks = np.asarray(tifffile.imread(root / "Sample000033_cp_masks.tif")[crop], np.int64)
    scope = dataclasses.replace(MICROSCOPE, pixel_size_um=0.134)  # a 1 um cell width
    fit = fit_colony(image, scope, masks, max_evaluations=6)
    assert fit.measured_noise_adu == 0.0
    assert fit.render.gaussian_noise_sd_adu == MIN_NOISE_ADU
    camera = Camera(baseline_adu=0.0, bit_depth=8)
    drawn = ForwardModel(scope, fit.render, camera).render(fit.scene, np.random.default_rng(1))
    flat = ndimage.binary_erosion(masks == 0, iterations=12)  # the pad beyond the halo
    real_sd, drawn_sd = (float(np.std(np.asarray(a, float)[flat])) for a in (image, drawn))
    assert real_sd > 0.2
    assert 0.5 * real_sd < drawn_sd < 3 * real_sd
