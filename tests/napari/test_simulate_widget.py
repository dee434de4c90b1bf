"""Drive the Simulate widget as a user would: run to completion, and cancel midway."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets.simulate import (
    PREVIEW_LAYER,
    RESULT_IMAGE_LAYER,
    RESULT_LABELS_LAYER,
    RESULT_OPL_LAYER,
    SimulateWidget,
)


@pytest.fixture
def widget(make_napari_viewer):
    viewer = make_napari_viewer()
    widget = SimulateWidget(viewer)
    viewer.window.add_dock_widget(widget)
    return widget


def test_run_to_completion_adds_aligned_layers(widget, qtbot):
    widget.form.n_frames.value = 6
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    images = widget.viewer.layers[RESULT_IMAGE_LAYER].data
    labels = widget.viewer.layers[RESULT_LABELS_LAYER].data
    assert images.shape == labels.shape
    assert images.shape[0] == 6
    assert PREVIEW_LAYER not in widget.viewer.layers
    assert widget.status.value.startswith("Done: 6 frames")
    # the last frame's cells, as its labels hold them (not the lineage's)
    n_last = np.count_nonzero(np.unique(labels[-1]))
    assert f", {n_last} cells in the last (" in widget.status.value
    assert widget.run_button.enabled
    # the frame slider is named "frame" and starts at frame 0 (found as a user: it read
    # "-3", napari's default name of that axis, taken for the frame number)
    assert widget.viewer.dims.axis_labels == ("frame", "y", "x")
    assert widget.viewer.dims.current_step[0] == 0


def test_a_simulated_time_series_shows_its_ground_truth_tracks(
    widget, qtbot, tracks_in_mask_colours
):
    """The simulation's lineage as a Tracks layer over its frames (as Auto-fit shows a
    fitted time-lapse's): a row per cell and frame at its label's centroid, and each
    division in the graph."""
    from napari_symbac._widgets.simulate import RESULT_TRACKS_LAYER

    widget.form.n_frames.value = 16
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    viewer = widget.viewer
    labels = viewer.layers[RESULT_LABELS_LAYER]
    assert labels.contour == 1  # outlines: the synthetic image stays visible under them
    tracks = viewer.layers[RESULT_TRACKS_LAYER]
    assert f"the layer '{RESULT_TRACKS_LAYER}'" in widget.status.value
    assert tuple(tracks.scale) == tuple(labels.scale)
    tracks_in_mask_colours(tracks, labels)
    for track, t, row, col in tracks.data[:: max(1, len(tracks.data) // 40)]:
        region = np.argwhere(labels.data[int(t)] == int(track))
        assert len(region), (track, t)
        np.testing.assert_allclose(region.mean(axis=0), (row, col))
    lineage = widget.simulation.lineage
    divided = {c: r.parent_id for c, r in lineage.items() if r.parent_id}
    assert tracks.graph  # 16 frames of 3 min: cells divided
    for daughter, (mother,) in tracks.graph.items():
        assert divided[daughter] == mother


def test_cancel_midway_leaves_no_half_state(widget, qtbot):
    widget.form.n_frames.value = 2000
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: PREVIEW_LAYER in widget.viewer.layers, timeout=60_000)
    widget.cancel_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=60_000)
    assert PREVIEW_LAYER not in widget.viewer.layers
    assert RESULT_IMAGE_LAYER not in widget.viewer.layers
    assert widget.simulation is None
    assert widget.status.value.startswith("Cancelled")


def test_invalid_settings_are_reported_not_raised(widget):
    widget.form.cell_width_um.value = 5.0  # wider than the trench
    widget.run_button.native.click()
    assert "does not fit in a trench" in widget.status.value
    assert widget.worker is None


def test_optical_path_length_layer_is_aligned(widget, qtbot):
    import numpy as np

    from napari_symbac._widgets.simulate import RESULT_OPL_LAYER

    widget.form.n_frames.value = 4
    widget.show_opl.value = True
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_OPL_LAYER in widget.viewer.layers, timeout=120_000)
    opl = widget.viewer.layers[RESULT_OPL_LAYER]
    image = widget.viewer.layers[RESULT_IMAGE_LAYER]
    labels = widget.viewer.layers[RESULT_LABELS_LAYER].data
    upsample = widget.pipeline.render.upsample
    assert opl.data.shape == (4, labels.shape[1] * upsample, labels.shape[2] * upsample)
    # The centre render pixel of a camera pixel sits at that camera pixel's world position.
    centre = upsample // 2
    np.testing.assert_allclose(
        opl.data_to_world((0, centre + upsample * 5, centre + upsample * 7)),
        image.data_to_world((0, 5, 7)),
        atol=1e-9,
    )
    # Light crosses more optical path through a cell (n_cell > n_media) than through the
    # empty trench (OPL3 = n_media * depth, the lowest value with n_media < n_PDMS).
    cells = np.kron(labels[-1] > 0, np.ones((upsample, upsample), bool))
    empty_trench = 1.333 * widget.pipeline.simulation.trench.depth_um
    assert opl.data[-1].min() == pytest.approx(empty_trench, rel=1e-4)
    assert opl.data[-1][cells].mean() > empty_trench + 0.02


def test_agar_pad_run_previews_and_renders_its_field(widget, qtbot):
    widget.form.geometry.value = "agar_pad"
    widget.form.agar_pad.field_width_um.value = 12.0
    widget.form.agar_pad.field_height_um.value = 10.0
    widget.form.n_frames.value = 5
    assert not widget.form.agar_pad.native.isHidden()  # only the chosen geometry's form
    assert widget.form.outline.native.isHidden()
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    labels = widget.viewer.layers[RESULT_LABELS_LAYER].data
    pixel = widget.pipeline.microscope.pixel_size_um
    assert labels.shape[1:] == (round(10.0 / pixel), round(12.0 / pixel))
    assert labels[-1].max() > 0


def test_recording_sets_pixel_size_microscope_and_modality(widget, qtbot):
    """Defect 3: Simulate always used 0.065 um, NA 1.45, Ph3, whatever the recording."""
    import numpy as np

    from napari_symbac.settings import Microscope

    microscope = dataclasses.replace(
        Microscope(), pixel_size_um=0.1, numerical_aperture=1.3, condenser="Ph2"
    )
    recording = widget.viewer.add_image(
        np.zeros((100, 20), np.uint16),
        name="my recording",
        scale=(0.1, 0.1),
        metadata={
            "pixel_size_um": 0.1,
            "modality": "fluorescence",
            "microscope": microscope,
            "class_means_adu": {"cell": 2500.0, "media": 200.0},
        },
    )
    assert widget.recording.value is recording  # the newest recording, chosen for you
    assert widget.form.geometry.value == "agar_pad"  # fluorescence: an open field, as fit
    widget.form.n_frames.value = 3
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    used = widget.pipeline
    assert used.microscope.pixel_size_um == 0.1
    assert used.microscope.numerical_aperture == 1.3
    assert used.microscope.condenser == "Ph2"
    assert used.microscope.modality == "fluorescence"
    assert used.render.cell_intensity == 2500.0
    assert used.render.media_intensity == 200.0
    image = widget.viewer.layers[RESULT_IMAGE_LAYER]
    labels = widget.viewer.layers[RESULT_LABELS_LAYER].data
    assert tuple(image.scale[1:]) == tuple(recording.scale)  # same physical scale
    assert [str(unit) for unit in image.units[1:]] == ["micrometer", "micrometer"]
    frame = image.data[-1].astype(float)
    assert frame[labels[-1] > 0].mean() > 3 * frame[labels[-1] == 0].mean()  # bright cells


def test_a_trench_recording_sizes_the_trench(widget, qtbot):
    """Found as a user: the default trench was drawn 46 px wide beside a 32 px wide
    recording (the DeLTA crop) until Auto-fit; the frames now have the recording's size."""
    recording = widget.viewer.add_image(
        np.full((256, 32), 1000, np.uint16),
        name="narrow trench",
        scale=(0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )
    assert widget.recording.value is recording
    assert widget.form.geometry.value == "trench"
    widget.form.n_frames.value = 2
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    assert widget.viewer.layers[RESULT_IMAGE_LAYER].data.shape[1:] == (256, 32)
    trench = widget.pipeline.simulation.trench
    assert trench.width_um > widget.pipeline.simulation.cell_width_um  # still holds cells
    # a fitted closed end (its own top margin) keeps its place; the frame its height
    fitted = dataclasses.replace(trench, top_margin_um=1.2)
    widget.form.value = dataclasses.replace(widget.form.value, trench=fitted)
    widget._follow_recording(recording)
    sized = widget.form.value.trench
    assert sized.top_margin_um == 1.2
    assert sized.length_um + sized.shown_top_um == pytest.approx(256 * 0.065, abs=1e-3)


def test_a_corrected_pixel_size_sizes_the_trench_as_if_typed_first(widget):
    """Found as a user: the trench's pixel size typed as 0.65 (a 10x slip), then
    corrected to 0.065, left Simulate a trench 2.99 um wide with no walls (the whole
    frame), where 0.065 typed first gives the 1.4 um trench between 0.795 um walls."""
    recording = widget.viewer.add_image(
        np.full((256, 46), 1000, np.uint16),
        name="trench",
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )
    assert widget.recording.value is recording
    direct = widget.form.value.trench
    for pixel_um in (0.65, 0.065):
        recording.metadata = {**recording.metadata, "pixel_size_um": pixel_um}
        widget._refresh_recordings()
    assert widget.form.value.trench == direct
    assert direct.width_um == pytest.approx(1.4)
    assert 2 * direct.margin_um + direct.width_um == pytest.approx(46 * 0.065, abs=1e-3)


def test_closing_the_viewer_during_a_run_is_clean(make_napari_viewer, qtbot):
    """Defect 2: closing the viewer mid-run raised KeyError in _on_yielded /
    _remove_preview (pytest-qt fails the test on any exception in the event loop)."""
    viewer = make_napari_viewer()
    widget = SimulateWidget(viewer)
    viewer.window.add_dock_widget(widget)
    widget.form.n_frames.value = 2000
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: PREVIEW_LAYER in viewer.layers, timeout=60_000)
    job = widget.worker
    viewer.close()
    qtbot.waitUntil(lambda: job.cancelled.is_set(), timeout=10_000)
    qtbot.waitUntil(lambda: not job.worker.is_running, timeout=60_000)


