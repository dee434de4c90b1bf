"""The Calibrate dock on a real ColiCoords field: settings, item 0 and report, then Export
writes the matched dataset; the input it refuses, and Cancel."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets._recording import layer_axes
from napari_symbac._widgets.calibrate import (
    CALIBRATION_KEY,
    CalibrateWidget,
    calibrated_layer_name,
)
from napari_symbac._widgets.export import ExportWidget
from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY


@pytest.fixture
def field(real_data_dir):
    """ColiCoords ds1 field 1, fluorescence (MIT): a 256 x 256 px corner and its masks."""
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    image = tifffile.imread(ds1 / "fluorescence" / "00001.tif")[:256, :256]
    masks = tifffile.imread(ds1 / "binary" / "00001_Probabilities_filtered.tif")[:256, :256]
    return image, masks


def _viewer_with(make_napari_viewer, image, masks=None, pixel_um=0.08):
    """The field as the Recording step leaves it (pixel size, modality, placed in um)."""
    viewer = make_napari_viewer()
    axes = layer_axes(pixel_um, 2)
    metadata = {"pixel_size_um": pixel_um, "modality": "fluorescence"}
    viewer.add_image(image, name="field", metadata=metadata, **axes)
    if masks is not None:
        viewer.add_labels(masks.astype(np.int32), name="field masks", **axes)
    widget = CalibrateWidget(viewer)
    viewer.window.add_dock_widget(widget)
    return viewer, widget


def test_calibrate_then_export_the_matched_dataset(make_napari_viewer, qtbot, tmp_path, field):
    image, masks = field
    viewer, widget = _viewer_with(make_napari_viewer, image, masks)
    # the recording and its masks (of its frame size) are chosen without a click
    assert widget.recording.value is viewer.layers["field"]
    assert widget.masks.value is viewer.layers["field masks"]
    export = ExportWidget(viewer)
    shown = []  # the status after each progress message (a QLabel signals no change)
    show = widget._on_progress
    widget._on_progress = lambda message: (show(message), shown.append(widget.status.value))
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=180_000)
    name = calibrated_layer_name("field")
    assert name in viewer.layers, widget.status.value
    # the status followed the stages: the fit's renders, then the compared items
    assert any(s.startswith("Calibrating: fit, ") for s in shown), shown
    # its bound said as one (found as a user: "472 renders (at most 45684)" read as hours)
    assert all("at most" not in s for s in shown), shown
    assert any("renders so far (a converging fit ends far below its bound" in s for s in shown)
    assert "Calibrating: simulating the dataset's first 4 items to compare..." in shown
    layer = viewer.layers[name]
    calibration = layer.metadata[SYMBAC_METADATA_KEY][CALIBRATION_KEY]
    assert calibration is widget.calibration
    assert calibration.settings.microscope.modality == "fluorescence"
    assert calibration.mask_offset_um is not None  # the masks' outline was measured
    assert viewer.layers[f"{name} masks"].data.max() > 0
    assert "WHERE THE SETTINGS CAME FROM" in widget.report.value
    assert "REAL AGAINST SYNTHETIC" in widget.report.value
    assert "WARNINGS" not in widget.report.value  # 1 um cells at their pixel size
    assert widget.status.value.startswith(calibration.method)
    assert "Export writes the dataset from it" in widget.status.value
    # placed over the recording, in micrometres
    assert tuple(layer.scale[-2:]) == pytest.approx((0.08, 0.08))
    # Export takes the new layer, and its dataset is the calibration's: item 0 is the
    # one shown (same seed, same item, bit for bit), its masks grown as the field's
    assert export.source.value is layer
    export.n_items.value = 2
    export.val_fraction.value = 0.0
    settings = export.settings()
    assert settings.mask_dilation_um == pytest.approx(round(calibration.mask_offset_um, 4))
    from napari_symbac.export.dataset import PipelineSource

    np.testing.assert_array_equal(PipelineSource(settings).make_unit(0)[0].image, layer.data)
    export.folder.value = tmp_path / "dataset"
    export.export_button.native.click()
    qtbot.waitUntil(lambda: export.report is not None, timeout=180_000)
    qtbot.waitUntil(lambda: export.worker is None, timeout=10_000)
    assert export.report.complete, export.status.value
    images = sorted((tmp_path / "dataset" / "tiff" / "train" / "images").glob("*.tif"))
    assert len(images) == 2
    np.testing.assert_array_equal(tifffile.imread(images[0]), layer.data)
    # a calibrated dataset is single frames: a time series is refused, in words
    export.kind.value = "timeseries"
    with pytest.raises(ValueError, match="single frames"):
        export.settings()


def test_cells_no_bacterium_is_as_wide_are_warned(
    make_napari_viewer, qtbot, field, notifications
):
    """Found as a user: a colony calibrated at 1.8 times its pixel size exported cells
    1.80 um wide without a word (Auto-fit warned). Here the field at 1.5 times its own:
    the dataset is made, and the status and a notification say to check the pixel size."""
    image, masks = field
    viewer, widget = _viewer_with(make_napari_viewer, image, masks, pixel_um=0.12)
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=180_000)
    assert calibrated_layer_name("field") in viewer.layers, widget.status.value
    assert widget.status.value.startswith("Warning: the dataset's cells are ")
    assert "check the pixel size" in widget.status.value
    assert "Export writes the dataset from it" in widget.status.value
    assert any(m.startswith("Calibrate: Warning: the dataset's cells") for m in notifications)
    assert "\nWARNINGS\n" in widget.report.value


def test_refusals_name_the_fix(make_napari_viewer, field):
    viewer, widget = _viewer_with(make_napari_viewer, field[0])
    assert widget.masks.value is None
    widget.cell_width_um.value = 1.0  # a width without masks to measure it on
    widget.run_button.native.click()
    assert widget.worker is None
    assert "choose the cell masks too" in widget.status.value
    # no pixel size and no width: where to enter one
    # (as the plugin's reader opens a TIFF that records none)
    viewer.layers["field"].metadata = {"modality": "fluorescence", "pixel_size_um": None}
    widget.cell_width_um.value = 0.0
    widget.run_button.native.click()
    assert widget.worker is None
    assert "no pixel size" in widget.status.value
    assert "in the 1 Recording tab" in widget.status.value
    assert "give the cells' width" in widget.status.value
    # a modality the image contradicts: where to set the right one (not the command's flag)
    viewer.layers["field"].metadata = {"pixel_size_um": 0.08, "modality": "phase"}
    widget.run_button.native.click()
    assert widget.worker is None
    assert "does not look like phase" in widget.status.value
    assert "Set its modality to fluorescence in the 1 Recording tab" in widget.status.value
    assert "--" not in widget.status.value
    # a trench is fitted with Auto-fit, not laid out as a field
    viewer.add_image(
        np.full((256, 40), 1000, np.uint16) + np.arange(40, dtype=np.uint16),
        name="trench",
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )
    widget.recording.value = viewer.layers["trench"]
    widget.run_button.native.click()
    assert widget.worker is None
    assert "mother-machine trench" in widget.status.value
    assert "Auto-fit" in widget.status.value
    assert calibrated_layer_name("trench") not in viewer.layers


def test_a_stain_in_the_envelope_is_fitted_and_drawn(make_napari_viewer, qtbot, real_data_dir):
    """A membrane-stained field (ColiCoords ds2, two cells of 00074) with 'stain in the
    cell envelope' ticked: the calibration puts the stain in the envelope, at an E. coli's
    width, and the dataset's settings draw it; in bright field the box is refused, named."""
    ds2 = real_data_dir / "colicoords" / "test_data" / "ds2"
    image = tifffile.imread(ds2 / "fluorescence" / "00074.tif")[60:220, 352:512]
    viewer, widget = _viewer_with(make_napari_viewer, image)
    assert not widget.envelope_stain.native.isHidden()  # a fluorescence recording's
    widget.envelope_stain.value = True
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=180_000)
    assert calibrated_layer_name("field") in viewer.layers, widget.status.value
    render = widget.calibration.settings.render
    assert render.envelope_stain_fraction > 0.8
    assert "stain in the envelope" in widget.report.value
    assert 0.9 < widget.calibration.settings.simulation.cell_width_um < 1.25
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    viewer.add_image(
        tifffile.imread(ds1 / "brightfield" / "00001.tif")[:256, :256],
        name="bright field",
        metadata={"pixel_size_um": 0.08, "modality": "brightfield"},
        **layer_axes(0.08, 2),
    )
    widget.recording.value = viewer.layers["bright field"]
    widget.run_button.native.click()
    assert widget.worker is None
    assert widget.status.value == (
        "Not calibrated: 'stain in the cell envelope (membrane dye)' is fitted in "
        "fluorescence; bright field is brightfield: untick it"
    )
    assert not widget.envelope_stain.native.isHidden()  # ticked: shown, to untick
    widget.envelope_stain.value = False
    widget.recording.value = viewer.layers["field"]
    widget.recording.value = viewer.layers["bright field"]
    assert widget.envelope_stain.native.isHidden()
    assert widget.depth.native.isHidden()


