"""Move the tuning sliders as a user would and watch the preview layer follow."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets.simulate import (
    RESULT_IMAGE_LAYER,
    RESULT_LABELS_LAYER,
    SYMBAC_METADATA_KEY,
    SimulateWidget,
)
from napari_symbac._widgets.tune import TuneWidget
from napari_symbac.fit.report import cells_counted


@pytest.fixture
def rendered(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    simulate = SimulateWidget(viewer)
    tune = TuneWidget(viewer)
    viewer.window.add_dock_widget(simulate)
    viewer.window.add_dock_widget(tune)
    simulate.form.n_frames.value = 3
    simulate.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: simulate.worker is None, timeout=10_000)
    return viewer, tune


def test_slider_moves_change_the_preview(rendered):
    viewer, tune = rendered
    assert tune.source.value is viewer.layers[RESULT_IMAGE_LAYER]
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    labels = viewer.layers[RESULT_LABELS_LAYER].data
    frame = tune._current_frame()
    cells = labels[frame] > 0
    before = layer.data[frame][cells].mean()
    tune.sliders["cell_intensity"].value = tune.sliders["cell_intensity"].value + 3000
    after = layer.data[frame][cells].mean()
    assert after > before + 1500
    settings = layer.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert settings.render.cell_intensity == pytest.approx(tune.sliders["cell_intensity"].value)


def test_other_frames_update_when_shown(rendered):
    viewer, tune = rendered
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    viewer.dims.set_current_step(0, 0)
    old_last = layer.data[2].copy()
    tune.sliders["media_intensity"].value = tune.sliders["media_intensity"].value + 4000
    np.testing.assert_array_equal(layer.data[2], old_last)  # not re-rendered yet
    viewer.dims.set_current_step(0, 2)
    assert layer.data[2].mean() > old_last.mean() + 1000


def test_invalid_value_is_reported(rendered):
    _viewer, tune = rendered
    tune.sliders["apodisation_sigma_um"].min = 0.05
    tune.sliders["apodisation_sigma_um"].value = 0.06
    assert "Not applied" in tune.status.value


def _export_simulates_the_fit(tune, stored, result, real) -> None:
    """``stored`` (the rendered layer's settings after Auto-fit) simulates cells of the
    fitted width in frames of the recording's size in um (in its pixels when simulated
    at its pixel size), and the preview still draws the simulation that was run."""
    import dataclasses

    from napari_symbac.pipeline import render_simulation
    from napari_symbac.sim import simulate

    width = float(np.median(result.cells.width_um))
    assert stored.simulation.cell_width_um == pytest.approx(width)
    assert "Export simulates cells" in tune.status.value
    two_frames = dataclasses.replace(stored.simulation, n_frames=2)
    short = dataclasses.replace(stored, simulation=two_frames)
    series = render_simulation(simulate(short.simulation, np.random.default_rng(0)), short)
    drawn_um = stored.microscope.pixel_size_um
    recorded_um = real.metadata["pixel_size_um"]
    size_um = np.array(series.images.shape[-2:]) * drawn_um
    assert size_um == pytest.approx(np.array(real.data.shape[-2:]) * recorded_um, abs=drawn_um)
    if drawn_um != recorded_um:
        assert "Simulate again with the recording chosen there" in tune.status.value
    assert tune.preview.frame(0).shape == tune.source.value.data.shape[-2:]


def _real_trench(viewer, real_data_dir, *, paint: dict | None = None):
    """The SyMBac trench as a recording at 0.065 um/px, with optional painted strokes."""
    import tifffile

    from napari_symbac._widgets.real_image import class_layer_name

    real = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    layer = viewer.add_image(
        real,
        name="real",
        scale=(0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )
    if paint is not None:
        classes = np.zeros(real.shape, np.uint8)
        for value, (rows, cols) in paint.items():
            classes[rows, cols] = value
        viewer.add_labels(classes, name=class_layer_name("real"), scale=(0.065, 0.065))
    return layer


def _as_agar_pad(tune) -> None:
    """The rendered layer's simulation made an agar pad: Auto-fit fits an open field."""
    import dataclasses

    metadata = tune.source.value.metadata[SYMBAC_METADATA_KEY]
    settings = metadata["settings"]
    simulation = dataclasses.replace(settings.simulation, geometry="agar_pad")
    metadata["settings"] = dataclasses.replace(settings, simulation=simulation)


def _auto_fit(tune, qtbot, real, *, iterations: int):
    """Auto-fit of ``real`` with ``iterations``, clicked as a user does; its result."""
    tune.reference.value = real
    tune.fit_iterations.value = iterations
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    assert tune.fit_result is not None, tune.status.value
    return tune.fit_result


def test_auto_fit_runs_the_scene_fit_on_the_recording(rendered, qtbot, real_data_dir):
    from napari_symbac._widgets.export import ExportWidget
    from napari_symbac._widgets.tune import FIT_RESIDUAL_LAYER, FIT_SYNTHETIC_LAYER
    from napari_symbac.fit.report import OPEN_PHASE_NOTE

    viewer, tune = rendered
    export = ExportWidget(viewer)
    assert export.source.current_choice == RESULT_IMAGE_LAYER
    real = _real_trench(viewer, real_data_dir)
    result = _auto_fit(tune, qtbot, real, iterations=2)
    assert result.objective_after < result.objective_before
    assert len(result.cells) >= 3  # the trench holds several cells
    # the fit's intensities went to the sliders and into the rendered layer's settings
    assert tune.sliders["media_intensity"].value == pytest.approx(result.render.media_intensity)
    stored = tune.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert stored.render.cell_intensity == pytest.approx(result.render.cell_intensity)
    # no camera is given in the GUI: the fit measured it from the recording, and the
    # preview and Export use it (the default camera is 2.9 ADU/e-, 8 e-)
    assert result.camera is not None
    assert stored.camera == result.camera
    assert tune.preview.model.camera == result.camera
    assert "Camera measured from the recording" in tune.status.value
    # and checked model-free against the image's own photon transfer, as `fit` does
    assert "Camera, model-free: sensitivity " in tune.status.value
    assert "Problem: the fit's camera gain" not in tune.status.value
    # all shot noise at this recording's baseline: the 0 e- read noise is said to be unmeasured
    assert result.camera.dark_noise_e == 0
    assert "Note: the read noise is too small to measure from this image" in tune.status.value
    synthetic = viewer.layers[FIT_SYNTHETIC_LAYER]
    assert synthetic.data.shape == real.data.shape
    assert tuple(synthetic.scale) == tuple(real.scale)
    assert tuple(synthetic.units) == tuple(real.units)
    residual = viewer.layers[FIT_RESIDUAL_LAYER]
    # white at 0 (found as a user: napari's min-max limits put it elsewhere), a colour bar
    low, high = residual.contrast_limits
    assert low == -high > -np.abs(residual.data).max()
    assert residual.colorbar.visible
    assert tune.terms_table.shape[0] == len(result.terms)
    assert "Fitted in" in tune.status.value
    # the convergence plot's caption says the status line's objective and the curve's ends
    objective = f"{result.objective_before:.4g} -> {result.objective_after:.4g}"
    assert f"objective {objective}" in tune.status.value
    caption = tune.convergence_caption.value
    assert not tune.convergence_caption.native.isHidden()
    assert f"start {result.objective_before:.4g} (grey square)" in caption
    assert f"end {result.objective_after:.4g} (orange square)" in caption
    assert f"{result.history[-1]:.4g} at the last" in caption
    # what the CLI's report says is said here too: 2 iterations stop at the limit
    assert f"{cells_counted(len(result.cells))} fitted" in tune.status.value
    assert "Problem: round 1: the fit stopped at the iteration limit" in tune.status.value
    assert OPEN_PHASE_NOTE not in tune.status.value  # a trench: the linear kernel is right
    assert tune.fit_button.enabled
    # the fitted cells and trench are the simulation Export runs, as in `fit`'s
    # settings.yaml (found as a user: Export drew the Simulate tab's cells and trench)
    _export_simulates_the_fit(tune, stored, result, real)
    # and Export says that its settings are the fitted ones (found as a user: it still
    # read "synthetic" after Auto-fit)
    assert export.source.value is tune.source.value
    assert export.source.current_choice == f"{RESULT_IMAGE_LAYER} (fitted to real)"
    # the fit's layers keep the frame slider named "frame" (it read "-3": napari's
    # default axis name) and at the frame shown
    assert viewer.dims.axis_labels[0] == "frame"
    assert viewer.dims.current_step[0] == tune._current_frame() >= 0