def test_worker_error_is_a_notification_and_the_widget_recovers(widget, qtbot, monkeypatch):
    """A failure inside the worker (here a RecursionError, a RuntimeError that superqt
    took for an aborted thread) reaches the user; the buttons come back."""
    from napari.utils.notifications import notification_manager

    import napari_symbac.sim as sim

    def broken(*_args, **_kwargs):
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(sim, "Simulator", broken)
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    widget.form.n_frames.value = 3
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=60_000)
    assert widget.status.value.startswith("Failed")
    assert any("Simulation failed (RecursionError)" in str(n.message) for n in seen)
    assert widget.run_button.enabled
    assert not widget.cancel_button.enabled


def test_backend_choice_renders_on_torch(widget, qtbot):
    assert widget.backend.value == "scipy"
    assert "torch" in widget.backend.choices  # torch is installed in CI
    widget.backend.value = "torch"
    widget.form.n_frames.value = 4
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    images = widget.viewer.layers[RESULT_IMAGE_LAYER].data
    assert images.shape[0] == 4
    assert images.dtype == np.uint16
    assert images.std() > 0
    assert widget.status.value.startswith("Done: 4 frames")


@pytest.mark.parametrize(
    ("width_px", "modality", "geometry"),
    [(46, "phase", "trench"), (512, "phase", "agar_pad"), (46, "fluorescence", "agar_pad")],
)
def test_a_chosen_recording_sets_the_geometry_as_fit_would(widget, width_px, modality, geometry):
    """Found as a user: an open fluorescence field was simulated, and so Auto-fitted, as a
    trench until the user found the geometry in the form. (A trench image is also at
    least twice as tall as wide: the 57 x 61 px crop's case is in the test below.)"""
    import numpy as np

    widget.form.geometry.value = "chamber"
    widget.viewer.add_image(
        np.zeros((128, width_px), np.uint16),
        name="recording",
        metadata={"pixel_size_um": 0.1, "modality": modality},
    )
    assert widget.recording.value.name == "recording"
    assert widget.form.geometry.value == geometry
    if geometry == "agar_pad":  # the pad the recording's size (a 512 px field had 500 px)
        assert widget.form.agar_pad.field_width_um.value == pytest.approx(width_px * 0.1)
        assert widget.form.agar_pad.field_height_um.value == pytest.approx(128 * 0.1)
        assert widget.pipeline_settings().simulation.agar_pad.field_width_um == pytest.approx(
            width_px * 0.1
        )


