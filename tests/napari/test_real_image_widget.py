"""Load a real image from a file, paint a few strokes of each class, measure them."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets._recording import check_recording_frame
from napari_symbac._widgets.real_image import RealImageWidget, class_layer_name
from napari_symbac.fit import CLASS_VALUES


def _trench_with_pixel_size(real_data_dir, tmp_path, name: str, pixel_um: float):
    """The SyMBac trench saved as an ImageJ TIFF that records ``pixel_um``."""
    source = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    path = tmp_path / f"{name}.tif"
    tifffile.imwrite(
        path, source, imagej=True, resolution=(1 / pixel_um, 1 / pixel_um), metadata={"unit": "um"}
    )
    return path


def _docked(make_napari_viewer) -> RealImageWidget:
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    viewer.window.add_dock_widget(widget)
    return widget


def test_open_paint_measure(make_napari_viewer, tmp_path, real_data_dir):
    path = _trench_with_pixel_size(real_data_dir, tmp_path, "trench", 0.065)
    source = tifffile.imread(path)
    widget = _docked(make_napari_viewer)
    viewer = widget.viewer

    widget.file.value = path
    assert widget.image.value.name == "trench"
    # the messages take the whole row: no label column that reads "warning" or "result"
    for message in (widget.warning, widget.result):
        assert message._labeled_widget()._label_widget.native.isHidden(), message.name
    assert widget.pixel_size.value == pytest.approx(0.065, abs=1e-4)

    fluorescence = tmp_path / "fluo.ome.tif"
    tifffile.imwrite(
        fluorescence,
        source,
        metadata={
            "axes": "YX",
            "PhysicalSizeX": 0.11,
            "Channel": {"ContrastMethod": "Fluorescence"},
        },
    )
    widget.file.value = fluorescence
    assert widget.modality.value == "fluorescence"
    assert widget.pixel_size.value == pytest.approx(0.11)
    widget.image.value = viewer.layers["trench"]

    widget.paint_button.native.click()
    labels = viewer.layers[class_layer_name("trench")]
    assert labels.mode == "paint"
    assert labels.selected_label == CLASS_VALUES["cell"]
    assert labels.data.shape == source.shape
    # A user's strokes: a few brush dabs along each region.
    for row in range(60, 220, 20):
        labels.paint((row, 22), CLASS_VALUES["cell"], refresh=False)
        labels.paint((row, 2), CLASS_VALUES["device"], refresh=False)
        labels.paint((row, 12), CLASS_VALUES["media"], refresh=False)
    widget.measure_button.native.click()
    stats = widget.statistics
    assert stats is not None
    assert stats["device"].mean < stats["cell"].mean < stats["media"].mean
    assert "cell: mean" in widget.result.value


def test_measure_without_labels_says_what_to_do(make_napari_viewer):
    viewer = make_napari_viewer()
    viewer.add_image(np.random.default_rng(0).random((32, 32)), name="img")
    widget = RealImageWidget(viewer)
    widget.measure_button.native.click()
    assert widget.result.value == "Paint classes first"
    widget.paint_button.native.click()
    widget.measure_button.native.click()
    assert "missing the class(es) cell, media" in widget.result.value


def test_paint_and_measure_a_time_series(make_napari_viewer):
    rng = np.random.default_rng(2)
    movie = rng.normal(1000, 20, (3, 40, 30))
    movie[:, 10:20, 10:20] -= 400  # a dark cell in every frame
    viewer = make_napari_viewer()
    viewer.add_image(movie, name="movie")
    widget = RealImageWidget(viewer)
    widget.paint_button.native.click()
    labels = viewer.layers[class_layer_name("movie")]
    assert labels.data.shape == movie.shape
    labels.paint((1, 15, 15), CLASS_VALUES["cell"], refresh=False)
    labels.paint((2, 30, 25), CLASS_VALUES["media"], refresh=False)
    widget.measure_button.native.click()
    assert widget.statistics["cell"].mean == pytest.approx(600, abs=15)
    assert widget.statistics["media"].mean == pytest.approx(1000, abs=15)


def test_missing_pixel_size_is_asked_for_and_remembered(
    make_napari_viewer, tmp_path, real_data_dir, notifications
):
    """Defect 4: a TIFF without pixel size opened at 1 um/px with no warning, kept the
    previous image's value, and an out-of-range value raised an uncaught error."""
    source = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    with_size = tmp_path / "sized.tif"
    tifffile.imwrite(
        with_size, source, imagej=True, resolution=(1 / 0.11, 1 / 0.11), metadata={"unit": "um"}
    )
    bare = tmp_path / "bare.tif"
    tifffile.imwrite(bare, source)  # no resolution tags
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    viewer.window.add_dock_widget(widget)

    widget.file.value = with_size
    assert widget.pixel_size.value == pytest.approx(0.11, abs=1e-4)
    widget.file.value = bare
    layer = viewer.layers["bare"]
    assert widget.image.value is layer
    assert widget.pixel_size.value == 0  # not the previous image's 0.11
    assert "no pixel size" in widget.warning.value
    assert any("no pixel size" in message for message in notifications)
    assert not layer.metadata.get("pixel_size_um")

    widget.pixel_size.value = 50.0  # implausible: warned, not raised, not applied
    assert "implausible" in widget.warning.value
    assert not layer.metadata.get("pixel_size_um")

    widget.pixel_size.value = 0.0745  # as docs/gui.md gives Sample000193: not rounded
    assert layer.metadata["pixel_size_um"] == 0.0745
    assert layer.scale[-1] == 0.0745
    widget.pixel_size.value = 0.065
    assert widget.warning.value == ""
    assert layer.metadata["pixel_size_um"] == pytest.approx(0.065)
    assert tuple(layer.scale) == pytest.approx((0.065, 0.065))
    # the scale bar and the cursor read um, not "pixel" (found as a user)
    assert [str(unit) for unit in layer.units] == ["micrometer", "micrometer"]
    assert layer.metadata["microscope"].pixel_size_um == pytest.approx(0.065)
    # remembered with the layer: choosing the other image and back restores it
    widget.image.value = viewer.layers["sized"]
    assert widget.pixel_size.value == pytest.approx(0.11, abs=1e-4)
    widget.image.value = layer
    assert widget.pixel_size.value == pytest.approx(0.065)