def test_auto_fit_of_a_phase_colony_says_what_the_linear_kernel_cannot_do(
    rendered, qtbot, real_data_dir
):
    """A phase recording of a colony on a pad (a crop of the Omnipose Sample000033,
    pixel size entered by the user) fitted after an agar-pad simulation, drawn as
    Simulate draws a phase pad (the partially coherent model): the scene fit's linear
    kernel is fitted (found as a user: Auto-fit was refused, naming parameters no
    control sets), and the status and a notification carry the CLI report's note on the
    colony's halo."""
    import dataclasses

    from napari.utils.notifications import notification_manager

    from napari_symbac.fit.colony import colony_phase_render
    from napari_symbac.fit.report import OPEN_PHASE_NOTE
    from napari_symbac.io import read_image

    viewer, tune = rendered
    _as_agar_pad(tune)
    metadata = tune.source.value.metadata[SYMBAC_METADATA_KEY]
    settings = metadata["settings"]
    drawn = colony_phase_render(settings.render, settings.microscope)
    assert drawn.phase_model == "partially_coherent"
    metadata["settings"] = dataclasses.replace(settings, render=drawn)
    tune._load_source()
    assert tune.preview.render_settings.phase_model == "partially_coherent"
    # the colony's edge: a crop inside it, whose touching cells the automatic start takes
    # as a few rods of which the fit keeps one, is refused (test_fit's colony window)
    colony = read_image(real_data_dir / "omnipose" / "Sample000033.png").data[192:256, 160:224]
    real = viewer.add_image(
        colony.astype(np.float32),
        name="colony",
        scale=(0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )
    tune.reference.value = real
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    assert tune.fit_result is not None, tune.status.value
    assert tune.fit_result.trench is None  # fitted as an open field
    assert tune.fit_result.render.phase_model == "linear"
    assert f"Note: {OPEN_PHASE_NOTE}" in tune.status.value
    assert any(OPEN_PHASE_NOTE in str(n.message) for n in seen)


def _auto_fit_refused(rendered, qtbot, image, pixel_size_um: float, modality: str) -> str:
    """Auto-fit of ``image`` (no masks, no strokes) on an agar pad: refused at once, the
    button enabled again; returns the status."""
    viewer, tune = rendered
    _as_agar_pad(tune)
    real = viewer.add_image(
        np.asarray(image, np.float32), name="recording", scale=(pixel_size_um,) * 2,
        metadata={"pixel_size_um": pixel_size_um, "modality": modality},
    )  # fmt: skip
    tune.reference.value = real
    assert tune.masks.value is None
    from napari.utils.notifications import notification_manager

    seen = []
    notification_manager.notification_ready.connect(seen.append)
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=120_000)
    assert tune.fit_result is None
    assert tune.fit_button.enabled
    # a refusal with what to give, as a warning: not "Auto-fit failed", an error
    assert tune.status.value.startswith("Not fitted: ")
    assert not any("Auto-fit failed" in str(n.message) for n in seen)
    assert any(str(n.message) == tune.status.value for n in seen)
    return tune.status.value