@pytest.mark.parametrize("modality", ["fluorescence", "brightfield"])
def test_a_field_is_laid_out_as_its_cells(widget, qtbot, real_data_dir, modality):
    """Found as a user: a ColiCoords field of eight cells was simulated as one founder on
    an empty 41 um pad until Auto-fit (in bright field too, after fluorescence was laid
    out); the pad now has a colony per cluster of cells."""
    import tifffile

    image = tifffile.imread(
        real_data_dir / "colicoords" / "test_data" / "ds1" / modality / "00001.tif"
    )
    widget.viewer.add_image(
        image, name="field 1", scale=(0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": modality},
    )  # fmt: skip
    assert widget.form.geometry.value == "agar_pad"
    settings = widget.pipeline_settings().simulation
    assert 6 <= settings.agar_pad.n_colonies <= 8  # the field's 8 cells, a pair touching
    assert settings.n_founders == settings.agar_pad.n_colonies
    assert "colonies of one founder each" in widget.status.value
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    labels = widget.viewer.layers[RESULT_LABELS_LAYER].data
    assert len(np.unique(labels[-1])) - 1 >= 6  # cells over the pad, not one


def _units_warnings(viewer, notifications: list[str]) -> list[str]:
    """Draw the canvas (napari checks the layers' units when it draws) and return the
    "Inconsistent units" warnings shown so far."""
    viewer.screenshot(canvas_only=True)
    return [message for message in notifications if "Inconsistent units" in message]


def test_an_image_waiting_for_its_pixel_size_is_said_not_used(widget, qtbot):
    """Found as a user: a TIFF opened without a pixel size was not offered as the
    recording ("-----"), the run used the built-in settings, and nothing said either."""
    widget.viewer.add_image(np.full((256, 46), 1000, np.uint16), name="my trench")
    assert widget.recording.value is None
    said = (
        "Built-in settings: my trench is offered as your recording once its pixel size is "
        "entered (step 1, Recording)"
    )
    assert widget.status.value == said
    _simulate(widget, qtbot)
    assert widget.status.value.startswith("Done: 3 frames, ")
    assert widget.status.value.endswith(f"<br>{said}")
    assert "shown to compare with" not in widget.status.value


def test_a_pixel_size_typed_in_nm_is_said_where_the_recording_is_missed(
    make_napari_viewer, real_data_dir
):
    """Found as a user: 65 typed for 65 nm was warned of in the Recording step, then
    Simulate said the image is offered "once its pixel size is entered" and Auto-fit
    that it "has no pixel size yet", while the field showed 65."""
    from napari_symbac._widgets._recording import no_recording_message
    from napari_symbac._widgets.real_image import RealImageWidget

    viewer = make_napari_viewer()
    recording = RealImageWidget(viewer)
    simulate = SimulateWidget(viewer)
    recording.file.value = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    recording.pixel_size.value = 65
    assert simulate.recording.value is None
    nm = "(in nm? 65 nm is 0.065 um)"
    assert simulate.status.value.startswith(
        "Built-in settings: ecoli_100x_oil_exponential is not offered as your recording: "
        "pixel size 65 um (entered) is outside 0.02-1 um"
    )
    assert nm in simulate.status.value
    assert simulate.status.value.endswith("correct it in step 1, Recording")
    told = no_recording_message(viewer, "fit it")
    assert told.startswith("ecoli_100x_oil_exponential: pixel size 65 um (entered)")
    assert nm in told
    recording.pixel_size.value = 0.065  # corrected: the recording, nothing to say
    assert simulate.recording.value is not None
    assert simulate.status.value == ""


def test_a_time_lapse_recording_keeps_its_frame_shown(widget, qtbot):
    """Found as a user: with a 4-frame recording at frame 2, Simulate moved the shared
    slider to its own last frame, and Auto-fit then fitted another frame of the recording
    than the one the user had looked at."""
    movie = np.full((4, 64, 46), 1000, np.uint16)
    movie[:, 20:40, 15:30] = 400  # something dark to look at
    widget.viewer.add_image(
        movie, name="movie", scale=(1, 0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )  # fmt: skip
    assert widget.recording.value is widget.viewer.layers["movie"]
    widget.viewer.dims.set_current_step(0, 2)
    _simulate(widget, qtbot, n_frames=6)
    assert widget.viewer.dims.current_step[0] == 2


def _simulate(widget, qtbot, n_frames: int = 3, show_opl: bool = False) -> None:
    widget.form.n_frames.value = n_frames
    widget.show_opl.value = show_opl
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in widget.viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)


def test_a_recording_still_in_pixels_and_a_simulation_share_units(
    make_napari_viewer, qtbot, real_data_dir, notifications
):
    """Found as a user: a recording opened without a pixel size, then simulated beside,
    made napari warn "Inconsistent units across layers" (the synthetic layers were in
    um, the recording in pixels). They are in pixels until the pixel size is entered,
    then both in um, over each other."""
    from napari_symbac._widgets.real_image import RealImageWidget

    viewer = make_napari_viewer()
    recording = RealImageWidget(viewer)
    simulate = SimulateWidget(viewer)
    viewer.window.add_dock_widget(recording)
    viewer.window.add_dock_widget(simulate)
    recording.file.value = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    assert simulate.recording.value is None  # no pixel size yet: not a recording
    _simulate(simulate, qtbot, show_opl=True)
    synthetic = viewer.layers[RESULT_IMAGE_LAYER]
    assert [str(u) for u in synthetic.units[-2:]] == ["pixel", "pixel"]
    assert _units_warnings(viewer, notifications) == []

    recording.pixel_size.value = 0.065
    pixel = simulate.pipeline.microscope.pixel_size_um  # the simulation's, built in
    real = viewer.layers["ecoli_100x_oil_exponential"]
    for layer in (synthetic, viewer.layers[RESULT_LABELS_LAYER]):
        assert [str(u) for u in layer.units[-2:]] == ["micrometer", "micrometer"]
        np.testing.assert_allclose(layer.data_to_world((0, 5, 7)), (0, 5 * pixel, 7 * pixel))
    np.testing.assert_allclose(real.data_to_world((5, 7)), (5 * 0.065, 7 * 0.065))
    # the optical path length's render pixels still sit over the camera pixels
    opl = viewer.layers[RESULT_OPL_LAYER]
    upsample = simulate.pipeline.render.upsample
    centre = upsample // 2
    np.testing.assert_allclose(
        opl.data_to_world((0, centre + upsample * 5, centre + upsample * 7)),
        synthetic.data_to_world((0, 5, 7)),
        atol=1e-9,
    )
    assert _units_warnings(viewer, notifications) == []
    # simulated again, now with the recording: in um at once
    assert simulate.recording.value is real
    _simulate(simulate, qtbot)
    assert [str(u) for u in viewer.layers[RESULT_IMAGE_LAYER].units[-2:]] == [
        "micrometer",
        "micrometer",
    ]
    assert _units_warnings(viewer, notifications) == []


def test_a_recording_opened_in_pixels_after_a_simulation_shares_its_units(
    make_napari_viewer, qtbot, real_data_dir, notifications
):
    """The other order: simulated first (in um), then a recording without a pixel size
    opened: the simulation follows it into pixels instead of napari warning."""
    from napari_symbac._widgets.real_image import RealImageWidget

    viewer = make_napari_viewer()
    recording = RealImageWidget(viewer)
    simulate = SimulateWidget(viewer)
    _simulate(simulate, qtbot)
    synthetic = viewer.layers[RESULT_IMAGE_LAYER]
    assert [str(u) for u in synthetic.units[-2:]] == ["micrometer", "micrometer"]
    recording.file.value = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    assert [str(u) for u in synthetic.units[-2:]] == ["pixel", "pixel"]
    np.testing.assert_allclose(synthetic.data_to_world((0, 5, 7)), (0, 5, 7))
    assert _units_warnings(viewer, notifications) == []
    recording.pixel_size.value = 0.08
    pixel = simulate.pipeline.microscope.pixel_size_um
    np.testing.assert_allclose(synthetic.data_to_world((0, 5, 7)), (0, 5 * pixel, 7 * pixel))
    assert _units_warnings(viewer, notifications) == []


def test_a_recording_whose_modality_is_set_later_is_followed_again(
    make_napari_viewer, real_data_dir
):
    """Found as a user: ColiCoords' single-cell crop (57 x 61 px, no modality recorded)
    was taken for phase contrast without a word (its cell's glow is most of it, so its
    look does not say), and Simulate stayed at a trench after the modality was set to
    fluorescence. The dock says the modality is assumed, and Simulate follows the
    recording again when its modality changes: the pad laid out as its bright cells, no
    longer as dark ones.
    (A crop this square is a pad, not a trench, in either modality.)"""
    from napari_symbac._widgets.real_image import RealImageWidget

    viewer = make_napari_viewer()
    recording = RealImageWidget(viewer)
    simulate = SimulateWidget(viewer)
    recording.file.value = real_data_dir / "colicoords" / "01" / "fluorescence.tif"
    assert recording.result.value == (
        "fluorescence records no modality, and its look does not settle it (a crop around "
        "a few cells, or phase contrast): phase is assumed; choose the modality in the "
        "microscope form"
    )
    recording.pixel_size.value = 0.08
    pad = simulate.form.agar_pad
    assert simulate.form.geometry.value == "agar_pad"  # 57 x 61 px: no trench image
    assert (pad.field_width_um.value, pad.field_height_um.value) == pytest.approx((4.88, 4.56))
    as_phase = simulate.status.value  # laid out as dark cells
    recording.modality.value = "fluorescence"
    assert recording.result.value == ""  # the user's choice: no longer "assumed"
    assert simulate.form.geometry.value == "agar_pad"
    assert simulate.status.value != as_phase
    assert simulate.status.value.startswith("fluorescence: layout")  # as its bright cells
    assert (pad.field_width_um.value, pad.field_height_um.value) == pytest.approx((4.88, 4.56))


def test_closing_the_dock_during_a_run_cancels_it(make_napari_viewer, qtbot):
    """Found as a user: napari's close button on the dock left the simulation running;
    when it ended it added its layers to the viewer. Closing the panel now cancels the
    run as its Cancel button does: the preview goes, no result is added."""
    viewer = make_napari_viewer()
    widget = SimulateWidget(viewer)
    dock = viewer.window.add_dock_widget(widget)
    widget.form.n_frames.value = 2000
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: PREVIEW_LAYER in viewer.layers, timeout=60_000)
    job = widget.worker
    dock.destroyOnClose()  # the dock's close button
    qtbot.waitUntil(lambda: widget.worker is None, timeout=60_000)
    assert job.cancelled.is_set()
    assert PREVIEW_LAYER not in viewer.layers
    assert RESULT_IMAGE_LAYER not in viewer.layers
    assert widget.simulation is None
    assert widget.status.value.startswith("Cancelled")


