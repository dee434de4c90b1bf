"""Slider latency in a fresh process (``python -m napari_symbac.bench.gui_child``).

A napari viewer (Qt offscreen, not shown) with the Simulate and Tune widgets on a
256 x 46 trench: the median seconds from setting the cell-intensity slider to the
preview layer holding the new image, the layer refresh alone, and the FFT floor of the
render frame. Prints one JSON line.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time


def run(repeats: int) -> dict[str, float]:
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    import numpy as np
    from qtpy.QtWidgets import QApplication

    import napari
    from napari_symbac._widgets.simulate import RESULT_IMAGE_LAYER, SimulateWidget
    from napari_symbac._widgets.tune import TuneWidget
    from napari_symbac.bench.timing import fft_floor_s
    from napari_symbac.settings import PipelineSettings, TrenchGeometry

    base = PipelineSettings()
    settings = dataclasses.replace(
        base,
        simulation=dataclasses.replace(
            base.simulation, n_frames=20, trench=TrenchGeometry(length_um=15.84)
        ),
    )
    viewer = napari.Viewer(show=False)
    try:
        simulate = SimulateWidget(viewer, settings)
        tune = TuneWidget(viewer)
        simulate.run()
        while simulate.worker is not None:  # the simulation runs in a worker thread
            QApplication.processEvents()
            time.sleep(0.005)
        layer = viewer.layers[RESULT_IMAGE_LAYER]
        index = tune._current_frame()
        latency, refresh = [], []
        for value in np.linspace(1000.0, 1800.0, repeats + 1)[1:]:
            before = layer.data[index].copy()
            start = time.perf_counter()
            tune.sliders["cell_intensity"].value = float(value)
            latency.append(time.perf_counter() - start)
            if np.array_equal(before, layer.data[index]):
                raise RuntimeError("the slider change did not reach the layer")
            start = time.perf_counter()
            layer.refresh()
            refresh.append(time.perf_counter() - start)
        scene = tune.preview.scene(index)
        kernel = np.asarray(tune.preview.model.kernel(), np.float32)
        return {
            "slider_s": float(np.median(latency)),
            "refresh_s": float(np.median(refresh)),
            "fft_s": fft_floor_s(scene.shape, kernel),
        }
    finally:
        viewer.close()


def main() -> None:
    import sys

    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 30
    print(json.dumps(run(repeats)))


if __name__ == "__main__":
    main()
