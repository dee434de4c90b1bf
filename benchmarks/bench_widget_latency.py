"""Latency from a tuning slider's value change to the preview layer's data update.

A 256 x 46 camera-pixel trench (3x upsampling, PSF radius 50). The reference is one
``scipy.fft.rfft2`` of the render-resolution frame, timed in the same run; the issue's
goal is the cached re-render bound (3 x that FFT) plus the layer refresh.

Run under a display or Xvfb::

    xvfb-run -a python benchmarks/bench_widget_latency.py
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import time

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import numpy as np
import scipy.fft
from qtpy.QtWidgets import QApplication

import napari
from napari_symbac._widgets.simulate import RESULT_IMAGE_LAYER, SimulateWidget
from napari_symbac._widgets.tune import TuneWidget
from napari_symbac.settings import PipelineSettings, TrenchGeometry

REPEATS = 30


def median_ms(samples: list[float]) -> float:
    return 1000 * statistics.median(samples)


def main() -> None:
    base = PipelineSettings()
    settings = dataclasses.replace(
        base,
        simulation=dataclasses.replace(
            base.simulation, n_frames=20, trench=TrenchGeometry(length_um=15.84)
        ),
    )
    viewer = napari.Viewer(show=False)
    simulate = SimulateWidget(viewer, settings)
    tune = TuneWidget(viewer)
    simulate.run()
    while simulate.worker is not None:
        QApplication.processEvents()
        time.sleep(0.01)
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    print(f"frame: {layer.data.shape[1]} x {layer.data.shape[2]} camera pixels")

    scene = tune.preview.scene(tune._current_frame())
    frame = np.asarray(scene.cells, np.float32)
    fft = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        scipy.fft.rfft2(frame)
        fft.append(time.perf_counter() - start)

    def drag(name: str, values: np.ndarray) -> list[float]:
        samples = []
        for value in values:
            before = layer.data[tune._current_frame()].copy()
            start = time.perf_counter()
            tune.sliders[name].value = float(value)
            samples.append(time.perf_counter() - start)
            assert not np.array_equal(before, layer.data[tune._current_frame()])
        return samples

    intensity = drag("cell_intensity", np.linspace(1000, 1800, REPEATS))
    tune.sliders["defocus_sigma_um"].value = 0.0
    defocus = drag("defocus_sigma_um", np.linspace(0.02, 0.3, REPEATS))

    index = tune._current_frame()
    render, refresh = [], []
    for _ in range(REPEATS):
        start = time.perf_counter()
        tune.preview.frame(index)
        render.append(time.perf_counter() - start)
        start = time.perf_counter()
        layer.refresh()
        refresh.append(time.perf_counter() - start)

    fft_ms = median_ms(fft)
    rows = [
        ("rfft2 of the render frame", fft_ms),
        ("cached re-render (LivePreview.frame)", median_ms(render)),
        ("layer refresh", median_ms(refresh)),
        ("slider -> layer: intensity (cached)", median_ms(intensity)),
        ("slider -> layer: defocus (re-convolve)", median_ms(defocus)),
    ]
    print(f"{'step':<42} {'median ms':>10} {'x rfft2':>8}")
    for name, ms in rows:
        print(f"{name:<42} {ms:10.2f} {ms / fft_ms:8.1f}")
    print(f"goal: cached change within 3 x rfft2 + layer refresh ({3 * fft_ms:.2f} ms + refresh)")
    viewer.close()


if __name__ == "__main__":
    main()