def test_an_unpainted_8_bit_recording_is_simulated_on_its_own_scale(widget, qtbot, real_data_dir):
    """Found as a user: Simulate on an 8-bit colony with no painted classes (Omnipose's
    Sample000252, 54-241 from its 1st to 99th percentile) rendered at 2488-2909 ADU with
    the built-in camera and intensities. Its camera is now measured from it (8 bits) and
    its intensities start from a rough split of its cells and background."""
    from napari_symbac.io import read_image

    data = np.asarray(read_image(real_data_dir / "omnipose" / "Sample000252.png").data)
    assert data.dtype == np.uint8
    recording = widget.viewer.add_image(
        data, name="colony", scale=(0.05734, 0.05734),
        metadata={"pixel_size_um": 0.05734, "modality": "phase"},
    )  # fmt: skip
    settings = widget.pipeline_settings()
    assert settings.camera.bit_depth == 8
    assert settings.render.media_intensity < 255
    _simulate(widget, qtbot, n_frames=3)
    synthetic = widget.viewer.layers[RESULT_IMAGE_LAYER].data[-1].astype(np.float64)
    # the pad's background is the recording's (median 137; before: 2700)
    assert abs(np.median(synthetic) - np.median(data)) < 0.1 * np.median(data)
    assert synthetic.max() <= 255
    # shown like for like: the recording's grey levels (its own range showed it white)
    shown = widget.viewer.layers[RESULT_IMAGE_LAYER].contrast_limits
    assert tuple(shown) == tuple(recording.contrast_limits)
    assert "camera measured from it" in widget.status.value
    assert "a rough split of it into cells and background" in widget.status.value


