"""The plugin as napari sees it: manifest, dock widgets, sample data."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")


def test_manifest_is_valid_and_imports():
    from npe2 import PluginManifest

    manifest = PluginManifest.from_distribution("napari-symbac")
    manifest.validate_imports()
    ids = {command.id for command in manifest.contributions.commands}
    assert all(command_id.startswith("napari-symbac.") for command_id in ids)
    assert manifest.contributions.widgets
    assert manifest.contributions.sample_data


def test_widget_docks_and_sample_opens(make_napari_viewer):
    viewer = make_napari_viewer()
    _dock, widget = viewer.window.add_plugin_dock_widget("napari-symbac", "Simulate and render")
    assert widget.run_button.enabled
    viewer.open_sample("napari-symbac", "trench")
    image = viewer.layers["synthetic trench"]
    labels = viewer.layers["synthetic trench labels"]
    assert image.data.ndim == 3
    assert image.data.shape == labels.data.shape
    assert image.data.dtype == np.uint16
    # Every frame has cells, and cells are darker than the media around them in the trench.
    centre = image.data.shape[2] // 2
    for frame, mask in zip(image.data, labels.data):
        assert mask.max() > 0
        trench_media = np.zeros(mask.shape, bool)
        trench_media[20:, centre - 3 : centre + 4] = True  # below the closed-end margin
        trench_media &= mask == 0
        assert frame[mask > 0].mean() < frame[trench_media].mean()


def test_save_layers_as_dataset_through_napari(make_napari_viewer, tmp_path):
    import tifffile

    viewer = make_napari_viewer()
    viewer.open_sample("napari-symbac", "trench")
    viewer.layers.selection = set(viewer.layers)
    written = viewer.layers.save(str(tmp_path / "ds"), selected=True, plugin="napari-symbac")
    assert written
    images = sorted((tmp_path / "ds" / "tiff" / "train" / "images").glob("*.tif"))
    masks = sorted((tmp_path / "ds" / "omnipose" / "train").glob("*_masks.tif"))
    n_frames = viewer.layers["synthetic trench"].data.shape[0]
    assert len(images) == len(masks) == n_frames
    np.testing.assert_array_equal(
        tifffile.imread(masks[0]), viewer.layers["synthetic trench labels"].data[0]
    )


def test_real_sample_field_opens(make_napari_viewer):
    viewer = make_napari_viewer()
    viewer.open_sample("napari-symbac", "colicoords")
    brightfield = viewer.layers["ColiCoords brightfield"]
    cells = viewer.layers["ColiCoords cells"]
    assert brightfield.data.shape == cells.data.shape == (512, 512)
    assert brightfield.scale[-1] == pytest.approx(0.08)
    assert cells.data.max() >= 5  # several labelled cells