def test_cancel_adds_nothing(make_napari_viewer, qtbot, real_data_dir):
    """Cancelled during the fit of a whole field without masks (a minute or more of fit):
    the fit stops at its next render and no layer is added."""
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    image = tifffile.imread(ds1 / "fluorescence" / "00002.tif")
    viewer, widget = _viewer_with(make_napari_viewer, image)
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: "renders" in widget.status.value, timeout=120_000)
    widget.cancel_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.status.value == "Calibration cancelled: nothing added"
    assert calibrated_layer_name("field") not in viewer.layers
    assert widget.run_button.enabled


@pytest.mark.parametrize("masks_as", ["labels", "image"])
def test_a_cell_width_enters_the_pixel_size_for_every_layer(
    make_napari_viewer, qtbot, real_data_dir, notifications, masks_as
):
    """Found as a user: a PNG calibrated with a cell width stayed in pixels (no pixel size
    entered) beside its calibrated layers in micrometres, and napari warned "Inconsistent
    units across layers". The pixel size Calibrate derives is entered for the recording:
    the recording, its masks and the calibrated layers in micrometres, and the Recording
    form shows it. The masks too when napari's own reader opened them as an image (found
    as a user: they stayed in pixels and the recording shrank to a corner)."""
    from napari_symbac._widgets.workflow import WorkflowWidget

    viewer = make_napari_viewer()
    dock = WorkflowWidget(viewer)
    viewer.window.add_dock_widget(dock)
    colony = real_data_dir / "omnipose" / "Sample000033.png"
    dock.real_image.file.value = colony
    recording = viewer.layers["Sample000033"]
    masks = tifffile.imread(colony.with_name("Sample000033_cp_masks.tif")).astype(np.int32)
    add = viewer.add_labels if masks_as == "labels" else viewer.add_image
    add(masks, name="Sample000033 masks")
    widget = dock.calibrate
    assert widget.recording.value is recording
    assert widget.masks.value is viewer.layers["Sample000033 masks"]
    assert recording.metadata.get("pixel_size_um") is None
    widget.cell_width_um.value = 1.0
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=300_000)
    name = calibrated_layer_name("Sample000033")
    assert name in viewer.layers, widget.status.value
    px = widget.calibration.settings.microscope.pixel_size_um
    assert 0.08 < px < 0.2  # the colony's ~8-10 px wide cells at 1 um
    assert recording.metadata["pixel_size_um"] == px
    assert recording.metadata["microscope"].pixel_size_um == px
    assert f"Pixel size {px:.4g} um (from the cell width) entered" in widget.status.value
    for layer in (recording, viewer.layers["Sample000033 masks"], viewer.layers[name]):
        assert tuple(layer.scale[-2:]) == pytest.approx((px, px)), layer.name
        assert tuple(str(u) for u in layer.units[-2:]) == ("micrometer", "micrometer")
    assert dock.real_image.pixel_size.value == pytest.approx(px, abs=1e-3)
    assert dock.real_image.warning.visible is False
    viewer.screenshot(canvas_only=True)  # napari compares the layers' units as it draws
    assert not [m for m in notifications if "Inconsistent units" in m], notifications
    # the later steps follow the recording, now that it has its pixel size
    assert dock.simulate.recording.value is recording


