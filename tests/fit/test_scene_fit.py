"""Analysis by synthesis: fit_scene recovers cell sizes that Otsu gets wrong."""

from __future__ import annotations

import numpy as np
import pytest
from _fit_synthetic import PIXEL_UM, TRENCH, TRUTH, make_cells

from napari_symbac.fit import (
    FitCancelled,
    SceneFit,
    TrenchPlacement,
    fit_scene,
    otsu_cells,
    scene_classes,
)
from napari_symbac.fit.placement import draw_fitted as _draw
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

START = RenderSettings(apodisation_sigma_um=1.0, defocus_sigma_um=0.05, psf_offset=0.0)
#: The fixture's progress calls, ``(done, total)``.
PROGRESS: list[tuple[int, int]] = []


def _to_image_coordinates(cells: FrameCells, margin_um: float) -> FrameCells:
    return FrameCells(
        cells.ids,
        cells.x_um + margin_um,
        cells.y_um + margin_um,
        cells.angle_rad,
        cells.length_um,
        cells.width_um,
    )


@pytest.fixture(scope="module")
def scene_fit(truth) -> SceneFit:
    PROGRESS.clear()
    return fit_scene(
        truth.image,
        truth.microscope,
        START,
        truth.camera,
        labels=scene_classes(truth.scene),
        irls_rounds=2,
        max_iterations=15,
        progress=lambda done, total: PROGRESS.append((done, total)),
    )


def test_progress_ends_at_the_renders_done(scene_fit):
    """Found as a user: the Tune dock's Auto-fit ended on "8748 renders (at most 8748)"
    and then said "Fitted in 3117 renders": the last call reported the bound as done."""
    assert PROGRESS[-1] == (scene_fit.n_evaluations, scene_fit.n_evaluations)
    assert all(0 <= done <= total for done, total in PROGRESS)
    assert PROGRESS[-2][1] > scene_fit.n_evaluations  # the bound, well above


def test_fit_scene_draws_with_draw_scene(truth):
    """Cells in image coordinates and a placed trench draw the pipeline's scene."""
    m = TRENCH.margin_um
    placement = TrenchPlacement(m, TRENCH.width_um, m, TRENCH.depth_um)
    scene = _draw(
        _to_image_coordinates(truth.cells, m),
        placement,
        truth.image.shape,
        truth.microscope,
        truth.render,
    )
    for name in ("cells", "media", "device", "labels"):
        np.testing.assert_array_equal(getattr(scene, name), getattr(truth.scene, name))


def test_fitted_scene_is_drawn_from_the_fitted_cells(scene_fit, truth):
    fitted = scene_fit.cells
    m = scene_fit.trench
    again = draw_scene(
        FrameCells(
            fitted.ids,
            fitted.x_um - m.left_um,
            fitted.y_um - m.top_um,
            fitted.angle_rad,
            fitted.length_um,
            fitted.width_um,
        ),
        TrenchGeometry(width_um=m.width_um, depth_um=m.depth_um, margin_um=0.0),
        truth.microscope,
        scene_fit.render,
        scene_fit.curvature(),
        trench_origin_um=(m.left_um, m.top_um),
        camera_shape=truth.image.shape,
    )
    np.testing.assert_array_equal(again.cells, scene_fit.scene.cells)
    np.testing.assert_array_equal(again.labels, scene_fit.scene.labels)


def test_scene_fit_recovers_widths_and_lengths(scene_fit, truth):
    fitted = scene_fit.cells
    assert len(fitted) == len(truth.cells)
    order = np.argsort(fitted.y_um)
    true = _to_image_coordinates(truth.cells, TRENCH.margin_um)
    np.testing.assert_allclose(fitted.width_um[order], true.width_um, atol=0.020)
    np.testing.assert_allclose(fitted.length_um[order], true.length_um, atol=0.050)
    np.testing.assert_allclose(fitted.x_um[order], true.x_um, atol=0.03)
    np.testing.assert_allclose(fitted.y_um[order], true.y_um, atol=0.03)
    np.testing.assert_allclose(fitted.angle_rad[order], true.angle_rad, atol=0.03)
    assert scene_fit.trench.width_um == pytest.approx(TRENCH.width_um, abs=0.02)
    assert scene_fit.trench.left_um == pytest.approx(TRENCH.margin_um, abs=0.02)
    assert np.all(np.abs(scene_fit.curvature_um) < 0.03)  # straight cells stay straight


