"""The fit on the real 100x trench (GPL-2 sample data read from ../shared/data/real)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_symbac.fit import fit_scene, otsu_cells
from napari_symbac.settings import Camera, Microscope, RenderSettings


@pytest.fixture(scope="module")
def real_crop(real_data_dir) -> np.ndarray:
    image = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    assert image.shape == (256, 46)
    return image[:128]  # closed end and the first cells


def test_trench_is_found_where_it_is(real_crop):
    microscope = Microscope(pixel_size_um=0.065)
    cells, otsu_width, trench, _ = otsu_cells(real_crop.astype(float), microscope)
    # ~23 px (1.5 um) wide trench near the middle of the 46 px crop, closed end at the top.
    assert 1.2 < trench.width_um < 1.8
    assert 0.3 < trench.left_um < 1.0
    assert 0.5 < trench.top_um < 2.5
    assert len(cells) >= 2
    assert np.all((otsu_width > 0) & (otsu_width < 1.5))


def test_rough_strokes_start_like_the_automatic_segmentation(real_crop):
    """Strokes down the cells' middle give the polarity, not the cells' outlines."""
    from napari_symbac.fit.start import start_scene

    microscope = Microscope(pixel_size_um=0.065)
    labels = np.zeros(real_crop.shape, np.uint8)
    labels[40:120:8, 22] = 1  # thin cell strokes, as a user paints them
    labels[40:120:8, 12] = 2
    labels[40:120:8, [2, 43]] = 3
    image = real_crop.astype(float)
    auto = start_scene(image, microscope)[0]
    painted = start_scene(image, microscope, labels=labels)[0]
    assert len(painted) == len(auto) >= 2
    # The same cells: the painted start places the trench first and uses it as given,
    # so region edges may differ by a few pixels.
    np.testing.assert_allclose(painted.y_um, auto.y_um, atol=0.25)
    # A region painted as media is no cell.
    _, _, _, instances = start_scene(image, microscope)
    biggest = np.argmax(np.bincount(instances.ravel())[1:]) + 1
    media = np.where(instances == biggest, 2, labels).astype(np.uint8)
    kept = start_scene(image, microscope, labels=media)[0]
    assert 1 <= len(kept) < len(auto)
    rows = (kept.y_um / 0.065).astype(int)
    cols = (kept.x_um / 0.065).astype(int)
    assert not np.any(media[rows, cols] == 2)


def test_scene_fit_lowers_the_residual_and_widens_the_otsu_cells(real_crop):
    microscope = Microscope(pixel_size_um=0.065)
    result = fit_scene(
        real_crop, microscope, RenderSettings(), Camera(), irls_rounds=1, max_iterations=8
    )
    assert result.objective_after < result.objective_before / 2
    assert np.sqrt(np.mean(result.residual**2)) < 0.5 * real_crop.std()
    # Model-based width is wider than Otsu's (supplement section 1.3 bias).
    assert result.cells.width_um[0] > np.median(result.otsu_width_um)
    assert 0.7 < result.cells.width_um[0] < 1.4


@pytest.mark.slow
def test_real_trench_holds_four_cells_and_no_hidden_duplicates(real_data_dir):
    """Three whole cells and one cut by the bottom edge, by eye; the start has 7 rods."""
    image = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    microscope = Microscope(pixel_size_um=0.065)
    fit = fit_scene(image, microscope, RenderSettings(), None, closed_end="round")
    assert len(fit.initial_cells) == 7
    assert len(fit.cells) == 4, fit.moves
    assert sum("merged" in move for move in fit.moves) == 3
    order = np.argsort(fit.cells.y_um)
    assert np.all(np.diff(fit.cells.y_um[order]) > 2.0)  # one after the other, no overlap
    assert fit.camera is not None
    assert fit.camera.sensitivity_adu_per_e > 0
    assert fit.objective_after < fit.objective_before / 2  # measured 2.57 -> 0.77


@pytest.mark.slow
def test_colicoords_fluorescence_count_equals_the_mask(real_data_dir):
    """ColiCoords ds1 field 1, a 120 x 250 crop holding four whole cells (80 nm pixels).

    Automatic start (bright cells from the modality), camera estimated, zeros of the
    background subtraction censored: as many fitted cells as connected components
    of the published binary mask.
    """
    from scipy import ndimage

    folder = real_data_dir / "colicoords" / "test_data" / "ds1"
    crop = (slice(80, 200), slice(60, 310))
    image = tifffile.imread(folder / "fluorescence" / "00001.tif")[crop]
    mask = tifffile.imread(folder / "binary" / "00001_Probabilities_filtered.tif")[crop]
    count = ndimage.label(mask > 0)[1]
    assert count == 4
    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    fit = fit_scene(image, microscope, RenderSettings(), None, geometry="open")
    assert len(fit.cells) == count, fit.moves
    assert not fit.valid[image == 0].any()  # clipped zeros left out
    # every fitted cell sits on one mask component
    labels = ndimage.label(mask > 0)[0]
    rows = (fit.cells.y_um / 0.08).astype(int)
    cols = (fit.cells.x_um / 0.08).astype(int)
    assert sorted(labels[rows, cols].tolist()) == [1, 2, 3, 4]


def test_a_background_above_the_baseline_is_fitted_from_the_first_round(real_data_dir):
    """ColiCoords ds3 frame 0 (its camera offset kept): the baseline guess (the 0.1 %
    quantile) leaves a few hundred background pixels below it and no measurable read
    noise, so weighing each pixel by its own value gave them 1/12 ADU^2 and about
    40 000 times a background pixel's weight: the start solved the media intensity to 0
    against a background 168 ADU above the baseline, and the moves then ran on that
    misfit (a dispersion of 1.2e5: a real cell removed, a blob with its angle and bend at
    their bounds in its place). The first round's variance now takes each pixel's level
    from its 3 x 3 neighbours."""
    from napari_symbac.fit.scene_fit import _run_frame

    image = tifffile.imread(real_data_dir / "colicoords" / "test_data" / "ds3" / "flu.tif")[0]
    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    run = _run_frame(
        image, microscope, RenderSettings(), None, geometry="open", irls_rounds=1,
        max_iterations=1, moves=False,
    )  # fmt: skip
    background = float(np.median(run.y))
    assert background > 100  # the pad's light above the baseline guess
    media = run.start.intensities[1]
    assert media == pytest.approx(background, rel=0.05)
    weights = run.problem.w[run.problem.w > 0]
    assert weights.max() < 20 * np.median(weights)


def test_a_start_wider_than_any_rod_is_refused_unless_cells_are_given(real_data_dir):
    """A 128 px corner of the Omnipose colony Sample000033 (0.118 um/px): its automatic
    start takes touching cells as regions wider than 3 um, a quarter of them or more, and
    is refused; painted strokes start the same way; ``refuse_wide=False`` (a series'
    frame started from the last frame's cells, tests/fit/test_series.py) takes it."""
    from napari_symbac.fit.start import MAX_START_WIDTH_UM, WideStartError, start_scene
    from napari_symbac.io import read_image

    image = np.asarray(read_image(real_data_dir / "omnipose" / "Sample000033.png").data, float)
    crop = image[60:188, 100:228]
    microscope = Microscope(pixel_size_um=0.118)
    with pytest.raises(WideStartError, match="wider than any rod-shaped bacterium") as refused:
        start_scene(crop, microscope, geometry="open")
    assert "give the cells' instance masks" in str(refused.value)
    assert "give" not in refused.value.cause
    strokes = np.zeros(crop.shape, np.uint8)
    strokes[::16, 64] = 1
    with pytest.raises(WideStartError):
        start_scene(crop, microscope, geometry="open", labels=strokes)
    _, widths, _, _ = start_scene(crop, microscope, geometry="open", refuse_wide=False)
    assert np.mean(widths > MAX_START_WIDTH_UM) >= 0.25


@pytest.mark.slow
def test_bright_field_cells_turn_past_horizontal_and_round_cells_report_as_drawn(
    real_data_dir,
):
    """ColiCoords ds2 bright field 00066 (MIT), 384 x 384 px with its masks. Found as a
    user: cells the moves added were turned to the angle's bound (+-1.6 rad then) and
    reported "at a bound"; a length fitted below the cell's width was reported as such
    (0.928 um +- 4e-11) while cells.json gave the width it is drawn at. Now the angles
    wrap (no angle at a bound, all in [-pi/2, pi/2)), and the parameters hold the
    lengths as drawn, a round cell's with no standard error and named at its bound."""
    ds2 = real_data_dir / "colicoords" / "test_data" / "ds2"
    window = np.s_[128:512, 128:512]
    image = tifffile.imread(ds2 / "brightfield" / "00066.tif")[window]
    masks = tifffile.imread(ds2 / "binary" / "00066_Probabilities_filtered.tif")[window]
    microscope = Microscope(pixel_size_um=0.08, modality="brightfield", wavelength_um=0.65)
    fit = fit_scene(image, microscope, RenderSettings(), geometry="open", masks=masks)
    assert not [name for name in fit.at_bounds if name.endswith("angle_rad")], fit.at_bounds
    angles = np.asarray(fit.cells.angle_rad)
    assert np.all((angles >= -np.pi / 2) & (angles < np.pi / 2))
    names = list(fit.parameter_names)
    for k, cell_id in enumerate(fit.cells.ids):
        i = names.index(f"cell{int(cell_id)}.length_um")
        assert fit.parameters[i] == pytest.approx(fit.cells.length_um[k])
        round_cell = fit.cells.length_um[k] <= fit.cells.width_um[k]
        assert np.isnan(fit.standard_errors[i]) == round_cell
        assert (f"cell{int(cell_id)}.length_um" in fit.at_bounds) == round_cell
