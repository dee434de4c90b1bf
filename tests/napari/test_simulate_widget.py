"""Drive the Simulate widget as a user would: run to completion, and cancel midway."""

from __future__ import annotations

import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets.simulate import (
    PREVIEW_LAYER,
    RESULT_IMAGE_LAYER,
    RESULT_LABELS_LAYER,
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
    assert widget.run_button.enabled


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