def test_auto_fit_refuses_a_modality_the_image_contradicts(rendered, qtbot, real_data_dir):
    """ColiCoords' fluorescence field marked phase: refused before any fit, as `napari-
    symbac fit` refuses it, with the modality to set and where (found as a user: a trench
    set to fluorescence ran, then ended in an "Auto-fit failed" error)."""
    import tifffile

    viewer, tune = rendered
    path = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    real = viewer.add_image(
        tifffile.imread(path)[:256, :256], name="recording", scale=(0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": "phase"},
    )  # fmt: skip
    tune.reference.value = real
    tune.fit_button.native.click()
    assert tune.fit_worker is None
    assert "the image does not look like phase" in tune.status.value
    assert "Set its modality to fluorescence in the 1 Recording tab" in tune.status.value


def test_auto_fit_of_a_whole_colony_without_masks_asks_for_them(rendered, qtbot, real_data_dir):
    """The whole Sample000033 colony (116 touching cells) with no masks: the automatic
    start takes the colony as a few wide regions, and Auto-fit stops there at once with
    where to choose the masks (it ran a long fit that ended with a dozen cells)."""
    from napari_symbac.io import read_image

    colony = read_image(real_data_dir / "omnipose" / "Sample000033.png").data
    status = _auto_fit_refused(rendered, qtbot, colony, 0.118, "phase")
    assert "wider than any rod-shaped bacterium" in status
    assert status.endswith("choose it as 'cell masks'")


def test_auto_fit_of_a_crop_around_one_cell_names_both_starts(rendered, qtbot, real_data_dir):
    """ColiCoords' single-cell crop ``01`` (fluorescence) with no masks and no strokes:
    the automatic start finds no cell standing out of the cell's own glow, and Auto-fit
    says at once where to give the masks or the strokes that start it."""
    import tifffile

    crop = tifffile.imread(real_data_dir / "colicoords" / "01" / "fluorescence.tif")
    status = _auto_fit_refused(rendered, qtbot, crop, 0.08, "fluorescence")
    assert status.startswith("Not fitted: the start found no cells in the image: ")
    assert "the brightest stands 21 times" in status
    assert status.endswith("or paint rough cell and media strokes in the Recording step)")


def test_auto_fit_of_a_phase_colony_with_its_masks_fits_the_halo(rendered, qtbot, real_data_dir):
    """The same kind of recording with its instance masks opened as a Labels layer and
    chosen as the cell masks: Auto-fit fits the partially coherent model to the masks'
    scene (as `napari-symbac fit --masks`), and the preview and Export take it."""

    import imageio.v3 as iio
    import tifffile

    from napari_symbac._widgets.tune import FIT_SYNTHETIC_LAYER
    from napari_symbac.calibrate.compaction import PAD_PHYS_ITERS
    from napari_symbac.fit import ColonyFit
    from napari_symbac.fit.report import COLONY_NOTE

    viewer, tune = rendered
    _as_agar_pad(tune)
    root = real_data_dir / "omnipose"
    crop = (slice(80, 176), slice(336, 432))  # half cells, half pad beside the colony
    grey = iio.imread(root / "Sample000193.png")[..., 0][crop]
    masks = tifffile.imread(root / "Sample000193_cp_masks.tif")[crop]
    real = viewer.add_image(
        grey, name="colony", scale=(0.0745, 0.0745),
        metadata={"pixel_size_um": 0.0745, "modality": "phase"},
    )  # fmt: skip
    labels = viewer.add_labels(masks.astype(np.int32), name="colony masks", scale=(0.0745,) * 2)
    tune.reference.value = real
    tune.masks.reset_choices()
    assert labels in tune.masks.choices
    tune.masks.value = labels
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    result = tune.fit_result
    assert isinstance(result, ColonyFit), tune.status.value
    assert result.objective_after < result.objective_before
    assert "partially coherent" in tune.status.value
    assert f"Note: {COLONY_NOTE}" in tune.status.value
    assert tune.noise_model.value == "gaussian"
    settings = tune.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
    stored, simulation = settings.render, settings.simulation
    assert stored.phase_model == "partially_coherent"  # Export renders the fitted model
    # Export draws a pad (chord over its depth), the fit the masks' scene (chord over the
    # cell's width): the same optical path per cell (as `fit --masks`'s settings.yaml)
    drawn_phase = result.render.cell_phase_rad * simulation.trench.depth_um
    assert stored.cell_phase_rad == pytest.approx(drawn_phase / simulation.cell_width_um)
    assert simulation.cell_width_um == pytest.approx(np.median(result.cells.width_um))
    # and its colonies packed as the recording's (gravity chosen by simulated colonies)
    assert simulation.phys_iters == PAD_PHYS_ITERS
    assert f"(gravity {simulation.gravity:g} um/min)" in tune.status.value
    # each cell's own optical path: Export draws the cells as varied as the fit found them
    assert result.cell_gains
    assert stored.cell_brightness_cv == pytest.approx(result.render.cell_brightness_cv)
    assert stored.cell_brightness_cv > 0
    assert "Each cell's own optical path fitted after the optics" in tune.status.value
    assert viewer.layers[FIT_SYNTHETIC_LAYER].data.shape == grey.shape
    assert tune.fit_button.enabled
    # the sliders are the partially coherent model's: phase, ring width, plate, and the
    # linear kernel's ring contrast and PSF offset are hidden; the phase slider acts
    phase = tune.sliders["cell_phase_rad"]
    assert phase.value == pytest.approx(stored.cell_phase_rad, abs=0.01)
    assert not phase.native.isHidden()
    assert tune.sliders["ring_contrast"].native.isHidden()
    assert tune.sliders["psf_offset"].native.isHidden()
    # the cell intensity says what it is in this model (a transmission: equal to the
    # media's for transparent cells; found as a user, read as a mistake)
    assert "bright-field transmission" in tune.sliders["cell_intensity"].tooltip
    assert tune.sliders["apodisation_sigma_um"].value == pytest.approx(
        result.render.apodisation_sigma_um, abs=0.01
    )  # beyond the slider's first range (3 um): widened, not refused
    # the 8-bit colony's intensities (tens of ADU) sit inside their sliders' ranges, not
    # at the left end of 0-20000 ADU where the slider could not move them
    cell = tune.sliders["cell_intensity"]
    assert 0 < result.render.cell_intensity < 256
    assert cell.value == pytest.approx(result.render.cell_intensity, rel=0.01)
    assert cell.max == pytest.approx(4 * cell.value, rel=0.01)
    layer = tune.source.value
    frame = tune._current_frame()
    before = layer.data[frame].astype(float).copy()
    phase.value = phase.value + 0.5
    assert np.abs(layer.data[frame].astype(float) - before).max() > 1


def test_auto_fit_of_all_frames_fits_a_trench_time_lapse_jointly(
    rendered, qtbot, real_data_dir, tracks_in_mask_colours
):
    """The real trench as a 2-frame time-lapse (the second frame 2 px further down the
    trench): 'all frames jointly' runs the series fit (optics and camera shared), the
    layers hold both frames and the sliders the shown frame's intensities."""
    from napari_symbac._widgets.tune import (
        FIT_SYNTHETIC_LAYER,
        FIT_TRACK_MASKS_LAYER,
        FIT_TRACKS_LAYER,
    )
    from napari_symbac.fit import SeriesFit

    viewer, tune = rendered
    trench = _real_trench(viewer, real_data_dir).data
    stack = np.stack([trench[2:], trench[:-2]])
    real = viewer.add_image(
        stack, name="trench time-lapse", scale=(1.0, 0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )  # fmt: skip
    tune.reference.value = real
    tune.fit_iterations.value = 2
    # one frame of it first: the status names which (found as a user: a fit of frame 15
    # of 30 never said so, and its 2D layers lie over every frame)
    viewer.dims.set_current_step(0, 1)
    tune.fit_all_frames.value = False
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=600_000)
    assert tune.status.value.startswith("Fitted frame 1 (of 2) in "), tune.status.value
    tune.fit_all_frames.value = True
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=600_000)
    series = tune.fit_result
    assert isinstance(series, SeriesFit), tune.status.value
    assert "Fitted 2 frames jointly" in tune.status.value
    # 'fit iterations' bounds the joint refinement too (found as a user: "stopped at the
    # iteration limit (15)" whatever the field said)
    assert series.iterations <= 2
    assert "iteration limit (15)" not in tune.status.value
    assert viewer.layers[FIT_SYNTHETIC_LAYER].data.shape == stack.shape
    shown = series.frames[tune._current_frame()]
    assert tune.sliders["media_intensity"].value == pytest.approx(shown.render.media_intensity)
    assert tune.preview.model.camera == series.camera  # measured once from both frames
    assert tune.fit_button.enabled
    # the tracks to see the links by: a Tracks layer and the cells labelled by track
    # id, placed over the recording (found as a user: only counts were given)
    masks = viewer.layers[FIT_TRACK_MASKS_LAYER]
    tracks = viewer.layers[FIT_TRACKS_LAYER]
    assert f"layers '{FIT_TRACKS_LAYER}' and '{FIT_TRACK_MASKS_LAYER}'" in tune.status.value
    assert masks.data.shape == stack.shape
    assert tuple(tracks.scale) == tuple(masks.scale) == (1.0, 0.065, 0.065)
    assert set(np.unique(tracks.data[:, 0])) == set(np.unique(masks.data)) - {0}
    assert set(np.unique(masks.data)) - {0} <= set(series.lineage.tracks[:, 0].tolist())
    assert len(np.unique(masks.data[0])) - 1 >= 3  # the real trench's cells, each tracked
    tracks_in_mask_colours(tracks, masks)
    # a fit of one frame afterwards: the joint fit's tracks are gone, not left stale
    tune.fit_all_frames.value = False
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=600_000)
    assert FIT_TRACKS_LAYER not in viewer.layers
    assert FIT_TRACK_MASKS_LAYER not in viewer.layers


