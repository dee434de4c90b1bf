"""Time to fit a 256 x 46 trench and open fields of growing cell count.

Run: ``python benchmarks/bench_fit.py [--large]``. The reference is
``scipy.signal.fftconvolve`` of one render-resolution frame (upsample 3 plus the PSF
border) with the phase kernel, timed in the same run, so the ratios travel between
machines. The second table is the cost of :func:`fit_scene` against the number of
cells (fluorescence, open 256 x 256 field at 80 nm, camera estimated; ``--large``
adds a 512 x 512 field with 100 cells). The real trench (``../shared/data/real``,
or ``NAPARI_SYMBAC_REAL_DATA``) is timed when present. Prints tables; asserts
nothing.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import signal

from napari_symbac.fit import fit_parameters, fit_scene, scene_classes
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import Field, draw_scene
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
            f"fit_scene, synthetic (chi2 {fitted.objective_after:.2f})",
            time.perf_counter() - start,
            fitted.n_evaluations,
        )
    )
    real = _real_trench()
    if real is not None:
        start = time.perf_counter()
        fitted = fit_scene(real, microscope, RenderSettings(), None, closed_end="round")
        rows.append(
            (
                f"fit_scene, real trench ({len(fitted.cells)} cells, chi2 "
                f"{fitted.objective_after:.2f})",
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
    print("\nfit_scene against the number of cells (fluorescence, open field, camera estimated)\n")
    print(f"| {'field':<10} | {'cells':>5} | {'found':>5} | {'seconds':>8} | {'chi2':>6} |")
    print(f"|{'-' * 12}|{'-' * 7}|{'-' * 7}|{'-' * 10}|{'-' * 8}|")
    sizes = [(256, 4), (256, 16), (256, 36)]
    if "--large" in sys.argv:
        sizes.append((512, 100))
    for side, count in sizes:
        field_image, truth_count = _field(side, count)
        start = time.perf_counter()
        fitted = fit_scene(
            field_image,
            Microscope(pixel_size_um=0.08, modality="fluorescence"),
            RenderSettings(),
            None,
            geometry="open",
        )
        seconds = time.perf_counter() - start
        print(
            f"| {side} x {side:<4} | {truth_count:5d} | {len(fitted.cells):5d} | {seconds:8.1f} "
            f"| {fitted.objective_after:6.2f} |"
        )


def _real_trench() -> np.ndarray | None:
    folder = os.environ.get("NAPARI_SYMBAC_REAL_DATA")
    root = Path(folder) if folder else Path(__file__).resolve().parents[2] / "shared/data/real"
    path = root / "ecoli_100x_oil_exponential.tiff"
    if not path.is_file():
        return None
    import tifffile

    return tifffile.imread(path)


def _field(side: int, count: int) -> tuple[np.ndarray, int]:
    """``count`` cells on a jittered grid of an open ``side`` x ``side`` field (80 nm)."""
    rng = np.random.default_rng(count)
    per_row = int(np.ceil(np.sqrt(count)))
    pitch = side * 0.08 / per_row
    ix, iy = np.meshgrid(np.arange(per_row), np.arange(per_row))
    x = ((ix.ravel() + 0.5) * pitch)[:count] + rng.uniform(-0.2, 0.2, count)
    y = ((iy.ravel() + 0.5) * pitch)[:count] + rng.uniform(-0.2, 0.2, count)
    length = np.minimum(rng.uniform(1.8, 3.0, count), pitch - 0.9)
    cells = FrameCells(
        ids=np.arange(1, count + 1),
        x_um=x,
        y_um=y,
        angle_rad=rng.uniform(-1.5, 1.5, count),
        length_um=np.maximum(length, 1.0),
        width_um=np.full(count, 0.9),
    )
    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    render = RenderSettings(cell_intensity=2000.0, media_intensity=150.0, defocus_sigma_um=0.1)
    field = Field(side * 0.08, side * 0.08)
    scene = draw_scene(cells, TrenchGeometry(), microscope, render, field=field)
    image = ForwardModel(microscope, render, Camera()).render(scene, np.random.default_rng(0))
    return image, count


if __name__ == "__main__":
    main()
