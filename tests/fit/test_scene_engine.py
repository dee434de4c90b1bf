"""The scene-fit engine: exact intensities, local patches, moves, camera, uncertainty."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _fit_synthetic import START, TRENCH, make_fluorescence_field
from scipy import ndimage, optimize

from napari_symbac.fit import fit_scene
from napari_symbac.fit.engine import Layout, SceneModel, solve_intensities
from napari_symbac.fit.overlap import overlap_terms
from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.fit.start import polarity_of, start_scene
from napari_symbac.settings import Camera, RenderSettings


@pytest.mark.parametrize("seed", range(6))
def test_intensities_are_the_exact_non_negative_least_squares(seed):
    rng = np.random.default_rng(seed)
    a = rng.random((200, 3))
    a[:, 2] *= 0.01 if seed % 2 else 1.0
    truth = rng.normal(size=3) * 100  # some negative: the fallback must clip them
    y = a @ truth + rng.normal(size=200)
    w = rng.uniform(0.5, 2.0, 200)
    got = solve_intensities(a, y, w)
    sw = np.sqrt(w)
    want = optimize.nnls(a * sw[:, None], y * sw)[0]
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-7)
    assert np.all(got >= 0)


def test_all_zero_columns_get_zero_intensity():
    a = np.zeros((50, 3))
    a[:, 0] = 1.0
    a[:, 1] = np.linspace(0, 1, 50)
    y = 3 + 2 * a[:, 1]
    got = solve_intensities(a, y, np.ones(50))
    np.testing.assert_allclose(got, [3, 2, 0], atol=1e-9)


def _model(truth, n=3):
    microscope = truth.microscope
    placement = TrenchPlacement(TRENCH.margin_um, TRENCH.width_um, TRENCH.margin_um, 1.2)
    layout = Layout(n, True, False, True, True, ("defocus_sigma_um",))
    model = SceneModel(
        truth.image.shape, microscope, truth.render, Camera(), placement, 1.2, layout
    )
    m = TRENCH.margin_um
    blocks = np.stack(
        [
            truth.cells.x_um + m,
            truth.cells.y_um + m,
            truth.cells.angle_rad,
            truth.cells.length_um,
            np.array([0.0, 0.1, 0.0]),
        ],
        axis=1,
    )
    shared = [0.95, m, TRENCH.width_um, m, 0.15]
    return model, np.concatenate([blocks.ravel(), shared])


@pytest.mark.parametrize("k", [0, 1, 2, 3, 4, 6, 8])
def test_cell_patch_equals_the_difference_of_full_renders(truth, k):
    """Linearity of the convolution: one cell's change is local and exact."""
    model, x = _model(truth)
    a, scene, render = model.design(x)
    x_new = x.copy()
    x_new[k] += 0.04
    owner = model.layout.owner(k)
    kernel = model.forward.with_render(render).kernel(scene.pixel_size_um)
    row0, col0, patch = model.cell_delta(x, x_new, owner, scene, kernel)
    a_new, _, _ = model.design(x_new)
    full = (a_new[:, 0] - a[:, 0]).reshape(truth.image.shape)
    local = np.zeros_like(full)
    rows, cols = full.shape
    ph, pw = patch.shape
    r0, c0 = max(row0, 0), max(col0, 0)
    r1, c1 = min(row0 + ph, rows), min(col0 + pw, cols)
    local[r0:r1, c0:c1] = patch[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0]
    assert np.abs(full).max() > 1e-3  # the move changed the image
    np.testing.assert_allclose(local, full, atol=2e-5 * np.abs(full).max() + 1e-6)
    # and the media image changed by exactly minus that (media = trench - cells)
    np.testing.assert_allclose((a_new[:, 1] - a[:, 1]).reshape(full.shape), -full, atol=1e-5)