def test_auto_fit_of_all_frames_fits_a_colony_time_lapse_jointly(rendered, qtbot, real_data_dir):
    """A time-lapse opened as one (T, Y, X) layer with its masks (two windows of the real
    colony 3 px apart: a drifting stage) and 'all frames jointly' ticked: one fit of every
    frame (as `napari-symbac fit --frames`), the optics shared, the cells tracked, the
    synthetic and residual layers holding every frame. A single frame with the box
    ticked is refused with the fix."""

    import imageio.v3 as iio
    import tifffile

    from napari_symbac._widgets.tune import (
        FIT_RESIDUAL_LAYER,
        FIT_SYNTHETIC_LAYER,
        FIT_TRACK_MASKS_LAYER,
        FIT_TRACKS_LAYER,
    )
    from napari_symbac.fit import ColonySeriesFit

    viewer, tune = rendered
    _as_agar_pad(tune)
    root = real_data_dir / "omnipose"
    grey = iio.imread(root / "Sample000193.png")[..., 0]
    full = tifffile.imread(root / "Sample000193_cp_masks.tif")
    windows = [(slice(80, 176), slice(336, 432)), (slice(77, 173), slice(338, 434))]
    scale = (1.0, 0.0745, 0.0745)
    real = viewer.add_image(
        np.stack([grey[w] for w in windows]), name="time-lapse", scale=scale,
        metadata={"pixel_size_um": 0.0745, "modality": "phase"},
    )  # fmt: skip
    masks = np.stack([full[w] for w in windows]).astype(np.int32)
    labels = viewer.add_labels(masks, name="time-lapse masks", scale=scale)
    tune.reference.value = real
    tune.masks.reset_choices()
    tune.masks.value = labels
    tune.fit_all_frames.value = True
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    series = tune.fit_result
    assert isinstance(series, ColonySeriesFit), tune.status.value
    assert len(series.frames) == 2
    assert "Fitted 2 frames jointly" in tune.status.value
    assert series.joint_objective[1] <= series.joint_objective[0]
    for name in (FIT_SYNTHETIC_LAYER, FIT_RESIDUAL_LAYER):
        assert viewer.layers[name].data.shape == real.data.shape
        assert tuple(viewer.layers[name].scale) == scale
    shown = series.frames[tune._current_frame()]
    settings = tune.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
    # the shared phase, per unit of the pad's drawn material (as a single frame's)
    drawn_phase = series.shared()["cell_phase_rad"][0] * settings.simulation.trench.depth_um
    assert shown.render.cell_phase_rad == pytest.approx(series.shared()["cell_phase_rad"][0])
    stored = settings.render
    assert stored.cell_phase_rad == pytest.approx(drawn_phase / settings.simulation.cell_width_um)
    assert tune.sliders["cell_phase_rad"].value == pytest.approx(stored.cell_phase_rad, abs=0.01)
    # the masks' cells whole in both windows keep their tracks
    ids = [
        dict(zip(f.cells.ids.tolist(), t.tolist()))
        for f, t in zip(series.frames, series.lineage.track_ids)
    ]
    common = set(ids[0]) & set(ids[1])
    assert len(common) >= 5
    assert sum(ids[0][k] == ids[1][k] for k in common) >= 5
    # ... and are seen as such: a Tracks layer whose tracks span both frames
    tracks = viewer.layers[FIT_TRACKS_LAYER]
    assert tuple(tracks.scale) == scale
    both = [k for k in np.unique(tracks.data[:, 0]) if (tracks.data[:, 0] == k).sum() == 2]
    assert len(both) >= 5
    assert viewer.layers[FIT_TRACK_MASKS_LAYER].data.shape == real.data.shape
    # masks of one frame, or of another number of frames: refused, with the fix
    for data, message in (
        (masks[0], "holds one frame but the real time-lapse has 2: give every frame its own"),
        (np.concatenate([masks, masks[:1]]), "has 3 frames but the real time-lapse has 2"),
    ):
        layer = viewer.add_labels(data, name=f"masks of {data.shape}", scale=scale[-data.ndim :])
        tune.masks.reset_choices()
        tune.masks.value = layer
        tune.fit_button.native.click()
        assert tune.fit_worker is None
        assert message in tune.status.value
        assert tune.fit_result is series
    # one frame with the box ticked: refused, with the fix, nothing run
    single = viewer.add_image(
        grey[windows[0]], name="one frame", scale=scale[1:],
        metadata={"pixel_size_um": 0.0745, "modality": "phase"},
    )  # fmt: skip
    tune.reference.value = single
    tune.masks.value = None
    tune.fit_button.native.click()
    assert tune.fit_worker is None
    assert "is a single frame: untick it" in tune.status.value
    assert tune.fit_result is series


def test_auto_fit_with_nan_terms_reports_them(rendered, qtbot, real_data_dir, monkeypatch):
    """Defect 1: a NaN term (rough strokes) ended the fit in a ValueError, status stuck."""
    import napari_symbac.fit as fit

    viewer, tune = rendered
    real = _real_trench(viewer, real_data_dir)
    original = fit.fit_scene

    def with_nan_term(*args, **kwargs):
        result = original(*args, **kwargs)
        result.terms["edge_profile"] = (float("nan"), float("nan"))
        return result

    monkeypatch.setattr(fit, "fit_scene", with_nan_term)
    tune.reference.value = real
    tune.fit_iterations.value = 1
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    assert tune.fit_result is not None, tune.status.value
    assert "NaN" in tune.status.value
    assert "edge_profile" in tune.status.value
    table = tune.terms_table.to_dict("list")
    assert np.isnan(float(table["after"][table["term"].index("edge_profile")]))
    plot = np.asarray(tune.terms_image.value)
    assert (plot == (220, 40, 40)).all(axis=-1).any()  # the NaN term's red stripe
    assert len(tune.fit_result.history) >= 1
    assert (plot == (240, 240, 240)).all(axis=-1).any()  # the convergence curve
    assert tune.fit_button.enabled


def test_the_convergence_plot_says_its_numbers_and_a_rise_is_not_a_worse_fit():
    """Found as a user: after Auto-fit of ColiCoords ds1 00002 (objective 4.415 ->
    2.497) a bare line, no axes or numbers, that rose: read as a fit that got worse.
    The plot marks the status line's objective at the start and the end; the caption
    says the axes, the line's first and last values and why it may rise."""
    from napari_symbac._widgets.tune import (
        AFTER_COLOUR,
        BEFORE_COLOUR,
        CURVE_COLOUR,
        convergence_caption,
        convergence_plot,
    )

    history = [3.0, 2.0, 6.0, 2.6]  # a rise where the round's weights were re-estimated
    plot = convergence_plot(history, 4.415, 2.497)
    assert (plot == CURVE_COLOUR).all(axis=-1).any()

    def rows(colour, columns):
        return np.flatnonzero((plot[:, columns] == colour).all(axis=-1).any(axis=1))

    start, end = rows(BEFORE_COLOUR, slice(0, 5)), rows(AFTER_COLOUR, slice(-5, None))
    assert start.size
    assert end.size
    assert end.mean() > start.mean()  # the end's objective lower than the start's
    caption = convergence_caption(history, 4.415, 2.497)
    assert "start 4.415 (grey square) -> end 2.497 (orange square)" in caption
    assert "each of the fit's 4 accepted steps (x, in order), 3 at the first, 2.6 at the last" in (
        caption
    )
    assert "y: log scale, 2 to 6" in caption
    assert "where the line rises, the weights or the cells changed, not the fit got worse" in (
        caption
    )
    assert "No fit step was recorded" in convergence_caption([], 4.415, 2.497)
    # the line at 1 is said where it is drawn, within the range, and only there
    assert "grey line at 1" not in caption
    assert "y: log scale, 0.8 to 6, a grey line at 1" in convergence_caption(
        [3.0, 0.8], 6.0, 0.9
    )


