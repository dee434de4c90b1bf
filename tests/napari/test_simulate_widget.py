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