def test_a_phase_pad_is_drawn_with_the_halo_of_the_recording(widget, qtbot, real_data_dir):
    """Found as a user: Simulate drew Omnipose's Sample000252 colony through the linear
    kernel as dark rods on a flat grey, its background 0.95 of the 1-99 % range against
    the recording's 0.44 (issue 16's table). A phase pad is now drawn through the
    partially coherent model at the colony fit's start: the halo around the colony is
    brighter than the pad far from it, as in the recording's own medians (measured with
    its masks)."""
    from napari_symbac.fit.masks import class_medians
    from napari_symbac.io import read_image

    folder = real_data_dir / "omnipose"
    data = np.asarray(read_image(folder / "Sample000252.png").data)
    masks = np.asarray(read_image(folder / "Sample000252_cp_masks.tif").data)
    pixel_um = 0.05734  # its cells 1 um wide
    widget.viewer.add_image(
        data, name="colony", scale=(pixel_um, pixel_um),
        metadata={"pixel_size_um": pixel_um, "modality": "phase"},
    )  # fmt: skip
    render = widget.pipeline_settings().render
    assert render.phase_model == "partially_coherent"
    assert render.cell_intensity == render.media_intensity  # transparent: phase contrast
    _simulate(widget, qtbot, n_frames=30)  # ~10 cells
    synthetic = widget.viewer.layers[RESULT_IMAGE_LAYER].data[-1]
    labels = widget.viewer.layers[RESULT_LABELS_LAYER].data[-1]
    far_px = 2.0 / pixel_um
    drawn = class_medians(synthetic, labels, far_px)
    real = class_medians(data, masks, far_px)
    assert real["halo"] - real["background"] > 0.25  # 0.49
    # the colony's halo above the pad (0.70; through the linear kernel -0.05)
    assert drawn["halo"] - drawn["background"] > 0.25
    assert drawn["cells"] < drawn["background"]
    assert "the cells drawn by their phase" in widget.status.value
    # shown at its last frame, to compare with the recording (not its founder)
    assert widget.viewer.dims.current_step[0] == 29
    assert "shown to compare with colony" in widget.status.value
    # a phase trench keeps the linear kernel of the supplement
    widget.form.geometry.value = "trench"
    assert widget.pipeline_settings().render.phase_model == "linear"