def test_auto_fit_error_is_a_notification_not_a_traceback(rendered, qtbot, real_data_dir):
    """Defect 9: expected errors (no media strokes) go to the status line and a
    notification, and are not re-raised (pytest-qt fails a test on any exception
    raised in the Qt event loop)."""
    from napari.utils.notifications import notification_manager

    viewer, tune = rendered
    # strokes of an unknown class value: the fit's input check rejects them
    real = _real_trench(viewer, real_data_dir, paint={7: (slice(60, 200), slice(20, 24))})
    tune.reference.value = real
    tune.fit_iterations.value = 1
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    assert tune.status.value.startswith("Fit failed")
    assert tune.fit_result is None
    assert any("Auto-fit failed" in str(n.message) for n in seen)
    assert tune.fit_button.enabled
    assert not tune.cancel_fit_button.enabled


def test_auto_fit_refuses_a_normalised_recording(rendered, real_data_dir):
    """The DeLTA trench is normalised (values down to -0.03): refused before any fit, with
    the words of `napari-symbac fit`, on the status line."""
    import tifffile

    viewer, tune = rendered
    data = tifffile.imread(real_data_dir / "ecoli_delta_phase_normalised.tiff")
    real = viewer.add_image(
        data, name="delta", scale=(0.065, 0.065), metadata={"pixel_size_um": 0.065}
    )
    tune.reference.value = real
    tune.fit_button.native.click()
    assert tune.fit_worker is None
    assert "delta has negative values" in tune.status.value
    # and says how the dock reads such a file
    assert "opened by napari-symbac (the commands, or the Real image dock's 'or open') is " \
        "read as counts" in tune.status.value
    assert tune.fit_result is None