@pytest.mark.parametrize("fused", [True, False])
@pytest.mark.parametrize("factor", [1, 2, 3])
def test_patch_convolution_is_fftconvolve_in_full_then_block_mean(factor, fused, monkeypatch):
    """A cell patch goes through the backend's fused circular transform (or, for a backend
    without it, the plain valid convolution of the zero-padded patch): both are the full
    ``fftconvolve`` of the patch, block-averaged to camera pixels."""
    from types import SimpleNamespace

    from scipy.signal import fftconvolve

    from napari_symbac.optics.backends import ScipyBackend
    from napari_symbac.settings import Microscope

    microscope = Microscope(pixel_size_um=0.065)
    render = RenderSettings(upsample=factor, defocus_sigma_um=0.1)
    layout = Layout(1, False, False, False, False, ())
    model = SceneModel((40, 30), microscope, render, Camera(), None, 1.2, layout)
    kernel = model.forward.kernel(microscope.pixel_size_um / factor)
    ky, kx = kernel.shape
    calls = []
    if fused:
        circular = model.forward.backend.convolve_resample_circular
        monkeypatch.setattr(
            model.forward.backend,
            "convolve_resample_circular",
            lambda *args: calls.append(args[0].shape) or circular(*args),
        )
    else:  # only what every backend has
        model.forward.backend = SimpleNamespace(convolve_valid=ScipyBackend().convolve_valid)
    rng = np.random.default_rng(factor)
    height = factor * (-(-(ky + 30) // factor)) - (ky - 1)  # the full output a multiple
    width = factor * (-(-(kx + 20) // factor)) - (kx - 1)
    patch = (rng.random((3, height, width)) - 0.5).astype(np.float32)
    patch[1, 5:9] += 2.0  # a sharp edge, as a cell's
    got = model._convolve_patch(patch, kernel, factor)
    full = np.stack([fftconvolve(p.astype(np.float64), kernel.astype(np.float64)) for p in patch])
    rows, cols = full.shape[1] // factor, full.shape[2] // factor
    want = full.reshape(3, rows, factor, cols, factor).mean(axis=(2, 4))  # in float64
    assert calls == ([(3, height + ky - 1, width + kx - 1)] if fused else [])
    assert got.dtype == np.float64
    assert got.shape == want.shape == (3, (height + ky - 1) // factor, (width + kx - 1) // factor)
    np.testing.assert_allclose(got, want, rtol=0, atol=3e-7 * np.ptp(want))


def test_overlapping_rods_are_penalised_and_touching_ones_are_not():
    layout = Layout(2, False, False, False, False, ())
    apart = np.array([1.0, 1.5, 0.0, 2.0, 1.0, 3.5, 0.0, 2.0, 1.0])  # end to end
    inside = np.array([1.0, 1.5, 0.0, 3.0, 1.0, 1.8, 0.0, 1.2, 1.0])  # one in the other
    assert overlap_terms(apart, layout)[0].size == 0
    res, jac = overlap_terms(inside, layout, np.full(9, 0.05))
    assert res.size == 1
    assert res[0] > 10
    assert np.abs(jac).sum() > 0


def test_a_rod_through_a_trench_wall_is_penalised_and_a_tilted_one_is_not():
    layout = Layout(1, False, False, True, False, ())  # x, y, angle, length; w, left, width
    upright = np.array([1.2, 3.0, 0.0, 3.0, 1.0, 0.5, 1.4])
    tilted = np.array([1.2, 3.0, -0.14, 4.7, 1.0, 0.5, 1.4])  # as on the real trench
    across = np.array([1.2, 3.0, 1.5, 3.0, 1.0, 0.5, 1.4])  # 3 um across a 1.4 um trench
    assert overlap_terms(upright, layout)[0].size == 0
    assert overlap_terms(tilted, layout)[0].size == 0
    res, jac = overlap_terms(across, layout, np.full(7, 0.05))
    # reaches 2.99 sin(1.5) / 2 + 0.5 = 1.49 um from its centre, 0.79 um past each wall
    expected = (1.0 * np.sin(1.5) + 0.5 - 0.7 - 0.25 * 1.0) / 0.02
    np.testing.assert_allclose(res, [expected], rtol=1e-9)
    # turning it upright and widening the trench both relieve it; y does not matter
    assert jac[0, 2] > 0
    assert jac[0, 6] < 0
    assert jac[0, 1] == 0
    # a pad has no walls
    pad = Layout(1, False, False, False, False, ())
    assert overlap_terms(across[:5], pad)[0].size == 0


def test_polarity_comes_from_labels_before_the_modality():
    image = np.full((20, 20), 100.0)
    image[5:15, 5:15] = 500.0
    labels = np.zeros((20, 20), int)
    labels[8:12, 8:12] = 1
    labels[0:3] = 2
    assert polarity_of(image, "phase", labels) == "bright"
    assert polarity_of(image, "phase") == "dark"
    assert polarity_of(image, "fluorescence") == "bright"


def test_fluorescence_trench_needs_a_placement():
    field = make_fluorescence_field()
    with pytest.raises(ValueError, match="trench=TrenchPlacement"):
        start_scene(field.image.astype(float), field.microscope, geometry="trench")


def test_camera_from_the_model_residual_and_its_flat_fallback():
    """After a round the camera comes from photon transfer against the model mean;
    a model too flat for a slope gives a constant variance, the residual's."""
    from napari_symbac.fit.scene_fit import _camera_from_model

    rng = np.random.default_rng(4)
    mu = np.repeat(np.linspace(100, 5000, 400)[:, None], 400, axis=1)
    var = 2.9 * mu + (2.9 * 8.0) ** 2 + 1 / 12
    real = mu + 100.0 + rng.normal(0, np.sqrt(var))
    valid = np.ones(real.shape, bool)
    est = _camera_from_model(real, valid, mu + 100.0, Camera(baseline_adu=100.0))
    assert est.sensitivity_adu_per_e == pytest.approx(2.9, rel=0.03)
    assert est.baseline_adu == 100.0
    flat = np.full((100, 100), 600.0)
    noisy = flat + rng.normal(0, 30.0, flat.shape)
    est = _camera_from_model(noisy, valid[:100, :100], flat, Camera(baseline_adu=100.0))
    assert est.sensitivity_adu_per_e == pytest.approx(1e-3)
    total = est.sensitivity_adu_per_e**2 * est.dark_noise_e**2 + 1 / 12
    assert total == pytest.approx(900.0, rel=0.05)


@pytest.fixture(scope="module")
def fluorescence_fit():
    field = make_fluorescence_field()
    fit = fit_scene(
        field.image, field.microscope, RenderSettings(defocus_sigma_um=0.0), None, geometry="open"
    )
    return field, fit


def test_fluorescence_field_is_recovered_with_its_camera(fluorescence_fit):
    truth, fit = fluorescence_fit
    assert len(fit.cells) == len(truth.cells)
    got = np.argsort(fit.cells.y_um * 100 + fit.cells.x_um)
    want = np.argsort(truth.cells.y_um * 100 + truth.cells.x_um)
    np.testing.assert_allclose(fit.cells.width_um[got], truth.cells.width_um[want], atol=0.020)
    np.testing.assert_allclose(fit.cells.length_um[got], truth.cells.length_um[want], atol=0.050)
    # each cell's own intensity (fluorescence: I_c (1 + dbrightness)) and the background
    table = fit.cells_table()
    np.testing.assert_allclose(table["intensity_adu"], truth.render.cell_intensity, rtol=0.02)
    assert fit.render.media_intensity == pytest.approx(truth.render.media_intensity, rel=0.02)
    assert fit.camera.sensitivity_adu_per_e == pytest.approx(2.9, rel=0.05)
    assert fit.objective_after == pytest.approx(1.0, abs=0.1)  # reduced chi-square
    assert fit.trench is None
    assert not fit.warnings


def test_uncertainty_api(fluorescence_fit):
    truth, fit = fluorescence_fit
    p = len(fit.parameter_names)
    assert fit.parameters.shape == fit.standard_errors.shape == (p,)
    assert fit.information.shape == (p, p)
    np.testing.assert_allclose(fit.information, fit.information.T, rtol=1e-9, atol=1e-9)
    assert np.all(fit.standard_errors > 0)
    assert np.all(np.isfinite(fit.standard_errors))
    jac = fit.jacobian()
    assert jac.shape == (truth.image.size, p)
    # information = J^T W J (+ priors on curvature only, none on the x_um columns)
    k = fit.parameter_names.index("cell1.x_um")
    col = jac[:, k].toarray().ravel()
    w = fit.valid.ravel() / np.maximum(fit.synthetic.ravel() - fit.camera.baseline_adu, 0)
    assert np.count_nonzero(col) < 0.5 * col.size  # a cell's column is local
    assert fit.information[k, k] > 0
    assert np.sum(col**2 * w) > 0
    table = fit.cells_table()
    assert len(table["length_um_se"]) == len(fit.cells)
    assert all(0 < se < 0.1 for se in table["length_um_se"])
    assert fit.standard_error("width_um") == table["width_um_se"][0]
    with pytest.raises(ValueError, match="no fitted parameter"):
        fit.standard_error("nonsense")


def test_convergence_history_records_the_descent(fluorescence_fit):
    _, fit = fluorescence_fit
    history = np.asarray(fit.history)
    assert history.size >= 2
    assert np.all(np.isfinite(history))
    # the first round starts far from the optimum and ends near the final fit
    assert history[0] > history.min()
    assert history.min() <= 1.5 * fit.objective_after


def test_censored_pixels_are_left_out(truth):
    image = truth.image.copy()
    image[40:44, 10:30] = 65535  # a saturated streak across a cell
    fit = fit_scene(
        image, truth.microscope, START, truth.camera, irls_rounds=1, max_iterations=10, moves=False
    )
    assert not fit.valid[40:44, 10:30].any()
    assert fit.valid.sum() == image.size - 80
    assert fit.objective_after < 1.3  # the streak does not count


def test_a_cell_split_in_the_start_mask_is_merged_back(truth):
    """Moves: an instance mask with one cell cut in two ends with the true count."""
    from napari_symbac.fit import scene_classes

    labels = truth.scene.camera_labels().astype(np.int64)
    assert labels.max() == 3
    rows = np.nonzero(labels == 2)[0]
    cut = (rows.min() + rows.max()) // 2
    labels[(labels == 2) & (np.arange(labels.shape[0])[:, None] > cut)] = 4
    assert ndimage.label(labels > 0)[1] <= 4
    fit = fit_scene(
        truth.image,
        truth.microscope,
        START,
        truth.camera,
        masks=labels,
        labels=scene_classes(truth.scene),
        irls_rounds=2,
        max_iterations=12,
    )
    assert len(fit.initial_cells) == 4
    assert len(fit.cells) == 3, fit.moves
    assert any("merged" in move for move in fit.moves)


def test_jacobian_columns_match_full_renders(truth):
    """The shared width's column (sum of the cells' patches) and a cell's column."""
    model, x = _model(truth)
    a, scene, render = model.design(x)
    intensities = np.array([1400.0, 2600.0, 900.0])
    free = np.zeros(x.size, bool)
    width, cell = model.layout.n * model.layout.per_cell, 5  # shared width, cell 2's x
    free[[cell, width]] = True
    jac = model.jacobian(x, a, intensities, scene, render, free).toarray()
    scales = model.layout.scales()
    for column, k in enumerate((cell, width)):
        xk = x.copy()
        xk[k] += 0.3 * scales[k]
        ak, _, _ = model.design(xk)
        want = (ak - a) @ intensities / 0.3
        np.testing.assert_allclose(jac[:, column], want, atol=1e-3 * np.abs(want).max())
    np.testing.assert_allclose(jac[:, 2:], a)  # d mu / d intensities


def test_kernel_column_and_per_cell_brightness_are_exact(truth):
    """The optics column without a redraw equals a full render; the brightness-weighted
    cells column (one transform) equals the sum of the cells' own patches."""
    from napari_symbac.fit.engine import _add_patch

    base, x = _model(truth)
    lay = dataclasses.replace(base.layout, per_cell_brightness=True)
    model = SceneModel(
        truth.image.shape, truth.microscope, truth.render, Camera(), base.placement, 1.2, lay
    )
    blocks = np.concatenate([x[: 3 * 5].reshape(3, 5), [[0.3], [-0.2], [0.0]]], axis=1)
    x = np.concatenate([blocks.ravel(), x[3 * 5 :]])
    a, scene, render = model.design(x)
    plain = model.design(_without_brightness(x, lay))[0]
    kernel = model.forward.with_render(render).kernel(scene.pixel_size_um)
    want = plain[:, 0].copy()
    for i, db in enumerate((0.3, -0.2)):
        _add_patch(want, truth.image.shape, *model.cell_delta(x, x, i, scene, kernel, True), db)
    assert np.abs(a[:, 0] - plain[:, 0]).max() > 0.1 * np.abs(want).max()  # brightness shows
    np.testing.assert_allclose(a[:, 0], want, atol=1e-4 * np.abs(want).max())
    intensities = np.array([1400.0, 2600.0, 900.0])
    k = x.size - 1  # defocus
    free = np.zeros(x.size, bool)
    free[k] = True
    column = model.jacobian(x, a, intensities, scene, render, free).toarray()[:, 0]
    xk = x.copy()
    xk[k] += 0.3 * lay.scales()[k]
    full = (model.design(xk)[0] - a) @ intensities / 0.3
    np.testing.assert_allclose(column, full, atol=1e-3 * np.abs(full).max())


def _without_brightness(x, layout):
    out = x.copy()
    pc = layout.per_cell
    for i in range(layout.n):
        out[i * pc + layout.i_brightness] = 0.0
    return out


def test_a_cell_missing_from_the_start_mask_is_added(truth):
    """Moves: a mask that misses one of the three cells ends with all three."""
    labels = truth.scene.camera_labels().astype(np.int64)
    labels[labels == 3] = 0
    fit = fit_scene(
        truth.image,
        truth.microscope,
        START,
        truth.camera,
        masks=labels,
        irls_rounds=2,
        max_iterations=12,
    )
    assert len(fit.initial_cells) == 2
    assert len(fit.cells) == 3, fit.moves
    assert any("added" in move for move in fit.moves)
    order = np.argsort(fit.cells.y_um)
    true_y = truth.cells.y_um + TRENCH.margin_um
    np.testing.assert_allclose(fit.cells.y_um[order], true_y, atol=0.05)


def test_a_cell_that_changes_no_pixel_is_pruned_after_the_last_round(truth):
    """The moves run after the first round; a cell they added can be pushed off its
    neighbour and out of the image by the later rounds, where it pays for nothing
    (found on a crop of ColiCoords ds3 frame 0: three cells parked at the field's edge
    bound). The final prune removes such a cell and keeps the three real ones."""
    from napari_symbac.fit.moves import prune_cells
    from napari_symbac.fit.problem import Problem
    from napari_symbac.fit.scene_fit import _run_frame

    run = _run_frame(
        truth.image, truth.microscope, START, truth.camera, irls_rounds=1, max_iterations=6,
        moves=False,
    )  # fmt: skip
    problem, state = run.problem, run.state
    blocks, shared = problem.blocks(state.x)
    assert len(blocks) == 3
    parked = blocks[0].copy()
    parked[0] = problem.lower(4)[0]  # its centre at the left bound, out of the image
    with_parked = problem.evaluate(Problem.join(np.vstack([blocks, parked]), shared))
    assert with_parked.chi2 == pytest.approx(state.chi2, rel=1e-9)  # it changes no pixel
    pruned, log = prune_cells(problem, with_parked)
    assert problem.n_cells(pruned.x) == 3
    assert log == [f"removed cell at ({parked[0]:.2f}, {parked[1]:.2f}) um"]
    np.testing.assert_array_equal(problem.blocks(pruned.x)[0], blocks)


@pytest.mark.parametrize("modality", ["phase", "fluorescence", "brightfield"])
def test_an_image_of_noise_alone_is_refused_as_holding_no_cells(modality):
    """Found as a user: a frame of pure noise fitted "1 cell" 0.3 um wide at the width's
    bound, its intensity 721 +- 639, exit 0: the moves kept the last cell whatever it
    was worth; as a trench it was told it held "2 trenches side by side". The start
    refuses a frame that holds nothing but noise, whatever its modality and geometry."""
    from napari_symbac.settings import Microscope

    noise = np.random.default_rng(3).normal(1000, 30, (96, 96))
    with pytest.raises(ValueError, match="found no cells in the image"):
        fit_scene(noise, Microscope(pixel_size_um=0.065, modality=modality), RenderSettings(),
                  geometry="field")  # fmt: skip


def test_a_blank_frame_is_judged_on_its_valid_pixels(truth):
    """A saturated blob excluded from the fit does not make a blank frame look full, a
    constant frame is blank, and a frame with cells passes."""
    from napari_symbac.fit.start import refuse_blank

    noise = np.random.default_rng(4).normal(1000, 30, (128, 128))
    valid = np.ones(noise.shape, bool)
    noise[40:60, 40:60], valid[40:60, 40:60] = 65535, False
    with pytest.raises(ValueError, match="blank or dark frame"):
        refuse_blank(noise, valid)
    with pytest.raises(ValueError, match=r"\(0 s\.d\."):
        refuse_blank(np.full((64, 64), 100.0))
    refuse_blank(truth.image)
    refuse_blank(noise)  # the blob counts when it is valid


def test_a_rod_turned_by_pi_and_bent_the_other_way_is_drawn_the_same():
    """Layout.wrap_angles brings every angle into [-pi/2, pi/2) and flips the curvature
    with each half turn; the scene drawn from the wrapped parameters is the same."""
    from napari_symbac.fit.placement import draw_fitted
    from napari_symbac.settings import Microscope
    from napari_symbac.sim import FrameCells

    layout = Layout(n=3, fit_curvature=True, per_cell_width=False, trench=False,
                    fit_top=False, optics=())  # fmt: skip
    x = np.zeros(layout.size)
    blocks = x[: 3 * layout.per_cell].reshape(3, layout.per_cell)
    blocks[:] = [[2.0, 2.0, 1.7, 2.5, 0.3], [4.5, 3.0, -2.9, 3.0, -0.2], [3.0, 5.0, 0.4, 2.0, 0.1]]
    wrapped = layout.wrap_angles(x.copy())
    angles = wrapped[2 : 3 * layout.per_cell : layout.per_cell]
    assert np.all((angles >= -np.pi / 2) & (angles < np.pi / 2))
    np.testing.assert_allclose(angles, [1.7 - np.pi, -2.9 + np.pi, 0.4])
    bends = wrapped[4 : 3 * layout.per_cell : layout.per_cell]
    np.testing.assert_allclose(bends, [-0.3, 0.2, 0.1])
    microscope = Microscope(pixel_size_um=0.065)

    def drawn(v):
        b = v[: 3 * layout.per_cell].reshape(3, layout.per_cell)
        cells = FrameCells(np.arange(1, 4), b[:, 0], b[:, 1], b[:, 2], b[:, 3], np.full(3, 1.0))
        curvature = {i + 1: (float(b[i, 4]), 1.0, 0.0) for i in range(3)}
        scene = draw_fitted(cells, None, (110, 110), microscope, RenderSettings(), 1.2, curvature)
        return np.asarray(scene.cells)

    np.testing.assert_array_equal(drawn(wrapped), drawn(x))


def test_horizontal_cells_are_fitted_across_the_angle_wrap():
    """Found as a user: ordinary horizontal rods were reported "at a bound" at 1.6 rad (the
    angle's bound then); a cell just past horizontal could not reach its angle. Cells at
    +-(pi/2 - 0.05) and pi/2 + 0.05 are fitted to their angles (modulo pi), none at a
    bound."""
    from _fit_synthetic import FLUO_TRUTH, make_cells

    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import Microscope, TrenchGeometry

    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    truth = make_cells(y_um=[1.6, 4.0, 6.4], x_um=[3.8, 3.8, 3.8],
                       angle_rad=[np.pi / 2 - 0.05, -np.pi / 2 + 0.05, np.pi / 2 + 0.05],
                       length_um=[3.0, 2.6, 2.8], width_um=0.9)  # fmt: skip
    scene = draw_scene(truth, TrenchGeometry(), microscope, FLUO_TRUTH, field=Field(7.68, 7.68))
    image = ForwardModel(microscope, FLUO_TRUTH, Camera()).render(
        scene, np.random.default_rng(3)
    )
    fit = fit_scene(image, microscope, RenderSettings(defocus_sigma_um=0.0), None,
                    geometry="open")  # fmt: skip
    assert len(fit.cells) == 3
    assert not [name for name in fit.at_bounds if name.endswith("angle_rad")], fit.at_bounds
    got = np.asarray(fit.cells.angle_rad)[np.argsort(fit.cells.y_um)]
    assert np.all((got >= -np.pi / 2) & (got < np.pi / 2))
    turn = (got - np.asarray(truth.angle_rad) + np.pi / 2) % np.pi - np.pi / 2
    np.testing.assert_allclose(turn, 0.0, atol=0.03)


def test_painted_classes_on_a_faint_frame_are_not_refused_as_blank(truth):
    """The blank-frame check is the automatic start's: painted classes say where faint
    cells are (the advice of the faint-start refusal), so a frame of them is fitted."""
    from napari_symbac.fit import scene_classes
    from napari_symbac.fit.start import refuse_blank

    faint = truth.image.astype(float)
    faint = 1000.0 + (faint - np.median(faint)) * 0.01
    faint += np.random.default_rng(1).normal(0, 30, faint.shape)
    with pytest.raises(ValueError, match="blank or dark frame"):
        refuse_blank(faint)
    start = start_scene(faint, truth.microscope, labels=scene_classes(truth.scene))
    assert len(start[0]) >= 1


def test_a_rod_is_cut_only_where_both_pieces_show_in_view():
    """The split move's cuts (at a septum or the middle) leave 0.6 widths of rod on each
    side of a rod wholly in view; of a rod that the image's edge cuts, the piece in view
    must be a rod (1.25 widths) and the piece past the edge must show a quarter width."""
    from napari_symbac.fit.moves import _cuttable_span

    view = (3.0, 15.0)  # um: the image's width and height
    inside = np.array([1.5, 7.0, 0.0, 4.0])  # x, y, angle (0: along y), length
    assert _cuttable_span(inside, 1.0, view) == pytest.approx((-1.4, 1.4))
    # 0.3 um of this rod's lower half lies inside the bottom edge
    at_edge = np.array([1.5, 14.7, 0.0, 3.0])
    assert _cuttable_span(at_edge, 1.0, view) == pytest.approx((-0.25, 0.05))
    sliver = np.array([1.5, 15.9, 0.0, 3.0])  # 0.6 um of it in view: no cut
    low, high = _cuttable_span(sliver, 1.0, view)
    assert low > high
    # turned by 90 degrees (angle pi/2: along x), past the right edge by its half
    across = np.array([3.0, 7.0, np.pi / 2, 2.0])
    assert _cuttable_span(across, 0.5, view) == pytest.approx((-0.375, -0.125))
    through = np.array([1.5, 7.5, 0.0, 20.0])  # past both edges
    assert _cuttable_span(through, 1.0, view) == pytest.approx((-7.25, 7.25))