def test_a_cell_width_that_contradicts_the_entered_pixel_size_is_refused(
    make_napari_viewer, real_data_dir
):
    """Found as a user: 0.065 um entered for an Omnipose colony, then a cell width of
    1 um: Calibrate ran at the 0.134 um the width gave and drew its layers at twice the
    recording's scale, without a word. Now the pair is refused, naming both fixes."""
    import imageio.v3 as iio

    colony = real_data_dir / "omnipose" / "Sample000033.png"
    image = np.asarray(iio.imread(colony))
    masks = tifffile.imread(colony.with_name("Sample000033_cp_masks.tif"))
    viewer, widget = _viewer_with(make_napari_viewer, image[..., 0], masks)
    viewer.layers["field"].metadata = {"pixel_size_um": 0.065, "modality": "phase"}
    widget.masks.value = viewer.layers["field masks"]
    widget.cell_width_um.value = 1.0
    widget.run_button.native.click()
    assert widget.worker is None
    status = widget.status.value
    assert "field has a pixel size of 0.065 um, and a cell width of 1 um makes it 0.1" in status
    assert "set the cell width to 0 to calibrate at 0.065 um" in status
    assert "enter 0.1336 um in the 1 Recording tab" in status
    assert status.endswith("if the cells are 1 um wide")
    assert calibrated_layer_name("field") not in viewer.layers