def test_auto_fit_fits_a_fluorescence_recording(rendered, qtbot, monkeypatch):
    """A fluorescence recording (the shipped ColiCoords field, bright cells on a dark
    background) is fitted with bright cells, not refused or fitted as phase."""
    import threading
    from pathlib import Path

    import tifffile

    import napari_symbac
    import napari_symbac.fit.clipped_background as clipping
    from napari_symbac._widgets.tune import FIT_SYNTHETIC_LAYER

    viewer, tune = rendered
    # the censored background fit runs in the fit's worker, not on the GUI thread (found
    # by review: it ran in the callback that shows the result); the real one, watched
    threads = []
    censored_fit = clipping.clipped_background

    def watched(*args, **kwargs):
        threads.append(threading.current_thread())
        return censored_fit(*args, **kwargs)

    monkeypatch.setattr(clipping, "clipped_background", watched)
    path = Path(napari_symbac.__file__).parent / "sample_data" / "colicoords_fluorescence.tif"
    field = tifffile.imread(path).astype(np.float32)[:256, :256]
    mask = tifffile.imread(path.with_name("colicoords_binary.tif"))[:256, :256]
    real = viewer.add_image(
        field,
        name="fluo",
        scale=(0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"},
    )
    tune.reference.value = real
    tune.fit_iterations.value = 3
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    result = tune.fit_result
    assert result is not None, tune.status.value
    assert result.trench is None  # no walls to see in fluorescence
    from scipy import ndimage

    # Every mask cell of this quarter but a 10-px sliver cut by the crop's edge.
    components, n = ndimage.label(mask > 0)
    areas_um2 = ndimage.sum(mask > 0, components, range(1, n + 1)) * 0.08**2
    assert len(result.cells) == int((areas_um2 >= 0.25).sum()) == 2
    assert result.render.cell_intensity > result.render.media_intensity
    synthetic = viewer.layers[FIT_SYNTHETIC_LAYER].data
    bright = field > np.percentile(field, 90)
    contrast_real = field[bright].mean() - field[~bright].mean()
    contrast_fit = synthetic[bright].mean() - synthetic[~bright].mean()
    assert 0.5 * contrast_real < contrast_fit < 1.5 * contrast_real  # bright cells, same scale
    # Export simulates a pad of the field's size with a colony per fitted cluster (two
    # lone cells here), not one colony of the defaults
    stored = tune.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert stored.simulation.geometry == "agar_pad"
    assert stored.simulation.agar_pad.n_colonies == stored.simulation.n_founders == 2
    assert stored.simulation.agar_pad.field_width_um == pytest.approx(256 * 0.08)
    _export_simulates_the_fit(tune, stored, result, real)
    # the field is background-subtracted (19 % of its pixels at 0): the fit leaves those
    # out, so its media level is the mean above 0; the preview and Export take the
    # censored fit's lower level, more read noise, and clip the recorded values at 0
    assert "The recording's background clipped at 0 ADU" in tune.status.value
    assert stored.render.media_intensity < 0.9 * result.render.media_intensity
    assert tune.sliders["media_intensity"].value == pytest.approx(stored.render.media_intensity)
    assert stored.camera.dark_noise_e > result.camera.dark_noise_e
    assert stored.extra_stages[-1].name == "saturation"
    assert stored.extra_stages[-1].parameters == {"clip_level_adu": 0.0, "high": False}
    assert [s.name for s in stored.extra_stages].count("saturation") == 1
    assert threads
    assert threading.main_thread() not in threads


def test_auto_fit_of_a_recording_longer_than_the_simulation(rendered, qtbot):
    """Found as a user: a 4-frame recording fitted at frame 2 beside a 2-frame simulation
    fitted, then lost the result to "IndexError: frame 2 is outside 0..1"; a slider moved
    there failed alike. The frame shown is fitted, the preview shows its last frame."""
    from pathlib import Path

    import tifffile

    import napari_symbac

    viewer, tune = rendered
    path = Path(napari_symbac.__file__).parent / "sample_data" / "colicoords_fluorescence.tif"
    crop = tifffile.imread(path).astype(np.float32)[:128, :128]
    movie = np.stack([np.roll(crop, 2 * t, axis=1) for t in range(5)])
    real = viewer.add_image(
        movie, name="movie", scale=(1, 0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"},
    )  # fmt: skip
    assert tune.preview.n_frames == 3
    viewer.dims.set_current_step(0, 4)
    tune.sliders["cell_intensity"].value = tune.sliders["cell_intensity"].value + 100
    assert "Not applied" not in tune.status.value
    result = _auto_fit(tune, qtbot, real, iterations=2)
    assert "Fitted frame 4 (of 5)" in tune.status.value
    assert result.synthetic.shape == crop.shape
    shifted = np.roll(crop, 8, axis=1)  # frame 4's cells, not frame 0's
    fitted = viewer.layers["auto-fit synthetic"].data
    assert np.corrcoef(fitted.ravel(), shifted.ravel())[0, 1] > np.corrcoef(
        fitted.ravel(), crop.ravel()
    )[0, 1]


@pytest.mark.parametrize("removed", ["recording", "rendered layer"])
def test_removing_a_layer_the_fit_needs_cancels_it(rendered, qtbot, real_data_dir, removed):
    """Found as a user: the recording (or the rendered layer) removed during Auto-fit,
    the fit ran a minute more and ended in "AttributeError: 'NoneType' object has no
    attribute 'data'". It stops at once and says why; nothing is added or changed."""
    from napari_symbac._widgets.tune import FIT_SYNTHETIC_LAYER

    viewer, tune = rendered
    real = _real_trench(viewer, real_data_dir)
    tune.reference.value = real
    sliders = {name: slider.value for name, slider in tune.sliders.items()}
    tune.fit_button.native.click()
    job = tune.fit_worker
    layer = real if removed == "recording" else tune.source.value
    viewer.layers.remove(layer)
    assert job.cancelled.is_set()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=120_000)
    assert tune.status.value == (
        f"Fit cancelled (its layer '{layer.name}' was removed): parameters unchanged"
    )
    assert FIT_SYNTHETIC_LAYER not in viewer.layers
    assert tune.fit_result is None
    assert {name: slider.value for name, slider in tune.sliders.items()} == sliders
    assert tune.fit_button.enabled


def test_fluorescence_gives_bright_cells_on_dark(rendered):
    """Defect 5: switching to fluorescence kept phase intensities (dark cells)."""
    viewer, tune = rendered
    tune.modality.value = "fluorescence"
    image = viewer.layers[RESULT_IMAGE_LAYER].data[tune._current_frame()].astype(float)
    labels = viewer.layers[RESULT_LABELS_LAYER].data[tune._current_frame()]
    assert tune.sliders["cell_intensity"].value > tune.sliders["media_intensity"].value
    assert image[labels > 0].mean() > 3 * image[labels == 0].mean()
    settings = viewer.layers[RESULT_IMAGE_LAYER].metadata[SYMBAC_METADATA_KEY]["settings"]
    assert settings.microscope.modality == "fluorescence"
    assert settings.render.cell_intensity > settings.render.media_intensity


@pytest.mark.parametrize("modality", ["phase", "fluorescence", "brightfield"])
def test_the_sliders_shown_are_those_that_change_the_image(rendered, modality):
    """Found as a user: in fluorescence ring contrast, PSF offset and apodisation (the
    phase kernel's) and the gaussian noise sd (with camera noise) moved and the image
    stayed the same. Each slider shown changes the frame; each one hidden leaves it as
    it was, with camera noise and with gaussian noise."""
    viewer, tune = rendered
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    tune.modality.value = modality
    for noise in ("camera", "gaussian"):
        tune.noise_model.value = noise
        frame = tune._current_frame()
        for name, slider in tune.sliders.items():
            before = layer.data[frame].copy()
            start = slider.value
            step = 0.2 * (slider.max - slider.min)
            slider.value = start + step if start + step <= slider.max else start - step
            changed = not np.array_equal(layer.data[frame], before)
            assert tune.status.value == "", (name, tune.status.value)
            assert changed != slider.native.isHidden(), (modality, noise, name, changed)
            slider.value = start
        shown = {name for name, slider in tune.sliders.items() if not slider.native.isHidden()}
        assert ("gaussian_noise_sd_adu" in shown) == (noise == "gaussian")
        assert "device_intensity" in shown  # the trench's walls glow in fluorescence too
        phase_kernel = {"ring_contrast", "psf_offset", "apodisation_sigma_um"}
        assert (phase_kernel <= shown) == (modality == "phase")
        assert not phase_kernel & shown or modality == "phase"
        # the linear kernel's cell intensity is eq. 3's, said so (not the coherent's tip)
        assert "transmission" not in tune.sliders["cell_intensity"].tooltip


def test_fit_progress_says_its_bound_is_one(make_napari_viewer):
    """Found as a user: "Fitting: 472 renders (at most 45684)" was read as hours to go."""
    tune = TuneWidget(make_napari_viewer())
    tune._on_fit_progress((472, 45684))
    assert tune.status.value == (
        "Fitting: 472 renders so far (a converging fit ends far below its bound of 45684)"
    )


def test_no_slider_before_a_render_and_no_device_on_an_agar_pad(make_napari_viewer, qtbot):
    """Found as a user: before any simulation Tune showed twelve sliders at 0.00 (the
    phase ring's among them, beside a fluorescence recording), and on an agar pad the
    device intensity slider moved nothing."""
    viewer = make_napari_viewer()
    simulate, tune = SimulateWidget(viewer), TuneWidget(viewer)
    viewer.window.add_dock_widget(simulate)
    viewer.window.add_dock_widget(tune)
    assert all(slider.native.isHidden() for slider in tune.sliders.values())
    simulate.form.geometry.value = "agar_pad"
    simulate.form.agar_pad.field_width_um.value = 12.0
    simulate.form.agar_pad.field_height_um.value = 10.0
    simulate.form.n_frames.value = 3
    simulate.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: simulate.worker is None, timeout=10_000)
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    assert tune.source.value is layer
    shown = {name for name, slider in tune.sliders.items() if not slider.native.isHidden()}
    assert {"cell_intensity", "media_intensity", "defocus_sigma_um"} <= shown
    assert "device_intensity" not in shown
    frame = tune._current_frame()
    device = tune.sliders["device_intensity"]
    step = 0.2 * (device.max - device.min)
    device.value = device.value + step  # the frame is now the preview's render
    before = layer.data[frame].copy()
    device.value = device.value + step
    np.testing.assert_array_equal(layer.data[frame], before)  # nothing to show
    media = tune.sliders["media_intensity"]
    media.value = media.value + 0.2 * (media.max - media.min)
    assert not np.array_equal(layer.data[frame], before)  # as a shown slider does


def test_matching_accepts_a_real_image_a_few_rows_off(rendered):
    """Defect 6: 258 rendered vs 256 real rows refused with 'crop the real image'."""
    viewer, tune = rendered
    rendered_shape = viewer.layers[RESULT_IMAGE_LAYER].data.shape[1:]
    rng = np.random.default_rng(0)
    real = rng.normal(2000, 100, (rendered_shape[0] - 2, rendered_shape[1])).astype(np.float32)
    viewer.add_image(real, name="real")
    tune.reference.value = viewer.layers["real"]
    tune.match_histogram.value = True
    # said (found as a user: ticking the box left the status line blank)
    assert tune.status.value == "Preview matched to the histogram of 'real'"
    shown = viewer.layers[RESULT_IMAGE_LAYER].data[tune._current_frame()].astype(float)
    assert shown.mean() == pytest.approx(real.mean(), rel=0.05)  # histogram matched
    tune.match_histogram.value = False
    assert tune.status.value == "Preview no longer matched to the real image"


def test_matching_refuses_a_different_field_with_the_fix(rendered):
    viewer, tune = rendered
    viewer.add_image(np.ones((40, 30), np.float32), name="small")
    tune.reference.value = viewer.layers["small"]
    tune.match_fourier.value = True
    assert "Not applied" in tune.status.value
    assert "simulate a field of the recording's size" in tune.status.value


def test_match_noise_measures_the_real_image(rendered):
    import numpy as np

    viewer, tune = rendered
    rng = np.random.default_rng(1)
    _, x = np.mgrid[:120, :60]
    real = (2000 + 5 * x + rng.normal(0, 35.0, x.shape)).astype(np.float32)
    viewer.add_image(real, name="noisy real")
    tune.reference.value = viewer.layers["noisy real"]
    tune.match_noise.value = True
    assert tune.noise_model.value == "gaussian"
    assert tune.sliders["gaussian_noise_sd_adu"].value == pytest.approx(35.0, rel=0.08)
    assert tune.preview.render_settings.gaussian_noise_sd_adu == pytest.approx(35.0, rel=0.08)
    assert "Noise matched" in tune.status.value