def test_a_class_not_measured_is_scaled_as_the_measured_media():
    from napari_symbac._widgets._recording import modality_render
    from napari_symbac.settings import RenderSettings

    default = modality_render(RenderSettings(), "phase")
    render = modality_render(RenderSettings(), "phase", {"cell": 40.0, "media": 130.0})
    assert (render.cell_intensity, render.media_intensity) == (40.0, 130.0)
    scale = 130.0 / default.media_intensity
    assert render.device_intensity == pytest.approx(default.device_intensity * scale)


def test_a_recording_at_a_pixel_size_no_camera_has_is_warned_about_while_it_runs(widget, qtbot):
    """Found as a user: a pixel size 10x too large (0.75 um at 100x), warned about in the
    Recording step, was simulated for minutes (cells 1.3 px wide on a 423 um pad) with
    "Rendered frame 20 of 94" and no word of it. The warning stays in the status."""
    rng = np.random.default_rng(0)
    widget.viewer.add_image(
        rng.normal(500.0, 20.0, (64, 64)).astype(np.uint16), name="slip",
        metadata={"pixel_size_um": 0.65, "modality": "fluorescence"},
    )  # fmt: skip
    said = []  # the status after each progress message (a Label has no changed signal)
    shown = widget._on_yielded

    def seen(message):
        shown(message)
        said.append(widget.status.value)

    widget._on_yielded = seen
    widget.form.n_frames.value = 2
    widget.run_button.native.click()
    warning = "Warning: pixel size 0.65 um at 100x magnification is a 65 um camera pixel"
    assert widget.status.value.startswith("Simulating...")
    assert warning in widget.status.value
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert any("Rendered frame" in line and warning in line for line in said), said
    assert widget.status.value.startswith("Done:")
    assert warning in widget.status.value