def test_scene_fit_reaches_the_noise_and_fits_intensities(scene_fit, truth):
    assert scene_fit.objective_after == pytest.approx(1.0, abs=0.1)  # reduced chi-square
    assert scene_fit.objective_before > 2 * scene_fit.objective_after
    for name in ("cell_intensity", "media_intensity", "device_intensity"):
        assert getattr(scene_fit.render, name) == pytest.approx(
            getattr(truth.render, name), rel=0.03
        ), name
    assert scene_fit.render.defocus_sigma_um == pytest.approx(0.15, abs=0.03)
    assert scene_fit.residual.shape == truth.image.shape
    assert np.abs(scene_fit.residual).mean() < 100  # ~ the camera noise (80 ADU)
    assert {"pixel", "eq20", "class_stats"} <= set(scene_fit.terms)


def test_otsu_is_biased_narrow_and_short(truth):
    cells, otsu_width, trench, instances = otsu_cells(truth.image.astype(float), truth.microscope)
    assert len(cells) == 3
    assert instances.max() == 3
    assert np.all(otsu_width < truth.cells.width_um - 0.15)  # section 1.3 of the supplement
    assert trench is not None


def test_scene_fit_inputs_are_checked(truth):
    with pytest.raises(ValueError, match="single frame"):
        fit_scene(np.stack([truth.image] * 2), truth.microscope, START, truth.camera)
    with pytest.raises(ValueError, match="do not match"):
        fit_scene(truth.image, truth.microscope, START, truth.camera, labels=np.zeros((5, 5)))
    with pytest.raises(ValueError, match="width_sd_um"):
        fit_scene(truth.image, truth.microscope, START, truth.camera, width_sd_um=-1.0)
    with pytest.raises(ValueError, match="curvature_sd_um"):
        fit_scene(truth.image, truth.microscope, START, truth.camera, curvature_sd_um=0.0)
    with pytest.raises(FitCancelled):
        fit_scene(truth.image, truth.microscope, START, truth.camera, cancel=lambda: True)


#: Truth of the curvature test: a (um) of eq. 1 with b = 1, c = 0 (one bend) per cell.
BENDS = np.array([0.12, 0.0, -0.15])
#: A 120 x 46 crop of the 1.5 um trench, three cells, two of them bent.
CURVED_TRENCH = TrenchGeometry(
    length_um=120 * PIXEL_UM - 0.75, width_um=1.5, depth_um=1.2, margin_um=0.75
)


@pytest.fixture(scope="module")
def curved():
    cells = make_cells(
        y_um=[1.2, 3.65, 5.95],
        x_um=[0.7, 0.77, 0.8],
        angle_rad=[0.0, 0.04, -0.03],
        length_um=[2.2, 2.4, 1.8],
        width_um=0.9,
    )
    bends = {int(i): (float(a), 1.0, 0.0) for i, a in zip(cells.ids, BENDS) if a}
    microscope, camera = Microscope(pixel_size_um=PIXEL_UM), Camera()
    scene = draw_scene(cells, CURVED_TRENCH, microscope, TRUTH, bends)
    image = ForwardModel(microscope, TRUTH, camera).render(scene, np.random.default_rng(3))
    fit = fit_scene(image, microscope, START, camera, irls_rounds=2, max_iterations=15)
    return cells, fit


def test_scene_fit_recovers_curvature(curved):
    cells, fit = curved
    order = np.argsort(fit.cells.y_um)
    assert len(order) == len(cells)
    np.testing.assert_allclose(fit.curvature_um[order], BENDS, atol=0.04)
    assert abs(fit.curvature_um[order][1]) < 0.03  # the straight cell stays straight
    np.testing.assert_allclose(fit.cells.width_um[order], cells.width_um, atol=0.020)
    np.testing.assert_allclose(fit.cells.length_um[order], cells.length_um, atol=0.050)
    assert fit.objective_after == pytest.approx(1.0, abs=0.1)
    bent = fit.curvature()  # draw_scene's mapping: id -> (a, b, c), b = 1, c = 0
    assert bent[int(fit.cells.ids[order[2]])] == (fit.curvature_um[order[2]], 1.0, 0.0)