def test_retyping_the_pixel_size_warns_only_when_it_is_entered(
    make_napari_viewer, qtbot, tmp_path, real_data_dir, notifications
):
    """Found as a user: retyping the pixel size showed "no pixel size" at the first
    keystroke (the field at 0 for a moment) and kept that toast after a valid value.
    The value is taken when the editing is finished (Enter, leaving the field)."""
    from qtpy.QtCore import Qt

    path = _trench_with_pixel_size(real_data_dir, tmp_path, "sized", 0.11)
    widget = _docked(make_napari_viewer)
    widget.file.value = path
    layer = widget.image.value
    box = widget.pixel_size.native

    def retype(text: str) -> None:
        box.selectAll()
        qtbot.keyClicks(box, text)

    retype("0.065")  # passes through 0, 0., 0.0 and 0.06
    assert not any("pixel size" in message for message in notifications)
    assert widget.warning.value == ""
    assert layer.metadata["pixel_size_um"] == pytest.approx(0.11)  # not yet entered
    qtbot.keyClick(box, Qt.Key.Key_Return)
    assert layer.metadata["pixel_size_um"] == pytest.approx(0.065)
    assert not any("pixel size" in message for message in notifications)

    retype("0")  # really none after editing: warned once, then
    qtbot.keyClick(box, Qt.Key.Key_Return)
    assert sum("no pixel size" in message for message in notifications) == 1
    assert "no pixel size" in widget.warning.value
    retype("0.08")  # a valid value typed: no further warning
    qtbot.keyClick(box, Qt.Key.Key_Return)
    assert sum("no pixel size" in message for message in notifications) == 1
    assert widget.warning.value == ""
    assert layer.metadata["pixel_size_um"] == pytest.approx(0.08)


def test_the_view_follows_a_pixel_size_entered_after_simulate(
    make_napari_viewer, qtbot, tmp_path, real_data_dir
):
    """Found as a user: the trench opened without a pixel size, Simulate run, then 0.065
    entered: every layer moved into micrometres (15 times smaller) and the view stayed,
    a speck in a corner of a black canvas. Now the view is reset as the layers move."""
    from napari_symbac._widgets.simulate import RESULT_IMAGE_LAYER, SimulateWidget

    bare = tmp_path / "bare.tif"
    tifffile.imwrite(bare, tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff"))
    viewer = make_napari_viewer()
    real_image, simulate = RealImageWidget(viewer), SimulateWidget(viewer)
    viewer.window.add_dock_widget(real_image)
    real_image.file.value = bare
    simulate.form.n_frames.value = 4
    simulate.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_IMAGE_LAYER in viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: simulate.worker is None, timeout=10_000)
    in_pixels = viewer.camera.zoom
    real_image.pixel_size.value = 0.065
    entered = viewer.camera.zoom
    assert entered > 5 * in_pixels  # zoomed in on the layers now 15 times smaller
    viewer.reset_view()
    assert viewer.camera.zoom == pytest.approx(entered)
    # a 10x slip corrected after Simulate: the view follows too (found as a user:
    # 0.65 then 0.065 left the layers a speck at the top left); a refinement does not
    real_image.pixel_size.value = 0.65
    assert viewer.camera.zoom == pytest.approx(entered / 10, rel=0.05)
    real_image.pixel_size.value = 0.065
    assert viewer.camera.zoom == pytest.approx(entered)
    real_image.pixel_size.value = 0.07
    assert viewer.camera.zoom == pytest.approx(entered)