def test_a_camera_the_recording_cannot_check_is_an_auto_fit_problem(real_data_dir):
    """Found as a user: the CLI says when the image's own photon transfer cannot check the
    camera a fit measured (an 8-bit phase colony fitted without masks: 0.001 ADU/e-),
    Auto-fit said nothing; the same check runs in its worker now, with the GUI's advice."""
    import imageio.v3 as iio

    from napari_symbac._widgets._recording import GUI_CAMERA_FIX
    from napari_symbac._widgets.tune import _camera_check
    from napari_symbac.fit import ColonyFit
    from napari_symbac.settings import Camera

    grey = iio.imread(real_data_dir / "omnipose" / "Sample000033.png")[..., 0]
    fitted = Camera(sensitivity_adu_per_e=0.001, dark_noise_e=1360.0, baseline_adu=4.0)

    class Fitted:  # what the check reads of a scene fit
        camera = fitted

    text, problem = _camera_check(Fitted(), grey, GUI_CAMERA_FIX)
    assert text.startswith("not available (")
    assert problem is not None
    assert problem.startswith("the fit's camera (no gain, a constant noise of 1.36 ADU s.d.)")
    assert problem.endswith(GUI_CAMERA_FIX)
    assert "--dark" not in problem  # no CLI option is offered where none can be passed
    assert _camera_check(ColonyFit.__new__(ColonyFit), grey, GUI_CAMERA_FIX) is None


