"""Screenshots of the real napari window with napari-symbac's widgets docked.

Run under a virtual display (Debian: ``apt-get install xvfb``)::

    xvfb-run -a -s "-screen 0 1366x768x24" python docs/scripts/make_screenshots.py [--napari-only]

Writes ``docs/images/napari-*.png`` (the flow of docs/gui.md on the real SyMBac trench,
Diagnose included, a phase colony fitted from its masks and one calibrated, read from
``../shared/data/real`` or ``$NAPARI_SYMBAC_REAL_DATA``, in a 1366 x 768 window) and the
demo montage
``docs/images/demo-preview.png``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from _args import checked_real_data, real_data_from_environment, script_parser

os.environ.setdefault("QT_QPA_PLATFORM", "xcb")

import imageio.v3 as iio
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


def dismiss_notifications(viewer: napari.Viewer) -> None:
    """Close the notification toasts (they would stay on the later screenshots)."""
    from napari._qt.dialogs.qt_notification import NapariQtNotification

    for toast in viewer.window._qt_window.findChildren(NapariQtNotification):
        toast.close()


def shot(viewer: napari.Viewer, name: str) -> None:
    for _ in range(20):
        QApplication.processEvents()
        time.sleep(0.02)
    viewer.screenshot(str(IMAGES / name), canvas_only=False, flash=False)
    print("wrote", IMAGES / name)


#: A laptop screen: the layout must fit it (issue 12).
WINDOW = (1366, 768)


def workflow_window() -> tuple[napari.Viewer, object]:
    """A napari window of :data:`WINDOW`'s size with the workflow dock, and the dock."""
    viewer = napari.Viewer(title="napari-symbac")
    viewer.window._qt_window.resize(*WINDOW)
    _, flow = viewer.window.add_plugin_dock_widget(PLUGIN, "SyMBac workflow (all steps)")
    return viewer, flow


def real_trench_flow(folder: Path) -> None:
    """The flow of docs/gui.md on the real SyMBac trench, one screenshot per tab."""
    import tifffile

    from napari_symbac._widgets.real_image import class_layer_name

    source = tifffile.imread(real_data_from_environment() / "ecoli_100x_oil_exponential.tiff")
    path = folder / "my_trench.tif"
    tifffile.imwrite(path, source)  # written without a pixel size, as many recordings are

    viewer, flow = workflow_window()
    flow.real_image.file.value = path
    shot(viewer, "napari-recording-no-pixel-size.png")
    dismiss_notifications(viewer)
    flow.real_image.pixel_size.value = 0.065
    flow.real_image.paint_button.native.click()
    labels = viewer.layers[class_layer_name("my_trench")]
    for row in range(40, 240, 8):
        labels.paint((row, 22), CLASS_VALUES["cell"], refresh=False)
        labels.paint((row, 12), CLASS_VALUES["media"], refresh=False)
        labels.paint((row, 2), CLASS_VALUES["device"], refresh=False)
        labels.paint((row, 43), CLASS_VALUES["device"], refresh=False)
    labels.refresh()
    flow.real_image.measure_button.native.click()
    shot(viewer, "napari-real-image.png")

    flow.setCurrentIndex(1)
    flow.simulate.form.n_frames.value = 100
    flow.simulate.run_button.native.click()
    wait_for(lambda: flow.simulate.worker is None and flow.simulate.series is not None)
    viewer.dims.set_current_step(0, 99)
    labels.visible = False
    # real and synthetic side by side, in micrometres
    viewer.layers["synthetic"].translate = (0, 0, 4.0)
    viewer.layers["synthetic labels"].translate = (0, 0, 4.0)
    viewer.reset_view()
    shot(viewer, "napari-simulate.png")

    flow.setCurrentIndex(2)
    flow.tune.reference.value = viewer.layers["my_trench"]
    flow.tune.fit_iterations.value = 10
    flow.tune.fit_button.native.click()
    wait_for(lambda: flow.tune.fit_worker is None)
    print(flow.tune.status.value)
    fitted = viewer.layers["auto-fit synthetic"]
    fitted.translate = (0, 8.0)
    viewer.reset_view()
    flow.tune.native.parent().parent().verticalScrollBar().setValue(10_000)
    shot(viewer, "napari-simulate-tune.png")

    flow.setCurrentIndex(flow.indexOf(flow.diagnose.native.parent().parent()))
    flow.diagnose.reference.value = viewer.layers["my_trench"]
    flow.diagnose.run_button.native.click()
    wait_for(lambda: flow.diagnose.worker is None, timeout_s=1200.0)
    print(flow.diagnose.status.value)
    dismiss_notifications(viewer)
    for layer in viewer.layers:
        layer.visible = layer.name in ("my_trench", "diagnosis residual")
    viewer.layers["diagnosis residual"].translate = (0, 4.0)
    viewer.reset_view()
    shot(viewer, "napari-diagnose.png")

    flow.setCurrentIndex(flow.indexOf(flow.export.native.parent().parent()))
    flow.export.folder.value = folder / "dataset"
    flow.export.n_items.value = 20
    flow.export.export_button.native.click()
    wait_for(lambda: flow.export.worker is None)
    print(flow.export.status.value)
    shot(viewer, "napari-export.png")
    viewer.close()


