"""Time to fit a 256 x 46 trench and open fields of growing cell count.

Run: ``python benchmarks/bench_fit.py [--large] [--compare OLD_SRC]``. The reference is
``scipy.signal.fftconvolve`` of one render-resolution frame (upsample 3 plus the PSF
border) with the phase kernel, timed in the same run, so the ratios travel between
machines. The second table is the cost of :func:`fit_scene` against the number of
cells (fluorescence, open 256 x 256 field at 80 nm, camera estimated; ``--large``
adds a 512 x 512 field with 100 cells). The real trench (``../shared/data/real``,
or ``NAPARI_SYMBAC_REAL_DATA``) is timed when present. Prints tables; asserts
nothing.

``--compare OLD_SRC`` times the same fits with another checkout's ``src`` (e.g. one
unpacked by ``git archive``) and this one, alternately in fresh processes, so that
both see the same load: the before/after table of docs/fitting.md.

The measurements are importable functions returning dicts (for ``napari-symbac
bench``): :func:`measure_fit_trench` and :func:`measure_fit_field`.
"""

from __future__ import annotations

import json
import os
import subprocess
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


def measure_fit_trench() -> dict:
    """``fit_scene`` on the synthetic 256 x 46 trench (camera given) and, when the data
    are present, on the real 100x trench (round closed end, camera estimated).

    Returns
    -------
    dict
        ``synthetic_s``, ``synthetic_chi2``, ``synthetic_renders``, ``synthetic_cells``
        and, with the real data, ``real_s``, ``real_chi2``, ``real_renders``,
        ``real_cells`` (seconds of wall time, reduced chi-square, renders and patches,
        fitted cells).
    """
    microscope, camera = Microscope(pixel_size_um=PIXEL_UM), Camera()
    scene = draw_scene(_cells(), TRENCH, microscope, TRUTH)
    image = ForwardModel(microscope, TRUTH, camera).render(scene, np.random.default_rng(0))
    start = time.perf_counter()
    fitted = fit_scene(image, microscope, START, camera)
    out = {
        "synthetic_s": time.perf_counter() - start,
        "synthetic_chi2": float(fitted.objective_after),
        "synthetic_renders": int(fitted.n_evaluations),
        "synthetic_cells": len(fitted.cells),
    }
    real = _real_trench()
    if real is not None:
        start = time.perf_counter()
        fitted = fit_scene(real, microscope, RenderSettings(), None, closed_end="round")
        out.update(
            real_s=time.perf_counter() - start,
            real_chi2=float(fitted.objective_after),
            real_renders=int(fitted.n_evaluations),
            real_cells=len(fitted.cells),
        )
    return out


def measure_fit_field(side: int = 256, count: int = 36) -> dict:
    """``fit_scene`` on an open fluorescence field of ``count`` cells (camera estimated).

    Returns
    -------
    dict
        ``side`` (pixels), ``cells`` (truth), ``found``, ``seconds`` (wall), ``chi2``
        (reduced chi-square), ``renders`` (renders and patches).
    """
    image, truth_count = _field(side, count)
    start = time.perf_counter()
    fitted = fit_scene(
        image,
        Microscope(pixel_size_um=0.08, modality="fluorescence"),
        RenderSettings(),
        None,
        geometry="open",
    )
    return {
        "side": side,
        "cells": truth_count,
        "found": len(fitted.cells),
        "seconds": time.perf_counter() - start,
        "chi2": float(fitted.objective_after),
        "renders": int(fitted.n_evaluations),
    }


def measure_fit_parameters() -> dict:
    """``fit_parameters`` on the synthetic trench: the plain FFT reference and both terms.

    Returns
    -------
    dict
        ``fft_s`` (one render-frame convolution, best of 20), ``pixel_s``,
        ``pixel_renders``, ``statistics_s``, ``statistics_renders``.
    """
    microscope, camera = Microscope(pixel_size_um=PIXEL_UM), Camera()
    scene = draw_scene(_cells(), TRENCH, microscope, TRUTH)
    model = ForwardModel(microscope, TRUTH, camera)
    image = model.render(scene, np.random.default_rng(0))
    frame = np.asarray(scene.cells, np.float32)
    kernel = model.kernel()
    out = {"fft_s": _best_of(lambda: signal.fftconvolve(frame, kernel, mode="valid"), 20)}
    classes = scene_classes(scene)
    for name, kwargs in (("pixel", {"terms": ("pixel",)}), ("statistics", {})):
        start = time.perf_counter()
        result = fit_parameters(image, classes, scene, microscope, START, camera, **kwargs)
        out[f"{name}_s"] = time.perf_counter() - start
        out[f"{name}_renders"] = int(result.n_evaluations)
    return out


def _in_process(src: str, call: str) -> dict:
    """Run ``call`` (an expression on this module) with ``src`` first on the path."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([src, str(Path(__file__).parent)]))
    code = f"import json, bench_fit; print(json.dumps(bench_fit.{call}))"
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(old_src: str, calls: tuple[str, ...]) -> list[tuple[str, dict, dict]]:
    """Each of ``calls`` with ``old_src`` and with this checkout, one after the other."""
    new_src = str(Path(__file__).resolve().parents[1] / "src")
    return [(call, _in_process(old_src, call), _in_process(new_src, call)) for call in calls]


def main() -> None:
    if "--compare" in sys.argv:
        old = sys.argv[sys.argv.index("--compare") + 1]
        calls = ["measure_fit_trench()", "measure_fit_field(256, 36)"]
        if "--large" in sys.argv:
            calls.append("measure_fit_field(512, 100)")
        print(f"| {'measurement':<28} | {'key':<18} | {'before':>9} | {'after':>9} |")
        print(f"|{'-' * 30}|{'-' * 20}|{'-' * 11}|{'-' * 11}|")
        for call, before, after in compare(old, tuple(calls)):
            for key in after:
                b, a = before.get(key, float("nan")), after[key]
                print(f"| {call:<28} | {key:<18} | {b:9.3f} | {a:9.3f} |")
        return
    fp = measure_fit_parameters()
    reference = fp["fft_s"]
    trench = measure_fit_trench()
    rows = [
        ("plain FFT convolution (reference)", reference, None),
        ("fit_parameters, pixel term (true scene)", fp["pixel_s"], fp["pixel_renders"]),
        ("fit_parameters, statistics terms", fp["statistics_s"], fp["statistics_renders"]),
        (
            f"fit_scene, synthetic (chi2 {trench['synthetic_chi2']:.2f})",
            trench["synthetic_s"],
            trench["synthetic_renders"],
        ),
    ]
    if "real_s" in trench:
        rows.append(
            (
                f"fit_scene, real trench ({trench['real_cells']} cells, chi2 "
                f"{trench['real_chi2']:.2f})",
                trench["real_s"],
                trench["real_renders"],
            )
        )
    print("256 x 46 trench\n")
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
        row = measure_fit_field(side, count)
        print(
            f"| {side} x {side:<4} | {row['cells']:5d} | {row['found']:5d} | "
            f"{row['seconds']:8.1f} | {row['chi2']:6.2f} |"
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