def _ds2_top_cell(viewer, tune, real_data_dir) -> np.ndarray:
    """ColiCoords ds2's top cell of field 00066 (64 x 64 px, 80 nm, fluorescence; a
    rhodamine-B conjugate, brighter at its rim) as the real image of ``tune``."""
    import tifffile

    path = real_data_dir / "colicoords" / "test_data" / "ds2" / "fluorescence" / "00066.tif"
    crop = tifffile.imread(path).astype(np.float32)[0:64, 224:288]
    real = viewer.add_image(
        crop, name="ds2", scale=(0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"},
    )  # fmt: skip
    tune.reference.value = real
    return crop


def test_auto_fit_places_a_stain_in_the_cell_envelope(rendered, qtbot, real_data_dir):
    """As `fit --envelope-stain`: ColiCoords ds2's top cell of field 00066 (a rhodamine-B
    conjugate, brighter at its rim), fitted with the envelope's fraction free from the
    check box; the fraction (started at 0.5) runs to ~1, the cell narrows to an E. coli's
    width, and the preview and Export draw the fitted stain."""
    from napari_symbac._widgets.tune import FIT_SYNTHETIC_LAYER
    from napari_symbac.fit.scene_fit import ENVELOPE_START

    viewer, tune = rendered
    crop = _ds2_top_cell(viewer, tune, real_data_dir)
    assert tune.fit_envelope_stain.native.isHidden() == (tune.modality.value != "fluorescence")
    tune.fit_envelope_stain.value = True
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    result = tune.fit_result
    assert result is not None, tune.status.value
    assert len(result.cells) == 1
    assert result.render.envelope_stain_fraction > ENVELOPE_START  # the fit moved it up
    assert result.cells.width_um[0] < 1.3  # the volume stain fits it 1.59 um wide
    stored = tune.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert stored.render.envelope_stain_fraction == result.render.envelope_stain_fraction
    assert tune.preview.render_settings.envelope_stain_fraction == (
        result.render.envelope_stain_fraction
    )
    assert viewer.layers[FIT_SYNTHETIC_LAYER].data.shape == crop.shape


def test_auto_fit_images_the_cells_in_depth(rendered, qtbot, real_data_dir):
    """As `fit --envelope-stain --depth-layers 5`: the same ds2 cell with both boxes
    ticked; the stain is imaged in 5 slabs, the focal plane is fitted, and the envelope's
    fraction settles inside its bounds (the 2-D model runs it to 1); the preview draws
    the slabs."""
    from napari_symbac._widgets.tune import FIT_SYNTHETIC_LAYER
    from napari_symbac.fit.scene_fit import DEPTH_FIT_LAYERS

    viewer, tune = rendered
    crop = _ds2_top_cell(viewer, tune, real_data_dir)
    assert tune.fit_depth.native.isHidden() == (tune.modality.value != "fluorescence")
    tune.fit_envelope_stain.value = True
    tune.fit_depth.value = True
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    result = tune.fit_result
    assert result is not None, tune.status.value
    assert len(result.cells) == 1
    assert result.render.depth_layers == DEPTH_FIT_LAYERS
    assert 0.1 < abs(result.render.focus_offset_um) < 0.5  # moved off its start, in range
    assert 0.5 < result.render.envelope_stain_fraction < 0.99
    assert "focus_offset_um" in result.parameter_names
    assert tune.preview.render_settings.depth_layers == DEPTH_FIT_LAYERS
    assert viewer.layers[FIT_SYNTHETIC_LAYER].data.shape == crop.shape


def test_the_stain_boxes_are_fluorescence_only(rendered, real_data_dir):
    """Shown for fluorescence only, unticked when hidden; ticked over a phase recording
    (the preview switched to fluorescence) the fit is refused with the fix."""
    viewer, tune = rendered
    tune.reference.value = _real_trench(viewer, real_data_dir)
    assert tune.modality.value == "phase"
    for box in (tune.fit_envelope_stain, tune.fit_depth):
        assert box.native.isHidden()  # (the viewer itself is not shown)
        tune.modality.value = "fluorescence"
        assert not box.native.isHidden()
        box.value = True
        tune.fit_button.native.click()
        assert tune.fit_worker is None
        assert f"'{box.text}' is fitted in fluorescence; this recording is phase: untick it" in (
            tune.status.value
        )
        tune.modality.value = "phase"
        assert box.native.isHidden()
        assert not box.value


def test_masks_opened_beside_the_recording_become_its_cell_masks(make_napari_viewer, real_data_dir):
    """Found as a user: Omnipose's Sample000193 opened with its `_cp_masks.tif` (a Labels
    layer), the pixel size entered, Simulate, then Auto-fit: *cell masks* had stayed
    empty, so the dense colony was fitted without them for 13 min (reduced chi-square
    222, 45 of its 182 cells) and the report advised `napari-symbac fit --masks`. Now
    the newest Labels layer of the real image's size with cells in it is chosen, whether
    it was opened before the pixel size was entered or after; an empty or mis-sized one
    is not, and a choice of none by hand stays."""
    import imageio.v3 as iio
    import tifffile

    root = real_data_dir / "omnipose"
    grey = np.asarray(iio.imread(root / "Sample000033.png"))[..., 0]
    masks = tifffile.imread(root / "Sample000033_cp_masks.tif")
    viewer = make_napari_viewer()
    tune = TuneWidget(viewer)
    real = viewer.add_image(grey, name="colony")  # no pixel size yet: not a recording
    viewer.add_labels(np.zeros_like(masks), name="paint here")  # empty: never chosen
    viewer.add_labels(masks[:100], name="other masks")  # another size: never chosen
    opened = viewer.add_labels(masks, name="Sample000033_cp_masks")
    assert tune.masks.value is None  # no real image yet
    real.metadata = {**real.metadata, "pixel_size_um": 0.134, "modality": "phase"}
    assert tune.reference.value is real
    assert tune.masks.value is opened
    tune.masks.value = None  # the user's choice: no masks
    viewer.add_image(np.zeros((4, 4), np.uint16), name="unrelated")
    assert tune.masks.value is None
    later = viewer.add_labels(masks, name="masks opened after")
    assert tune.masks.value is later


def test_auto_fit_fits_the_sample_brightfield_with_its_lens_term(rendered, qtbot):
    """The ColiCoords sample's brightfield layer (hidden, marked bright field) chosen as
    the recording beside a phase-contrast preview: Auto-fit fits its 8 cells (the
    masks' count) with the lens term, the preview turns bright field, the lens slider
    shows the term and the phase kernel's sliders are hidden."""
    viewer, tune = rendered
    _as_agar_pad(tune)
    viewer.open_sample("napari-symbac", "colicoords")
    real = viewer.layers["ColiCoords brightfield"]
    tune.reference.value = real
    # chosen, the recording's modality is the preview's (before, only Auto-fit switched it)
    assert tune.modality.value == "brightfield"
    assert tune.preview.model.microscope.modality == "brightfield"
    assert tune.sliders["ring_contrast"].native.isHidden()
    tune.masks.value = None  # the automatic start
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    result = tune.fit_result
    assert result is not None, tune.status.value
    assert len(result.cells.ids) == 8
    assert 1.0 < float(np.median(result.cells.width_um)) < 1.25
    assert tune.modality.value == "brightfield"
    lens = tune.sliders["defocus_contrast_um2"]
    assert not lens.native.isHidden()
    assert lens.value == pytest.approx(result.render.defocus_contrast_um2, abs=1e-3)
    for name in ("ring_contrast", "psf_offset", "apodisation_sigma_um"):
        assert tune.sliders[name].native.isHidden(), name
    # the preview, and so Export, is bright field with the fitted lens term
    assert tune.preview.model.microscope.modality == "brightfield"
    stored = tune.source.value.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert stored.microscope.modality == "brightfield"
    assert stored.render.defocus_contrast_um2 == pytest.approx(
        result.render.defocus_contrast_um2
    )


def test_a_camera_given_in_the_recording_step_is_the_fits(rendered, qtbot, real_data_dir):
    """Found as a user: Auto-fit's advice for a camera it could not check was
    `napari-symbac fit --camera`, which the GUI had no way to follow. The Recording step
    now takes the camera (its data sheet); Auto-fit fits with it, as `fit --camera`
    does, and says so; one the settings refuse is warned and the camera measured."""
    import dataclasses

    from napari_symbac._widgets.real_image import GIVEN_CAMERA, MEASURED_CAMERA, RealImageWidget
    from napari_symbac.settings import Camera

    viewer, tune = rendered
    real = _real_trench(viewer, real_data_dir)
    recording = RealImageWidget(viewer)
    recording.image.value = real
    assert recording.camera_source.value == MEASURED_CAMERA
    assert recording.camera.native.isHidden()
    recording.camera_source.value = GIVEN_CAMERA
    assert not recording.camera.native.isHidden()
    given = Camera(baseline_adu=500.0, sensitivity_adu_per_e=1.5, dark_noise_e=3.0)
    recording.camera.value = given
    assert real.metadata["camera"] == given
    # a camera the settings refuse, or one that cannot have recorded the trench (591-7507
    # ADU): said under the camera's form, and the camera measured until it is fixed
    # (found as a user: an 8-bit camera failed Auto-fit with "every pixel is clipped",
    # an offset of 3000 ADU fitted to chi-square 1e5, both without a word)
    for field, value, words in (
        ("bit_depth", 8, "not below the camera's full scale"),  # 500 ADU > 8 bits' 255
        ("baseline_adu", 3000.0, "its offset 3000 ADU lies above 81% of the recording"),
    ):
        getattr(recording.camera, field).value = value
        assert words in recording.camera_warning.value
        assert not recording.camera_warning.native.isHidden()
        assert real.metadata["camera"] is None
        recording.camera.value = given
        assert real.metadata["camera"] == given
        assert recording.camera_warning.value == ""
    recording.camera.value = dataclasses.replace(given, baseline_adu=10.0, bit_depth=8)
    assert "reaches 7507 ADU, above this camera's full scale" in recording.camera_warning.value
    recording.camera.value = given
    result = _auto_fit(tune, qtbot, real, iterations=1)
    assert result.camera == given
    assert tune.preview.model.camera == given
    assert "Camera given in the Recording step: 1.5 ADU/e-, read noise 3 e-" in tune.status.value
    assert "Camera, model-free" not in tune.status.value  # as `fit --camera`: not checked
    # each recording shows its own camera when chosen, never the form's last one
    other = viewer.add_image(
        real.data[:128], name="other", scale=(0.065, 0.065), metadata={"pixel_size_um": 0.065}
    )
    recording.image.value = other
    assert recording.camera_source.value == MEASURED_CAMERA
    assert other.metadata["camera"] is None
    assert recording.camera.value == Camera()
    # a camera given before the pixel size is entered is kept (found as a user: lost)
    bare = viewer.add_image(real.data[:100], name="bare")
    recording.image.value = bare
    recording.camera_source.value = GIVEN_CAMERA
    recording.camera.value = given
    assert bare.metadata["camera"] == given
    recording.image.value = other
    recording.image.value = bare
    assert recording.camera_source.value == GIVEN_CAMERA
    recording.pixel_size.value = 0.065
    assert bare.metadata["camera"] == given
    recording.image.value = real
    assert recording.camera_source.value == GIVEN_CAMERA
    assert recording.camera.value == given
    recording.camera_source.value = MEASURED_CAMERA
    assert real.metadata["camera"] is None


def test_auto_fit_refuses_a_real_image_without_a_pixel_size(rendered, real_data_dir):
    """Found as a user: an image with no pixel size (opened by napari's own reader) was
    fitted at the simulation's 0.065 um without a word; it is refused with where to
    enter it, and nothing runs."""
    viewer, tune = rendered
    trench = _real_trench(viewer, real_data_dir).data
    unscaled = viewer.add_image(trench, name="unscaled")
    tune.reference.value = unscaled
    tune.fit_button.native.click()
    assert tune.fit_worker is None
    assert tune.status.value.startswith("unscaled: no pixel size")
    assert tune.status.value.endswith("then fit it")
    assert tune.fit_result is None



def test_auto_fit_refuses_a_trench_on_its_side(rendered, real_data_dir):
    """Found as a user: the SyMBac trench turned by 90 degrees (46 x 256 px) was laid out
    as a pad and fitted as an open field; Auto-fit now says to turn it upright."""
    import tifffile

    viewer, tune = rendered
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    real = viewer.add_image(
        np.rot90(trench), name="lying", scale=(0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )  # fmt: skip
    tune.reference.value = real
    tune.fit_button.native.click()
    assert tune.fit_worker is None
    assert tune.status.value.startswith("lying is 46 x 256 px (rows x columns), wide and short")
    assert "rotate it by 90 degrees" in tune.status.value
