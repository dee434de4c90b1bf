"""Each cell's own optical path fitted to an image (fit.cell_gains, fit_colony's last stage)."""

from __future__ import annotations

import dataclasses

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.fit import FitCancelled, fit_colony
from napari_symbac.fit.cell_gains import fit_cell_gains
from napari_symbac.fit.colony import colony_start
from napari_symbac.fit.masks import class_medians, estimate_pixel_size_um
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import scale_cells
from napari_symbac.settings import Camera, Microscope

MICROSCOPE = Microscope(pixel_size_um=0.075, wavelength_um=0.55, modality="phase")
CAMERA = Camera(baseline_adu=0.0)
TRUE_GAINS = np.array([0.8, 1.2, 1.0, 0.9, 1.15, 1.05])


def _touching_rods() -> np.ndarray:
    """Six touching rods, 13 px (1 um) wide and 4.5 um long, a pad around them."""
    masks = np.zeros((110, 100), np.int64)
    for k in range(6):
        top = 16 + 13 * k
        masks[top : top + 13, 20:80] = k + 1
    return masks


@pytest.fixture(scope="module")
def rendered_colony():
    """The rods drawn with known gains on known optics, Gaussian noise of 1 ADU."""
    masks = _touching_rods()
    render, scene = colony_start(masks, MICROSCOPE, 90.0, 1.0)
    render = dataclasses.replace(render, cell_phase_rad=0.5)
    truth = scale_cells(scene, np.arange(1, 7), TRUE_GAINS)
    clean = ForwardModel(MICROSCOPE, render, CAMERA).render_clean(truth, cache=False)
    image = clean + np.random.default_rng(3).normal(0.0, 1.0, clean.shape)
    return image, scene, render


def test_the_gains_of_a_rendered_colony_are_recovered_within_their_errors(rendered_colony):
    image, scene, render = rendered_colony
    fit = fit_cell_gains(image, scene, MICROSCOPE, render, CAMERA, max_evaluations=40)
    gains = np.array([fit.gains[i] for i in range(1, 7)])
    errors = np.array([fit.standard_errors[i] for i in range(1, 7)])
    assert np.all(errors > 0)
    assert np.all(errors < 0.02)
    assert np.all(np.abs(gains - TRUE_GAINS) < np.maximum(3 * errors, 0.005)), gains
    assert fit.rms_before_adu > 3.0
    assert fit.rms_after_adu == pytest.approx(1.0, rel=0.05)  # down to the noise
    spread = np.std(TRUE_GAINS, ddof=1) / np.mean(TRUE_GAINS)
    assert fit.cv == pytest.approx(spread, abs=0.01)
    assert fit.warnings == ()
    assert fit.n_evaluations <= 40
    # the returned scene is the truth's: its image matches the noise-free one
    model = ForwardModel(MICROSCOPE, render, CAMERA)
    drawn = model.render_clean(fit.scene, cache=False)
    truth = model.render_clean(scale_cells(scene, np.arange(1, 7), TRUE_GAINS), cache=False)
    assert np.abs(drawn - truth).max() < 0.5


def test_identical_cells_get_no_spread_beyond_their_errors(rendered_colony):
    """Cells drawn alike: the fitted gains scatter by their errors only, and the spread
    handed to the export (``cv``) is the part the errors do not explain (about 0)."""
    _, scene, render = rendered_colony
    clean = ForwardModel(MICROSCOPE, render, CAMERA).render_clean(scene, cache=False)
    image = clean + np.random.default_rng(5).normal(0.0, 1.0, clean.shape)
    fit = fit_cell_gains(image, scene, MICROSCOPE, render, CAMERA, max_evaluations=30)
    gains = np.array(list(fit.gains.values()))
    assert np.abs(gains - 1).max() < 0.01
    assert fit.cv < 0.005


def test_bad_input_is_refused_with_the_fix_and_a_cancel_stops_the_fit(rendered_colony):
    image, scene, render = rendered_colony
    with pytest.raises(ValueError, match="draw the scene from the image's own masks"):
        fit_cell_gains(image[:50], scene, MICROSCOPE, render, CAMERA)
    holes = image.copy()
    holes[3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN or infinite"):
        fit_cell_gains(holes, scene, MICROSCOPE, render, CAMERA)
    with pytest.raises(ValueError, match="reach_um must be positive"):
        fit_cell_gains(image, scene, MICROSCOPE, render, CAMERA, reach_um=0.0)
    with pytest.raises(FitCancelled):
        fit_cell_gains(image, scene, MICROSCOPE, render, CAMERA, cancel=lambda: True)
    with pytest.raises(ValueError, match="one gain per cell id"):
        scale_cells(scene, np.arange(1, 7), np.ones(5))
    with pytest.raises(ValueError, match="finite and non-negative"):
        scale_cells(scene, np.arange(1, 7), -np.ones(6))


@pytest.mark.slow
def test_a_real_colony_of_long_cells_reaches_its_cells_brightness(real_data_dir):
    """Omnipose Sample000252 (MIT), 240 px of its densest long cells: with one optical
    path for all cells the fitted cells were 0.085 darker than the real ones in the
    normalised class medians (docs/rendering.md); each cell's own path brings them
    within 0.05, lowers the residual, and hands its spread to the settings."""
    root = real_data_dir / "omnipose"
    crop = (slice(280, 520), slice(320, 560))
    image = iio.imread(root / "Sample000252.png")
    masks = np.asarray(tifffile.imread(root / "Sample000252_cp_masks.tif"), np.int64)
    px = estimate_pixel_size_um(masks)
    image, masks = image[crop], masks[crop]
    scope = Microscope(pixel_size_um=px, wavelength_um=0.55, numerical_aperture=1.45)
    far = 2.0 / px
    real = class_medians(image.astype(np.float64), masks, far)
    fits = {gains: fit_colony(image, scope, masks, cell_gains=gains) for gains in (False, True)}

    def cells_median(fit) -> float:
        drawn = ForwardModel(scope, fit.render, fit.camera).render(
            fit.scene, np.random.default_rng(0)
        )
        return class_medians(drawn.astype(np.float64), masks, far)["cells"]

    one_path, own_paths = fits[False], fits[True]
    assert one_path.cell_gains == {}
    assert one_path.render.cell_brightness_cv == 0
    assert real["cells"] - cells_median(one_path) > 0.06  # the darker cells of before
    assert cells_median(own_paths) == pytest.approx(real["cells"], abs=0.05)
    assert own_paths.objective_after < 0.85 * one_path.objective_after
    assert np.std(own_paths.residual) < np.std(one_path.residual)
    assert set(own_paths.cell_gains) == set(np.unique(masks[masks > 0]).tolist())
    assert 0.05 < own_paths.render.cell_brightness_cv < 0.4
    assert own_paths.render.cell_brightness_max_gain > 1
    table = own_paths.cells_table()
    assert len(table["optical_path_gain"]) == len(table["ids"])
    assert own_paths.warnings == ()
