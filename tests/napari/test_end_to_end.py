"""From a real recording with no pixel size to an exported dataset that resembles it.

The whole GUI path a user takes, in the workflow dock: open the SyMBac trench (written
without resolution tags) -> set the pixel size -> paint classes -> measure -> simulate
-> Auto-fit -> export; then the exported images are compared with the recording.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets.real_image import class_layer_name
from napari_symbac._widgets.simulate import RESULT_LABELS_LAYER
from napari_symbac._widgets.workflow import WorkflowWidget
from napari_symbac.fit import CLASS_VALUES

PIXEL_UM = 0.065
N_FRAMES = 60
#: Generous: a wait ends as soon as its condition holds; on 2 loaded cores the slowest
#: step (60 frames simulated and rendered) has taken ~60 s.
WAIT_MS = 900_000


def _paint_strokes(labels) -> None:
    """Rough strokes as a user paints them: down the cells' middle, along the bright
    media beside the cells inside the trench, and on the PDMS at both sides."""
    for row in range(40, 240, 8):
        labels.paint((row, 22), CLASS_VALUES["cell"], refresh=False)
        labels.paint((row, 12), CLASS_VALUES["media"], refresh=False)
        labels.paint((row, 2), CLASS_VALUES["device"], refresh=False)
        labels.paint((row, 43), CLASS_VALUES["device"], refresh=False)
    labels.refresh()


@pytest.mark.slow
def test_real_recording_to_matched_dataset(make_napari_viewer, qtbot, tmp_path, real_data_dir):
    source = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    path = tmp_path / "my_trench.tif"
    tifffile.imwrite(path, source)  # no resolution tags: the pixel size must be asked for
    viewer = make_napari_viewer()
    flow = WorkflowWidget(viewer)
    viewer.window.add_dock_widget(flow)

    # 1 your recording: open it, see the warning, give the pixel size
    flow.real_image.file.value = path
    real = viewer.layers["my_trench"]
    assert "no pixel size" in flow.real_image.warning.value
    flow.real_image.pixel_size.value = PIXEL_UM
    assert real.metadata["pixel_size_um"] == PIXEL_UM
    assert tuple(real.scale) == (PIXEL_UM, PIXEL_UM)
    flow.real_image.paint_button.native.click()
    _paint_strokes(viewer.layers[class_layer_name("my_trench")])
    flow.real_image.measure_button.native.click()
    stats = flow.real_image.statistics
    assert stats["cell"].mean < stats["media"].mean  # phase contrast: dark cells

    # 2 simulate with the recording's microscope (60 frames: the trench fills with cells)
    assert flow.simulate.recording.value is real
    flow.simulate.form.n_frames.value = N_FRAMES
    flow.simulate.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in viewer.layers, timeout=WAIT_MS)
    qtbot.waitUntil(lambda: flow.simulate.worker is None, timeout=WAIT_MS)
    assert flow.simulate.pipeline.microscope.pixel_size_um == PIXEL_UM

    # 3 Auto-fit the scene to the recording
    assert flow.tune.reference.value is real  # your recording, chosen for you
    flow.tune.fit_iterations.value = 3
    flow.tune.fit_button.native.click()
    qtbot.waitUntil(lambda: flow.tune.fit_worker is None, timeout=WAIT_MS)
    fit = flow.tune.fit_result
    assert fit is not None, flow.tune.status.value
    assert fit.objective_after < fit.objective_before
    # its layers are outputs, never a recording (found as a user: Calibrate chose "auto-fit
    # residual" as its recording, the newest image, and refused its negative values)
    fitted_layers = {"auto-fit synthetic", "auto-fit residual"}
    assert fitted_layers <= {layer.name for layer in viewer.layers}
    for combo in (flow.calibrate.recording, flow.tune.reference, flow.simulate.recording):
        combo.reset_choices()
        assert not fitted_layers & {c.name for c in combo.choices if c is not None}
    assert flow.calibrate.recording.value is real

    # 4 export with the tuned settings (the newest rendered layer, chosen for you)
    flow.export.n_items.value = 4
    flow.export.val_fraction.value = 0.0
    flow.export.formats.value = ["tiff"]
    flow.export.folder.value = tmp_path / "dataset"
    flow.export.export_button.native.click()
    qtbot.waitUntil(lambda: flow.export.worker is None, timeout=WAIT_MS)
    assert flow.export.report is not None, flow.export.status.value
    assert flow.export.report.complete

    # the dataset resembles the recording
    out = tmp_path / "dataset"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"]["pipeline"]["microscope"]["pixel_size_um"] == PIXEL_UM
    images = sorted((out / "tiff" / "train" / "images").glob("*.tif"))
    masks = sorted((out / "tiff" / "train" / "labels").glob("*.tif"))
    assert len(images) == len(masks) == 4
    # Like with like: the cell class is the pixels >= 5 px (0.33 um) inside a cell, the
    # media beside the cells the pixels 2-4 px outside one, in the exported images with
    # their masks and in the recording with the cells Auto-fit found in it. (The painted
    # media strokes lie in the brightest media, between cells: a trench packed with
    # cells as long as the recording's has fewer such gaps, and its ring of media
    # beside the cells was 11 % below them while 6 % from the recording's own ring.)
    from scipy import ndimage

    def classes(image, cells):
        inside = ndimage.distance_transform_edt(cells)
        outside = ndimage.distance_transform_edt(~cells)
        return image[inside >= 5], image[(outside >= 2) & (outside <= 4)]

    cell_pixels, media_pixels = [], []
    for image_path, mask_path in zip(images, masks):
        image = tifffile.imread(image_path).astype(float)
        assert image.ndim == 2
        cell, media = classes(image, tifffile.imread(mask_path) > 0)
        cell_pixels.append(cell)
        media_pixels.append(media)
    cell_mean = np.concatenate(cell_pixels).mean()
    media_mean = np.concatenate(media_pixels).mean()
    real_frame = np.asarray(real.data, float)
    real_frame = real_frame[0] if real_frame.ndim == 3 else real_frame
    real_cell, real_media = (
        float(c.mean()) for c in classes(real_frame, fit.scene.camera_labels() > 0)
    )
    print(
        f"exported cell {cell_mean:.0f} media {media_mean:.0f}; recording with its fitted "
        f"cells: cell {real_cell:.0f} media {real_media:.0f}; painted strokes: cell "
        f"{stats['cell'].mean:.0f} media {stats['media'].mean:.0f}"
    )
    assert cell_mean < media_mean  # same polarity as the recording
    assert cell_mean == pytest.approx(real_cell, rel=0.10)
    assert media_mean == pytest.approx(real_media, rel=0.10)
    assert cell_mean == pytest.approx(stats["cell"].mean, rel=0.10)  # the painted cells