def _noisy_frame() -> np.ndarray:
    return np.random.default_rng(3).normal(1000.0, 30.0, (64, 48))


def test_fit_scene_refuses_arguments_of_the_wrong_kind_in_words():
    """Found as an API user: None or swapped settings failed deep inside with
    "'NoneType' object has no attribute 'modality'" and the like."""
    image, microscope, render = _noisy_frame(), Microscope(pixel_size_um=0.065), RenderSettings()
    with pytest.raises(TypeError, match=r"fit_scene\(microscope=...\) needs Microscope"):
        fit_scene(image, None, render)
    with pytest.raises(TypeError, match=r"needs Microscope, got RenderSettings.*order"):
        fit_scene(image, render, microscope)
    with pytest.raises(TypeError, match=r"fit_scene\(trench=...\) needs TrenchPlacement"):
        fit_scene(image, microscope, render, trench="round")
    with pytest.raises(TypeError, match=r"got dict: pass Camera\(\*\*that_dict\)"):
        fit_scene(image, microscope, render, camera={"baseline_adu": 100})


def test_fit_scene_refuses_images_no_camera_wrote():
    """Found as an API user: a shifted image (negative values) and DeLTA's normalised
    trench were fitted without a word (gain 1.5e-6 ADU/e-, cell intensity 0), though
    the CLI refused both."""
    microscope, render = Microscope(pixel_size_um=0.065), RenderSettings()
    with pytest.raises(ValueError, match=r"negative values.*camera=Camera\(baseline_adu"):
        fit_scene(_noisy_frame() - 5000, microscope, render)
    with pytest.raises(ValueError, match=r"within 0\.\.1 only.*napari_symbac\.io\.as_counts"):
        fit_scene(_noisy_frame() / 2000, microscope, render)
    with pytest.raises(ValueError, match=r"normalised values.*napari_symbac\.io\.as_counts"):
        fit_scene(_noisy_frame() / 200, microscope, render)


def test_fit_scene_refuses_masks_that_are_not_instance_masks():
    """Found as an API user: a float mask of 1.5 was fitted as one cell; negative ids
    and empty masks were reported as "the start found no cells"."""
    image, microscope, render = _noisy_frame(), Microscope(pixel_size_um=0.065), RenderSettings()
    masks = np.zeros(image.shape, np.int64)
    masks[20:30, 10:20] = 1
    with pytest.raises(ValueError, match="integer cell ids"):
        fit_scene(image, microscope, render, masks=masks * 1.5)
    with pytest.raises(ValueError, match="negative ids"):
        fit_scene(image, microscope, render, masks=-masks)
    with pytest.raises(ValueError, match="holds no cell"):
        fit_scene(image, microscope, render, masks=np.zeros_like(masks))
    with pytest.raises(ValueError, match="but the image frame has shape"):
        fit_scene(image, microscope, render, masks=masks[:-1])


def test_the_command_lines_word_field_is_an_open_geometry():
    """Found as an API user: `fit --geometry field` but fit_scene(geometry="open"); the
    CLI's word was refused from Python."""
    image = _noisy_frame()
    masks = np.zeros(image.shape, np.int64)
    masks[20:30, 10:20] = 1
    microscope = Microscope(pixel_size_um=0.065, modality="fluorescence")
    image[masks > 0] += 500
    kwargs = {"masks": masks, "max_iterations": 2, "irls_rounds": 1, "moves": False}
    field = fit_scene(image, microscope, RenderSettings(), geometry="field", **kwargs)
    open_ = fit_scene(image, microscope, RenderSettings(), geometry="open", **kwargs)
    assert field.trench is None
    np.testing.assert_array_equal(field.synthetic, open_.synthetic)
    with pytest.raises(ValueError, match=r"'trench' or 'open' \('field'\), got 'pad'"):
        fit_scene(image, microscope, RenderSettings(), geometry="pad")
