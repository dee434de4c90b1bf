"""The step widgets follow the recording the user opened last."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets._recording import layer_axes
from napari_symbac._widgets.calibrate import CalibrateWidget
from napari_symbac._widgets.diagnose import DiagnoseWidget
from napari_symbac._widgets.simulate import SimulateWidget
from napari_symbac._widgets.tune import TuneWidget


def test_widgets_follow_the_recording_opened_last(make_napari_viewer):
    """Found as a user: with a trench opened (0.065 um) and then a colony PNG (no pixel
    size), Calibrate kept the trench chosen and refused it as a trench."""
    viewer = make_napari_viewer()
    rng = np.random.default_rng(0)
    trench = viewer.add_image(
        rng.uniform(900, 1100, (256, 46)).astype(np.uint16),
        name="trench",
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
        **layer_axes(0.065, 2),
    )
    masks = viewer.add_labels(np.zeros((256, 46), np.int32), name="trench masks")
    masks.data[100:120, 20:26] = 1
    calibrate, simulate = CalibrateWidget(viewer), SimulateWidget(viewer)
    diagnose, tune = DiagnoseWidget(viewer), TuneWidget(viewer)
    calibrate.masks.value = masks
    for combo in (calibrate.recording, simulate.recording, diagnose.reference, tune.reference):
        assert combo.value is trench
    # a PNG without a pixel size: Calibrate (which takes a cell width instead) follows it
    # at once, without the trench's masks; the others once its pixel size is entered
    colony = viewer.add_image(rng.uniform(0, 255, (300, 300)).astype(np.uint8), name="colony")
    assert calibrate.recording.value is colony
    assert calibrate.masks.value is None
    for combo in (simulate.recording, diagnose.reference, tune.reference):
        assert combo.value is trench
    colony.metadata = {"pixel_size_um": 0.07, "modality": "phase"}
    for combo in (calibrate.recording, simulate.recording, diagnose.reference, tune.reference):
        assert combo.value is colony
    # a layer Simulate makes is no recording: nothing follows it
    viewer.add_image(
        np.zeros((2, 256, 46), np.uint16), name="synthetic", metadata={"symbac": {}}
    )
    for combo in (calibrate.recording, simulate.recording, diagnose.reference, tune.reference):
        assert combo.value is colony


def test_a_running_step_keeps_its_recording(make_napari_viewer, qtbot, real_data_dir):
    """Found as a user: a ColiCoords field opened while Calibrate ran on another became
    Calibrate's recording, above the status and report of the first. A running step
    keeps its recording; once it has finished, it follows the newest again."""
    import tifffile

    viewer = make_napari_viewer()
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    axes = layer_axes(0.08, 2)
    first = viewer.add_image(
        tifffile.imread(ds1 / "fluorescence" / "00001.tif")[:256, :256], name="first",
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"}, **axes,
    )  # fmt: skip
    masks = tifffile.imread(ds1 / "binary" / "00001_Probabilities_filtered.tif")[:256, :256]
    viewer.add_labels(masks.astype(np.int32), name="first masks", **axes)
    calibrate = CalibrateWidget(viewer)
    assert calibrate.recording.value is first
    calibrate.run_button.native.click()
    assert calibrate.worker is not None
    second = viewer.add_image(
        tifffile.imread(ds1 / "fluorescence" / "00002.tif")[:256, :256], name="second",
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"}, **axes,
    )  # fmt: skip
    assert calibrate.recording.value is first
    qtbot.waitUntil(lambda: calibrate.worker is None, timeout=180_000)
    assert "synthetic (calibrated to first)" in viewer.layers, calibrate.status.value
    assert calibrate.recording.value is first  # what the report beside it is about
    third = viewer.add_image(
        np.asarray(second.data), name="third",
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"}, **axes,
    )  # fmt: skip
    assert calibrate.recording.value is third


def test_masks_opened_as_an_image_are_masks_not_a_recording(make_napari_viewer, real_data_dir):
    """Found as a user: Sample000033's masks TIFF opened with napari's own reader (an
    image layer) became Calibrate's recording, with no masks chosen. An image that holds
    masks (integers, a background of 0, one patch per id) is offered as cell masks and
    never as a recording; the colony PNG stays the recording."""
    import tifffile

    from napari_symbac.io import read_image

    viewer = make_napari_viewer()
    folder = real_data_dir / "omnipose"
    colony = viewer.add_image(read_image(folder / "Sample000033.png").data, name="colony")
    calibrate, tune = CalibrateWidget(viewer), TuneWidget(viewer)
    assert calibrate.recording.value is colony
    masks = viewer.add_image(tifffile.imread(folder / "Sample000033_cp_masks.tif"), name="m")
    assert masks.__class__.__name__ == "Image"
    assert calibrate.recording.value is colony
    assert masks not in calibrate.recording.choices
    assert calibrate.masks.value is masks
    assert masks in tune.masks.choices
    assert masks not in tune.reference.choices
    # the answer is kept per data array: new data in the layer is looked at again
    masks.data = np.asarray(colony.data)
    calibrate.recording.reset_choices()
    assert masks in calibrate.recording.choices