def colony_flow() -> None:
    """A phase colony (Omnipose Sample000033, a PNG without pixel size) opened from the
    Recording tab, its masks as a labels layer, fitted by Auto-fit from them."""
    import tifffile

    root = real_data_from_environment() / "omnipose"
    viewer, flow = workflow_window()
    flow.real_image.file.value = root / "Sample000033.png"
    dismiss_notifications(viewer)
    flow.real_image.pixel_size.value = 0.134  # a 1 um cell width (docs/rendering.md)
    flow.setCurrentIndex(1)
    flow.simulate.form.geometry.value = "agar_pad"
    flow.simulate.form.n_frames.value = 30
    flow.simulate.run_button.native.click()
    wait_for(lambda: flow.simulate.worker is None and flow.simulate.series is not None)
    real = viewer.layers["Sample000033"]
    masks = viewer.add_labels(  # in pixels, as its file: placed over the recording
        tifffile.imread(root / "Sample000033_cp_masks.tif"),
        name="Sample000033 masks",
    )
    flow.setCurrentIndex(2)
    flow.tune.reference.value = real
    flow.tune.masks.value = masks
    flow.tune.fit_button.native.click()
    wait_for(lambda: flow.tune.fit_worker is None)
    print(flow.tune.status.value)
    dismiss_notifications(viewer)
    masks.visible = False
    for name in ("synthetic", "synthetic labels"):
        viewer.layers[name].visible = False
    viewer.layers["auto-fit synthetic"].translate = (0, 377 * 0.134 + 2.0)
    viewer.reset_view()
    viewer.camera.center = (0, 287 * 0.134 / 2, 377 * 0.134 + 1.0)
    viewer.camera.zoom = 320 / (2 * 377 * 0.134 + 2.0)  # both images across the canvas
    shot(viewer, "napari-colony-fit.png")
    viewer.close()


def calibrate_flow() -> None:
    """A phase colony (Omnipose Sample000193, a PNG without pixel size) and its masks
    calibrated in the Calibrate tab with a 1 um cell width; item 0 of the matched dataset
    placed beside the recording."""
    import tifffile

    root = real_data_from_environment() / "omnipose"
    viewer, flow = workflow_window()
    flow.real_image.file.value = root / "Sample000193.png"
    dismiss_notifications(viewer)
    viewer.add_labels(
        tifffile.imread(root / "Sample000193_cp_masks.tif"), name="Sample000193 masks"
    )
    flow.setCurrentIndex(4)
    flow.calibrate.cell_width_um.value = 1.0
    flow.calibrate.run_button.native.click()
    wait_for(lambda: flow.calibrate.worker is None)
    print(flow.calibrate.status.value)
    dismiss_notifications(viewer)
    name = "synthetic (calibrated to Sample000193)"
    recording = viewer.layers["Sample000193"]  # in um: the pixel size the width gave
    beside = (recording.data.shape[-1] + 20) * float(recording.scale[-1])
    viewer.layers["Sample000193 masks"].visible = False
    viewer.layers[name].translate = (0, beside)
    viewer.layers[f"{name} masks"].translate = (0, beside)
    viewer.layers[f"{name} masks"].visible = False
    viewer.reset_view()
    shot(viewer, "napari-calibrate.png")
    viewer.close()


def demo_montage() -> None:
    import tempfile

    from napari_symbac.demo import run_demo

    with tempfile.TemporaryDirectory() as folder:
        print(run_demo(folder, n_frames=40, seed=0))
        montage = iio.imread(Path(folder) / "preview.png")
    iio.imwrite(IMAGES / "demo-preview.png", montage)
    print("wrote", IMAGES / "demo-preview.png")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``[--napari-only]``; the real recordings are read from
    ``$NAPARI_SYMBAC_REAL_DATA``, else ``../shared/data/real``."""
    parser = script_parser(__doc__)
    parser.add_argument(
        "--napari-only",
        action="store_true",
        help="only the napari windows' screenshots, not the demo montage",
    )
    parser.add_argument(
        "--calibrate-only",
        action="store_true",
        help="only the Calibrate tab's screenshot (napari-calibrate.png)",
    )
    args = parser.parse_args(argv)
    checked_real_data(
        parser,
        real_data_from_environment(),
        "ecoli_100x_oil_exponential.tiff and omnipose",
        given="environment",
    )
    return args


if __name__ == "__main__":
    import tempfile

    args = parse_args()
    IMAGES.mkdir(parents=True, exist_ok=True)
    if not args.calibrate_only:
        if not args.napari_only:
            demo_montage()
        with tempfile.TemporaryDirectory() as tmp:
            real_trench_flow(Path(tmp))
        colony_flow()
    calibrate_flow()