def test_calibrate_uses_the_camera_given_in_the_recording_step(make_napari_viewer, qtbot, field):
    """The camera given in the Recording step (layer metadata ``camera``) is the one
    calibrate uses, and the status says which camera the matched settings hold (found as
    a user: only the report said it)."""
    from napari_symbac.settings import Camera

    image, masks = field
    viewer, widget = _viewer_with(make_napari_viewer, image, masks)
    given = Camera(baseline_adu=0.0, sensitivity_adu_per_e=1.0, dark_noise_e=2.0)
    layer = viewer.layers["field"]
    layer.metadata = {**layer.metadata, "camera": given}
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=180_000)
    assert "with the camera given in the Recording step" in widget.status.value
    assert "camera: given: baseline 0.0 ADU, sensitivity 1 ADU/e-" in widget.report.value


def test_a_camera_the_recording_cannot_measure_is_said_so(make_napari_viewer, qtbot):
    """Found as a user: on ColiCoords' flattened bright-field crop the status said the
    matched settings hold "the camera measured from the recording" while the report said
    it could not be measured. The status says what the settings hold."""
    from pathlib import Path

    import napari_symbac

    folder = Path(napari_symbac.__file__).parent / "sample_data"
    image = tifffile.imread(folder / "colicoords_brightfield.tif")
    masks = tifffile.imread(folder / "colicoords_binary.tif")
    viewer, widget = _viewer_with(make_napari_viewer, image, masks)
    layer = viewer.layers["field"]
    layer.metadata = {**layer.metadata, "modality": "brightfield"}
    widget.run_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=180_000)
    assert "not measurable" in widget.report.value, widget.status.value
    assert "with its own pixel noise (the camera not measurable from the recording)" in (
        widget.status.value
    )
    assert "camera measured from the recording" not in widget.status.value
