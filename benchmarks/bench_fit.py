"""Time to fit a 256 x 46 trench, as ratios to one plain FFT convolution.

Run: ``python benchmarks/bench_fit.py``. The reference is ``scipy.signal.fftconvolve``
of one render-resolution frame (upsample 3 plus the PSF border) with the phase kernel,
timed in the same run, so the ratios travel between machines. Prints a table; asserts
nothing.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import signal

from napari_symbac.fit import fit_parameters, fit_scene, scene_classes
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

PIXEL_UM = 0.065
TRENCH = TrenchGeometry(length_um=256 * PIXEL_UM - 0.75, width_um=1.5, margin_um=0.75)
TRUTH = RenderSettings(apodisation_sigma_um=0.6, defocus_sigma_um=0.15, psf_offset=0.05)
START = RenderSettings(
    cell_intensity=1700.0,
    media_intensity=2100.0,
    apodisation_sigma_um=1.0,
    defocus_sigma_um=0.05,
    psf_offset=0.0,
)


def _cells() -> FrameCells:
    y = np.array([1.3, 3.9, 6.5, 9.0, 11.6, 14.2])
    n = y.size
    return FrameCells(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, 0.75) + 0.02 * np.sin(np.arange(n)),
        y_um=y,
        angle_rad=0.05 * np.cos(np.arange(n)),
        length_um=np.array([2.3, 2.6, 2.2, 2.4, 2.5, 2.3]),
        width_um=np.full(n, 0.95),
    )


def _best_of(func, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    microscope, camera = Microscope(pixel_size_um=PIXEL_UM), Camera()
    scene = draw_scene(_cells(), TRENCH, microscope, TRUTH)
    model = ForwardModel(microscope, TRUTH, camera)
    image = model.render(scene, np.random.default_rng(0))
    frame = np.asarray(scene.cells, np.float32)
    kernel = model.kernel()
    reference = _best_of(lambda: signal.fftconvolve(frame, kernel, mode="valid"), 20)
    rows = [("plain FFT convolution (reference)", reference, None)]
    classes = scene_classes(scene)
    for label, kwargs in (
        ("fit_parameters, pixel term (true scene)", {"terms": ("pixel",)}),
        ("fit_parameters, statistics terms", {}),
    ):
        start = time.perf_counter()
        result = fit_parameters(image, classes, scene, microscope, START, camera, **kwargs)
        rows.append((label, time.perf_counter() - start, result.n_evaluations))
    start = time.perf_counter()
    fitted = fit_scene(image, microscope, START, camera)
    rows.append(
        (
            "fit_scene (cells, curvature, trench, optics)",
            time.perf_counter() - start,
            fitted.n_evaluations,
        )
    )
    print(f"256 x 46 trench, render frame {frame.shape}, kernel {kernel.shape}\n")
    print(f"| {'step':<42} | {'seconds':>8} | {'x FFT':>8} | {'renders':>7} |")
    print(f"|{'-' * 44}|{'-' * 10}|{'-' * 10}|{'-' * 9}|")
    for label, seconds, renders in rows:
        n = "" if renders is None else str(renders)
        print(f"| {label:<42} | {seconds:8.3f} | {seconds / reference:8.0f} | {n:>7} |")


if __name__ == "__main__":
    main()