def test_an_image_opened_beside_the_recording_is_shown_and_asked_its_pixel_size(
    make_napari_viewer, tmp_path, real_data_dir, notifications
):
    """Found as a user: with the trench chosen (0.065 um), DeLTA's trench opened with the
    plugin's reader got no "no pixel size" prompt: the dock stayed on the trench and the
    new layer sat in pixels beside the layers in micrometres."""
    bare = tmp_path / "bare.tif"
    tifffile.imwrite(bare, tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff"))
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    viewer.window.add_dock_widget(widget)
    widget.file.value = bare
    widget.pixel_size.value = 0.065
    assert widget.warning.value == ""
    (second,) = viewer.open(
        real_data_dir / "ecoli_delta_phase_normalised.tiff", plugin="napari-symbac"
    )
    assert widget.image.value is second
    assert widget.pixel_size.value == 0
    assert "no pixel size" in widget.warning.value
    # the view fits the new image, in pixels some 15 times the trench in micrometres
    # (found as a user: a few of its pixels filled the canvas)
    low, high = second.extent.world[:, -2:]
    np.testing.assert_allclose(viewer.camera.center[-2:], (low + high) / 2, atol=1)
    assert "normalised values (-0.02847..1.007, not camera counts)" in widget.result.value
    viewer.add_image(np.zeros((8, 8, 4), np.uint8), name="mask", metadata={"symbac": {}})
    assert widget.image.value is second  # a layer the plugin made is no recording


def test_a_removed_recording_leaves_its_successors_problem_in_the_dock(
    make_napari_viewer, notifications
):
    """Found as a user: closing the viewer removed the recording, the dock chose an image
    without a pixel size, and a 'no pixel size' notification came as the window closed.
    Its warning is shown in the dock, not notified again."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    waiting = viewer.add_image(np.full((40, 30), 900.0), name="waiting")
    assert sum("waiting: no pixel size" in m for m in notifications) == 1
    recording = viewer.add_image(
        np.full((40, 30), 1000.0), name="recording", metadata={"pixel_size_um": 0.065}
    )
    widget.image.value = recording
    assert widget.warning.value == ""
    viewer.layers.remove(recording)
    assert widget.image.value is waiting
    assert "no pixel size" in widget.warning.value
    assert sum("waiting: no pixel size" in m for m in notifications) == 1


def test_measured_means_are_kept_with_the_layer(make_napari_viewer):
    rng = np.random.default_rng(3)
    image = rng.normal(1100, 10, (40, 30))
    image[10:20, 10:20] = rng.normal(700, 10, (10, 10))
    viewer = make_napari_viewer()
    layer = viewer.add_image(image, name="img")
    widget = RealImageWidget(viewer)
    widget.pixel_size.value = 0.065
    widget.paint_button.native.click()
    labels = viewer.layers[class_layer_name("img")]
    assert tuple(labels.scale) == pytest.approx((0.065, 0.065))
    assert [str(unit) for unit in labels.units] == ["micrometer", "micrometer"]
    labels.paint((15, 15), CLASS_VALUES["cell"], refresh=False)
    labels.paint((30, 25), CLASS_VALUES["media"], refresh=False)
    widget.measure_button.native.click()
    means = layer.metadata["class_means_adu"]
    baseline = 100.0  # Camera().baseline_adu
    assert means["cell"] == pytest.approx(700 - baseline, abs=10)
    assert means["media"] == pytest.approx(1100 - baseline, abs=10)


def test_a_pixel_size_entered_makes_the_image_a_recording_everywhere(
    make_napari_viewer, tmp_path, real_data_dir
):
    """Found as a user: a TIFF opened without pixel size, the size then entered, stayed
    missing from Diagnose's and Simulate's lists (they refreshed only when a layer was
    added), so Diagnose said "no recording" until something else was painted."""
    from napari_symbac._widgets.diagnose import DiagnoseWidget
    from napari_symbac._widgets.simulate import SimulateWidget
    from napari_symbac._widgets.tune import TuneWidget

    source = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    bare = tmp_path / "bare.tif"
    tifffile.imwrite(bare, source)  # no resolution tags
    viewer = make_napari_viewer()
    real_image = RealImageWidget(viewer)
    diagnose = DiagnoseWidget(viewer)
    simulate = SimulateWidget(viewer)
    tune = TuneWidget(viewer)

    real_image.file.value = bare
    layer = viewer.layers["bare"]
    assert diagnose.reference.value is None  # no pixel size yet: not offered
    assert simulate.recording.value is None
    real_image.pixel_size.value = 0.065
    assert diagnose.reference.value is layer
    assert simulate.recording.value is layer
    assert tune.reference.value is layer
    real_image.pixel_size.value = 50.0  # implausible: no longer a recording
    assert layer not in diagnose.reference.choices

    tune.fit_button.native.click()  # nothing rendered yet: says what to do first
    assert "Run Simulate first" in tune.status.value


def test_a_grey_png_saved_as_colour_is_used_by_its_grey_channel(
    make_napari_viewer, real_data_dir, notifications
):
    """Found as a user: napari opens the Omnipose colonies (grey PNGs saved as RGBA) as
    RGBA layers, which every step then took for a 377-frame series of 4-pixel rows."""
    from napari_symbac._widgets.diagnose import DiagnoseWidget

    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    diagnose = DiagnoseWidget(viewer)
    layer = viewer.open(real_data_dir / "omnipose" / "Sample000033.png")[0]
    assert layer.rgb
    widget.image.value = layer
    grey = viewer.layers["Sample000033 grey"]
    assert widget.image.value is grey
    assert grey.data.shape == layer.data.shape[:2]
    np.testing.assert_array_equal(grey.data, np.asarray(layer.data)[..., 0])
    # shown at its own grey levels (4-14 of 255), as *or open* shows it: napari's 0-255
    # made the canvas black (found as a user)
    low, high = grey.contrast_limits
    assert grey.data.min() <= low < high <= grey.data.max()
    assert "grey image saved as colour" in widget.result.value
    widget.pixel_size.value = 0.065
    assert diagnose.reference.value is grey
    assert layer not in diagnose.reference.choices

    colour = np.zeros((32, 32, 3), np.uint8)
    colour[..., 0] = 200  # red only: a colour image
    widget.image.value = viewer.add_image(colour, name="colour", rgb=True)
    assert "colour image" in widget.warning.value
    assert any("open one grey channel" in message for message in notifications)
    assert "colour grey" not in viewer.layers


def test_a_deleted_grey_channel_is_said(make_napari_viewer, real_data_dir, notifications):
    """Found as a user: after deleting ``Sample000033 grey`` the dock fell back to the
    RGBA original, called it "a colour image" and still named the deleted layer as its
    grey channel. It says the grey channel was removed and how to get it back."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    viewer.open(real_data_dir / "omnipose" / "Sample000033.png")
    assert widget.image.value is viewer.layers["Sample000033 grey"]
    viewer.layers.remove("Sample000033 grey")
    assert widget.image.value is viewer.layers["Sample000033"]
    assert not any("is a colour image" in message for message in notifications)
    assert "grey channel, the layer 'Sample000033 grey', was removed" in widget.warning.value
    assert "its grey channel is the layer" not in widget.result.value


def test_a_colour_png_opened_before_the_dock_gets_its_grey_channel(
    make_napari_viewer, real_data_dir, notifications
):
    """Found as a user: File > Open of an Omnipose PNG, then the dock: it said the grey
    channel "was removed", a layer that was never made. It is made when the dock opens;
    a grey channel removed later is said in the dock, not as a notification (napari
    removes the layers one by one when the viewer closes)."""
    viewer = make_napari_viewer()
    viewer.open(real_data_dir / "omnipose" / "Sample000033.png")
    widget = RealImageWidget(viewer)
    grey = viewer.layers["Sample000033 grey"]
    assert widget.image.value is grey
    assert "was removed" not in widget.warning.value
    viewer.layers.remove(grey)
    assert "was removed" in widget.warning.value
    assert not any("was removed" in message for message in notifications)


def test_a_layer_another_reader_scaled_is_a_recording_to_every_dock(
    make_napari_viewer, real_data_dir
):
    """Found as a user: the trench opened by napari's own reader and scaled to 0.065 um
    (as readers of microscope formats scale their layers) was "no pixel size yet" to
    Diagnose and Simulate. Every dock now takes the scale a reader set (Auto-fit's
    refusal of an image without one: test_tune_widget.py)."""
    from napari_symbac._widgets._recording import is_recording, recording_microscope
    from napari_symbac._widgets.diagnose import DiagnoseWidget

    viewer = make_napari_viewer()
    diagnose = DiagnoseWidget(viewer)
    layer = viewer.open(real_data_dir / "ecoli_100x_oil_exponential.tiff", plugin="napari")[0]
    assert not is_recording(layer)  # the builtin reader sets no scale
    layer.scale = (0.065, 0.065)
    layer.units = ("um", "um")
    assert is_recording(layer)
    assert recording_microscope(layer).pixel_size_um == pytest.approx(0.065)
    diagnose.reference.reset_choices()
    assert layer in diagnose.reference.choices


def test_two_channels_of_one_name_are_told_apart_by_their_folder(
    make_napari_viewer, real_data_dir
):
    """Found as a user: ColiCoords' fluorescence/00002.tif and brightfield/00002.tif
    opened with *or open* became "00002" and "00002 [1]"."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    widget.file.value = ds1 / "fluorescence" / "00002.tif"
    widget.file.value = ds1 / "brightfield" / "00002.tif"
    assert [layer.name for layer in viewer.layers] == ["00002", "00002 (brightfield)"]
    assert widget.image.value is viewer.layers["00002 (brightfield)"]


def test_or_open_takes_a_grey_png_as_the_fit_command_does(make_napari_viewer, real_data_dir):
    """Found as a user: *or open* took only TIFFs ("Sample000033.png is not a TIFF
    file"), while `napari-symbac fit` reads the same PNG; it opens as its grey channel,
    and with no pixel size recorded the widget asks for one."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    widget.file.value = real_data_dir / "omnipose" / "Sample000033.png"
    layer = widget.image.value
    assert layer is viewer.layers["Sample000033"]
    assert not layer.rgb
    assert layer.data.shape == (287, 377)
    low, high = layer.contrast_limits  # the image's own 19 grey levels, not 0-255
    assert layer.data.min() <= low < high <= layer.data.max()
    assert widget.pixel_size.value == 0.0
    assert "no pixel size" in widget.warning.value
    widget.pixel_size.value = 0.134
    assert layer.metadata["pixel_size_um"] == 0.134


def test_or_open_reads_a_normalised_trench_as_counts(make_napari_viewer, real_data_dir):
    """Found as a user: DeLTA's normalised trench (float, -0.03..1.01) could not be
    opened ("has negative values ... the docks take no camera file"); it opens as
    counts, said on the dock, and the steps after take it."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    widget.file.value = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    layer = widget.image.value
    assert layer is viewer.layers["ecoli_delta_phase_normalised"]
    assert layer.data.min() == 0
    assert 10_000 < layer.data.max() < 10_500
    assert "not camera counts): read as (value + 0.02847) x 10000 ADU" in widget.result.value
    # the layer keeps the map as data: its counts map back to the file's values
    stored = tifffile.imread(real_data_dir / "ecoli_delta_phase_normalised.tiff")
    mapping = layer.metadata["counts_mapping"]
    np.testing.assert_allclose(mapping.values(layer.data), stored, atol=1e-6)
    widget.pixel_size.value = 0.065
    check_recording_frame(layer.data, layer.name)  # what Auto-fit and Diagnose check


def test_a_recording_without_a_modality_gets_one_from_what_it_shows(
    make_napari_viewer, real_data_dir
):
    """Found as a user: a ColiCoords fluorescence field (no modality, no pixel size in
    the TIFF) opened as phase contrast with a Ph3 condenser."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    fields = real_data_dir / "colicoords" / "test_data" / "ds2"
    widget.file.value = fields / "fluorescence" / "00066.tif"
    assert widget.modality.value == "fluorescence"
    assert "records no modality: fluorescence" in widget.result.value
    assert widget.microscope.condenser.native.isHidden()  # a phase-contrast setting
    fluorescence = widget.image.value
    widget.file.value = fields / "brightfield" / "00066.tif"
    assert widget.modality.value == "phase"
    assert "dark objects" in widget.result.value
    assert not widget.microscope.condenser.native.isHidden()
    # the user's choice, made before any pixel size, is kept when the layer is chosen again
    brightfield = widget.image.value
    widget.modality.value = "fluorescence"
    # ... and one the image contradicts is warned of at once (found as a user: phase
    # chosen for a fluorescence field was said only by Auto-fit, after Simulate)
    assert (
        "Modality doubt: 00066 (brightfield): the image does not look like fluorescence"
        in widget.result.value
    )
    assert "Set its modality to phase in the 1 Recording tab" in widget.result.value
    widget.modality.value = "phase"
    assert "Modality doubt" not in widget.result.value
    widget.modality.value = "fluorescence"
    widget.image.value = fluorescence
    widget.image.value = brightfield
    assert widget.modality.value == "fluorescence"
    assert widget.pixel_size.value == 0.0  # still asked for


def test_masks_and_the_colour_original_are_placed_over_the_recording(
    make_napari_viewer, real_data_dir
):
    """Found with the scale bar's units: a masks file (no pixel size) stayed 1 unit per
    pixel beside a recording in micrometres, 7x larger than it, and napari warned that
    the layers' units were inconsistent."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    original = viewer.open(real_data_dir / "omnipose" / "Sample000033.png")[0]
    widget.image.value = original
    grey = widget.image.value
    early = viewer.add_labels(np.zeros(grey.data.shape, np.uint16), name="early masks")
    widget.pixel_size.value = 0.134
    late = viewer.add_labels(np.zeros(grey.data.shape, np.uint16), name="late masks")
    for layer in (grey, original, early, late):
        assert tuple(layer.scale[-2:]) == pytest.approx((0.134, 0.134)), layer.name
        assert [str(unit) for unit in layer.units[-2:]] == ["micrometer", "micrometer"]
    # what napari draws by (None: "Inconsistent units across layers", a warning)
    assert viewer.layers.extent.units is not None
    widget.pixel_size.value = 0.1  # corrected: they follow
    for layer in (grey, original, early, late):
        assert tuple(layer.scale[-2:]) == pytest.approx((0.1, 0.1)), layer.name
    # another grey image of that size may come from another microscope: left alone
    other = viewer.add_image(np.zeros(grey.data.shape, np.uint8), name="another field")
    assert tuple(other.scale) == (1.0, 1.0)


def test_a_masks_file_napari_opens_as_an_image_is_placed_and_never_the_recording(
    make_napari_viewer, qtbot, real_data_dir
):
    """Found as a user: ColiCoords ds3's binary.tif opened with napari's own reader (an
    image) after the pixel size was entered stayed in pixels, 12.5x the recording; with
    the recording removed it became the recording ("no pixel size"). And it lay as an
    opaque grey image over the recording, hiding it: it becomes a Labels layer, as this
    plugin's reader makes it."""
    from napari.layers import Labels

    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    ds3 = real_data_dir / "colicoords" / "test_data" / "ds3"
    widget.file.value = ds3 / "flu.tif"
    recording = widget.image.value
    widget.pixel_size.value = 0.08
    opened = viewer.open(ds3 / "binary.tif", plugin="napari")[0]
    name = opened.name
    qtbot.waitUntil(lambda: isinstance(viewer.layers[name], Labels), timeout=10_000)
    masks = viewer.layers[name]
    np.testing.assert_array_equal(masks.data, np.asarray(opened.data))
    assert list(viewer.layers) == [recording, masks]
    assert tuple(masks.scale[-2:]) == pytest.approx((0.08, 0.08))
    assert [str(unit) for unit in masks.units[-2:]] == ["micrometer", "micrometer"]
    assert viewer.layers.extent.units is not None  # one unit over all layers
    viewer.layers.remove(recording)
    widget.image.reset_choices()
    assert masks not in widget.image.choices
    assert widget.image.value is not masks


def _open_refused_colour_png(widget, tmp_path) -> None:
    """Open a 32 x 32 colour PNG with *or open*: refused, said in the dock."""
    import imageio.v3 as iio

    colour = np.random.default_rng(0).integers(0, 255, (32, 32, 3), dtype=np.uint8)
    iio.imwrite(tmp_path / "colour.png", colour)
    widget.file.value = tmp_path / "colour.png"
    assert "Cannot open colour.png" in widget.result.value


def test_a_refused_file_is_not_still_said_when_the_next_one_opens(
    make_napari_viewer, real_data_dir, tmp_path
):
    """Found as a user: "Cannot open colour.png" stayed in the dock after the next image
    opened."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    _open_refused_colour_png(widget, tmp_path)
    fields = real_data_dir / "colicoords" / "test_data" / "ds2"
    widget.file.value = fields / "fluorescence" / "00066.tif"
    assert "Cannot open" not in widget.result.value
    assert "records no modality" in widget.result.value


def test_or_open_shows_the_file_of_the_recording_chosen(
    make_napari_viewer, real_data_dir, tmp_path
):
    """Found as a user: after a refused colour PNG, *or open* kept showing its path once
    another recording was opened (File > Open) and chosen, as if it were that recording's
    file. The field follows the chosen recording: its file, or empty for a layer from no
    file; and showing a file does not open it again."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    _open_refused_colour_png(widget, tmp_path)
    assert len(viewer.layers) == 0
    fields = real_data_dir / "colicoords" / "test_data" / "ds2"
    opened = viewer.open(fields / "fluorescence" / "00066.tif")[0]  # File > Open
    assert widget.image.value is opened
    assert widget.file.line_edit.value == str(fields / "fluorescence" / "00066.tif")
    drawn = viewer.add_image(np.full((16, 16), 500, np.uint16), name="drawn")
    widget.image.value = drawn  # no file
    assert widget.file.line_edit.value == ""
    widget.file.value = fields / "brightfield" / "00066.tif"  # *or open*
    brightfield = widget.image.value
    assert widget.file.line_edit.value == str(fields / "brightfield" / "00066.tif")
    widget.image.value = opened
    assert widget.file.line_edit.value == str(fields / "fluorescence" / "00066.tif")
    widget.image.value = brightfield
    assert widget.file.line_edit.value == str(fields / "brightfield" / "00066.tif")
    # shown, not opened again: one layer per file
    assert [layer.name for layer in viewer.layers] == ["00066", "drawn", "00066 (brightfield)"]
    # a grey PNG saved as colour, opened with File > Open: its grey channel's file is it
    png = real_data_dir / "omnipose" / "Sample000033.png"
    widget.image.value = viewer.open(png)[0]
    assert widget.image.value.name == "Sample000033 grey"
    assert widget.file.line_edit.value == str(png)


def test_what_the_fit_refuses_is_not_opened_and_a_missing_file_is_said(
    make_napari_viewer, tmp_path, monkeypatch
):
    """Found as a user: an all-zero and a negative-valued TIFF opened as recordings (the
    CLI refuses both, Auto-fit failed only later), and a mistyped path did nothing,
    under the previous file's "Cannot open"."""
    import tifffile

    shown = []
    monkeypatch.setattr(
        "napari_symbac._widgets.real_image.notify_warning", lambda message: shown.append(message)
    )
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    tifffile.imwrite(tmp_path / "zeros.tif", np.zeros((32, 32), np.uint16))
    tifffile.imwrite(tmp_path / "negative.tif", np.linspace(-1, 50, 32 * 32).reshape(32, 32))
    refusals = {"zeros.tif": "is constant (every pixel is 0)", "negative.tif": "negative values"}
    for name, words in refusals.items():
        widget.file.value = tmp_path / name
        assert f"Cannot open {name}" in widget.result.value
        assert words in widget.result.value
        assert words in shown[-1]
    assert "in the Recording step's camera (camera: given)" in widget.result.value
    assert len(viewer.layers) == 0
    widget.file.value = tmp_path / "no_such.tif"
    assert widget.result.value == f"No such file: {tmp_path / 'no_such.tif'}"
    assert len(shown) == 2  # said in the dock as it is typed, not as a notification


def test_a_pixel_size_no_camera_has_is_warned_and_used(
    make_napari_viewer, tmp_path, real_data_dir, notifications
):
    """Found as a user: 0.65 um (a 10x slip) at the form's 100x was taken in silence,
    where `napari-symbac fit` warns of the 65 um camera pixel; the GUI now says it too,
    keeps the value (as fit does), and the warning goes when the form adds up."""
    path = _trench_with_pixel_size(real_data_dir, tmp_path, "trench", 0.065)
    widget = _docked(make_napari_viewer)
    widget.file.value = path
    layer = widget.image.value
    assert widget.warning.value == ""
    widget.pixel_size.value = 0.65
    assert "is a 65 um camera pixel" in widget.warning.value
    assert "in the microscope form below" in widget.warning.value
    assert not widget.warning.native.isHidden()  # (the viewer itself is not shown)
    assert sum("65 um camera pixel" in message for message in notifications) == 1
    assert layer.metadata["pixel_size_um"] == pytest.approx(0.65)  # used all the same
    widget.microscope.magnification.value = 10.0  # a 10x objective: 6.5 um camera pixel
    assert widget.warning.value == ""
    assert widget.warning.native.isHidden()
    assert sum("camera pixel" in message for message in notifications) == 1


def test_a_folder_typed_in_or_open_is_said(make_napari_viewer, tmp_path):
    """Found as a user: a folder's path left the previous "No such file" in the dock."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    widget.file.value = tmp_path / "no_such.tif"
    assert widget.result.value.startswith("No such file")
    widget.file.value = tmp_path
    assert widget.result.value == (
        f"{tmp_path} is a folder: choose an image file in it (TIFF or PNG)"
    )
    assert len(viewer.layers) == 0


def test_a_hyperstack_of_channels_opens_as_a_layer_per_channel(
    make_napari_viewer, cell_hyperstack
):
    """A brightfield + fluorescence hyperstack (Fiji's composite): *or open*, which reads
    one recording, says so and where the channels open; File > Open with this plugin's
    reader adds a layer per channel, each in micrometres, to choose as the recording."""
    path, channels = cell_hyperstack
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    widget.file.value = path
    assert "Cannot open two_channels.tif: two_channels.tif holds 2 channels" in widget.result.value
    assert widget.result.value.endswith("the napari-symbac reader, which adds a layer per channel")
    assert len(viewer.layers) == 0
    layers = viewer.open(path, plugin="napari-symbac")
    assert [layer.name for layer in layers] == ["two_channels channel 0", "two_channels channel 1"]
    widget.image.value = layers[1]
    np.testing.assert_array_equal(layers[1].data, channels[1])
    assert layers[1].scale[-1] == pytest.approx(0.08, rel=1e-4)
    assert "Cannot open" not in widget.result.value


def test_a_layer_scaled_in_nanometres_by_another_reader_is_read_in_um(
    make_napari_viewer, real_data_dir
):
    """A layer that another reader scaled in nanometres (scale 65, units nm) was taken
    for 65 um pixels and warned implausible; its unit is now converted."""
    source = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    widget = _docked(make_napari_viewer)
    layer = widget.viewer.add_image(source, name="nd2", scale=(65, 65), units=("nm", "nm"))
    widget.image.value = layer
    assert widget.pixel_size.value == pytest.approx(0.065)
    assert widget.warning.value == ""
    assert tuple(layer.scale) == pytest.approx((0.065, 0.065))
    assert [str(unit) for unit in layer.units] == ["micrometer", "micrometer"]


def test_or_open_refuses_a_tiff_of_nan(make_napari_viewer, tmp_path):
    """Found as a user: *or open* took an all-NaN float TIFF as a recording (its check
    says it refuses what `fit` refuses); it is refused, named, and nothing is added."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    tifffile.imwrite(tmp_path / "nan.tif", np.full((32, 32), np.nan, np.float32))
    widget.file.value = tmp_path / "nan.tif"
    assert "Cannot open nan.tif: nan.tif contains 1024 NaN or infinite pixels" in (
        widget.result.value
    )
    assert len(viewer.layers) == 0


def test_an_8_bit_recordings_classes_are_measured_above_its_own_offset(
    make_napari_viewer, real_data_dir
):
    """Found as a user: the class means of an 8-bit colony (cells about 80, background
    140 on a 0-255 scale) were taken above the built-in camera's 100 ADU offset: the
    cells' mean came out 0 ADU, and Simulate drew them black."""
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    widget.file.value = real_data_dir / "omnipose" / "Sample000252.png"
    layer = widget.image.value
    widget.pixel_size.value = 0.05734
    masks = tifffile.imread(real_data_dir / "omnipose" / "Sample000252_cp_masks.tif")
    widget.paint_button.native.click()
    classes = viewer.layers[class_layer_name(layer.name)]
    cells = masks > 0
    classes.data = np.where(cells, CLASS_VALUES["cell"], CLASS_VALUES["media"]).astype(np.uint8)
    widget.measure_button.native.click()
    means = layer.metadata["class_means_adu"]
    data = np.asarray(layer.data, np.float64)
    offset = data[cells].mean() - means["cell"]
    assert 0 <= offset <= np.quantile(data, 0.001) + 1e-9  # the fit's offset guess, not 100
    assert means["media"] - means["cell"] == pytest.approx(data[~cells].mean() - data[cells].mean())
    assert means["cell"] > 0.5 * data[cells].mean()


def test_a_normalised_image_opened_by_napari_is_said_unfittable_as_it_is_chosen(
    make_napari_viewer, real_data_dir
):
    """Found as a user: DeLTA's normalised trench opened with napari's own reader (values
    -0.03-1.01) showed only the pixel size and modality notes; Simulate drew it with the
    built-in camera, thousands of ADU, and only Auto-fit refused it. The dock says at
    once what the steps will refuse, and what to open instead."""
    from napari_symbac._widgets.real_image import RECORDING_DOUBT

    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    path = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    (layer,) = viewer.open(path, plugin="napari")
    widget.image.value = layer
    assert widget.result.value.startswith(f"{RECORDING_DOUBT} {layer.name} has negative values")
    assert "a normalised image opened by napari-symbac" in widget.result.value
    # read by this plugin (as counts): nothing to doubt
    viewer.layers.remove(layer)
    widget.file.value = path
    assert RECORDING_DOUBT not in widget.result.value
    assert "read as" in widget.result.value


def test_a_file_napari_opened_gives_the_pixel_size_it_records(
    make_napari_viewer, real_data_dir, tmp_path
):
    """Found as a user: a TIFF recording 65 nm pixels (OME), opened with napari's own
    reader (which keeps no pixel size), was said to come from a file that "does not
    record one"; the dock reads it from the file and enters it, placing the layer in
    micrometres. A phase + fluorescence file napari opened as one stack is warned of
    (it was fitted as a time-lapse of 2 frames)."""
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    path = tmp_path / "ome_nm.ome.tif"
    tifffile.imwrite(path, trench, metadata={"axes": "YX", "PhysicalSizeX": 65,
                                             "PhysicalSizeXUnit": "nm"})  # fmt: skip
    viewer = make_napari_viewer()
    widget = RealImageWidget(viewer)
    layer = viewer.open(path, plugin="napari")[0]
    assert widget.image.value is layer
    assert widget.pixel_size.value == pytest.approx(0.065)
    assert "pixel size 0.065 um read from its file" in widget.result.value
    assert layer.metadata["pixel_size_um"] == pytest.approx(0.065)
    assert tuple(layer.scale[-2:]) == pytest.approx((0.065, 0.065))
    assert not widget.warning.visible or "no pixel size" not in widget.warning.value
    channels = tmp_path / "phase_gfp.tif"
    tifffile.imwrite(channels, np.stack([trench, trench[::-1]]), imagej=True,
                     resolution=(1 / 0.065, 1 / 0.065),
                     metadata={"axes": "CYX", "unit": "um", "mode": "composite"})  # fmt: skip
    stack = viewer.open(channels, plugin="napari")[0]
    widget.image.value = stack
    assert "its file holds channels (axes CYX)" in widget.result.value
    assert widget.pixel_size.value == pytest.approx(0.065)  # read from the file all the same
    assert "napari-symbac reader, which adds a layer per channel" in widget.result.value


def test_two_recording_docks_say_a_missing_pixel_size_once(
    make_napari_viewer, real_data_dir, notifications
):
    """Found as a user: with the workflow dock and the Recording step docked alone, a
    TIFF without a pixel size gave two identical "no pixel size" toasts. Both docks
    show the warning; one notification says it."""
    viewer = make_napari_viewer()
    first, second = RealImageWidget(viewer), RealImageWidget(viewer)
    viewer.open(real_data_dir / "ecoli_100x_oil_exponential.tiff", plugin="napari-symbac")
    for widget in (first, second):
        assert "no pixel size" in widget.warning.value
    assert sum("no pixel size" in message for message in notifications) == 1
