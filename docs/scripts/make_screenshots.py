"""Screenshots of the real napari window with napari-symbac's widgets docked.

Run under a virtual display (Debian: ``apt-get install xvfb``)::

    xvfb-run -a -s "-screen 0 1600x1000x24" python docs/scripts/make_screenshots.py

Writes ``docs/images/napari-*.png`` and the demo montage ``docs/images/demo-preview.png``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "xcb")

import imageio.v3 as iio
import numpy as np
from qtpy.QtWidgets import QApplication

import napari
from napari_symbac.fit import CLASS_VALUES

IMAGES = Path(__file__).resolve().parents[1] / "images"
PLUGIN = "napari-symbac"


def wait_for(condition, timeout_s: float = 300.0) -> None:
    start = time.perf_counter()
    while not condition():
        QApplication.processEvents()
        time.sleep(0.02)
        if time.perf_counter() - start > timeout_s:
            raise TimeoutError("the widget did not finish in time")


def shot(viewer: napari.Viewer, name: str) -> None:
    for _ in range(20):
        QApplication.processEvents()
        time.sleep(0.02)
    viewer.screenshot(str(IMAGES / name), canvas_only=False, flash=False)
    print("wrote", IMAGES / name)


def simulate_and_tune() -> None:
    viewer = napari.Viewer(title="napari-symbac")
    viewer.window._qt_window.resize(1500, 950)
    _, simulate = viewer.window.add_plugin_dock_widget(PLUGIN, "Simulate and render")
    _, tune = viewer.window.add_plugin_dock_widget(PLUGIN, "Tune optics and noise")
    simulate.form.n_frames.value = 30
    simulate.run_button.native.click()
    wait_for(lambda: simulate.worker is None and simulate.series is not None)
    viewer.dims.set_current_step(0, 29)
    viewer.layers["synthetic labels"].contour = 1
    viewer.reset_view()
    tune.sliders["ring_contrast"].value = 0.8
    shot(viewer, "napari-simulate-tune.png")
    viewer.close()


def paint_real_image() -> None:
    viewer = napari.Viewer(title="napari-symbac")
    viewer.window._qt_window.resize(1500, 950)
    viewer.open_sample(PLUGIN, "colicoords")
    cells = viewer.layers["ColiCoords cells"].data
    viewer.layers.remove("ColiCoords cells")
    _, real = viewer.window.add_plugin_dock_widget(PLUGIN, "Real image and classes")
    real.image.value = viewer.layers["ColiCoords brightfield"]
    real.paint_button.native.click()
    labels = viewer.layers["ColiCoords brightfield classes"]
    # Rough strokes as a user paints them: a dab in each cell, dabs of media between.
    from scipy import ndimage

    for region in ndimage.find_objects(cells):
        if region is not None:
            centre = tuple((s.start + s.stop) // 2 for s in region)
            labels.paint(centre, CLASS_VALUES["cell"], refresh=False)
    far = ndimage.distance_transform_edt(cells == 0) > 25
    rows, cols = np.nonzero(far[::40, ::40])
    for row, col in zip(rows * 40, cols * 40):
        labels.paint((row, col), CLASS_VALUES["media"], refresh=False)
    labels.refresh()
    real.measure_button.native.click()
    shot(viewer, "napari-real-image.png")
    viewer.close()


def export_widget() -> None:
    viewer = napari.Viewer(title="napari-symbac")
    viewer.window._qt_window.resize(1500, 950)
    viewer.open_sample(PLUGIN, "trench")
    viewer.window.add_plugin_dock_widget(PLUGIN, "Export dataset")
    viewer.reset_view()
    shot(viewer, "napari-export.png")
    viewer.close()


def demo_montage() -> None:
    import tempfile

    from napari_symbac.demo import run_demo

    with tempfile.TemporaryDirectory() as folder:
        print(run_demo(folder, n_frames=40, seed=0))
        montage = iio.imread(Path(folder) / "preview.png")
    iio.imwrite(IMAGES / "demo-preview.png", montage)
    print("wrote", IMAGES / "demo-preview.png")


if __name__ == "__main__":
    IMAGES.mkdir(parents=True, exist_ok=True)
    demo_montage()
    simulate_and_tune()
    paint_real_image()
    export_widget()
