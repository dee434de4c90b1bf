"""Render timings: one 256 x 46 frame at 3x upsampling with a radius-50 PSF.

Prints a table: drawing the scene, rendering it cold (new scene: three
convolutions), re-rendering after an intensity / noise change (cached: no
convolution), and, as the yardstick measured in the same run, one real FFT of the
render-resolution frame. If SyMBac 0.5.2 is installed in a separate virtual
environment (``SYMBAC_PYTHON``, default ``/tmp/symbac-venv-render/bin/python``),
its convolve-and-rescale step on a frame of the same size and kernel is timed too
(a lower bound of its per-frame cost: it also composes, matches and adds noise).

Run: ``python benchmarks/bench_render.py``
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
from scipy import fft as sp_fft

from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

REPEATS = 30


def best_of(fn, repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def frame_cells(shift_um: float) -> SimpleNamespace:
    y = np.array([1.7, 5.0, 8.3, 11.6, 14.9]) + shift_um
    n = y.size
    return SimpleNamespace(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, 0.7),
        y_um=y,
        angle_rad=np.zeros(n),
        length_um=np.full(n, 3.1),
        width_um=np.full(n, 1.0),
    )


SYMBAC_SCRIPT = r"""
import sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
from SyMBac.PSF import PSF_generator
from SyMBac.renderer import convolve_rescale
shape = (int(sys.argv[1]), int(sys.argv[2]))
psf = PSF_generator(radius=50, wavelength=0.65, NA=1.45, n=1.518, apo_sigma=20,
                    mode="phase contrast", condenser="Ph3", resize_amount=3,
                    pix_mic_conv=0.065)
psf.calculate_PSF()
image = np.random.default_rng(0).random(shape)
times = []
for _ in range(10):
    t0 = time.perf_counter()
    convolve_rescale(image, psf.kernel, 1 / 3, rescale_int=True)
    times.append(time.perf_counter() - t0)
print(np.median(times))
"""


def symbac_time(shape: tuple[int, int]) -> tuple[float | None, str]:
    python = os.environ.get("SYMBAC_PYTHON", "/tmp/symbac-venv-render/bin/python")
    if not os.path.exists(python):
        return None, f"SyMBac not installed ({python} missing; pip install SyMBac==0.5.2 there)"
    try:
        out = subprocess.run(
            [python, "-c", SYMBAC_SCRIPT, str(shape[0]), str(shape[1])],
            capture_output=True,
            text=True,
            timeout=300,
            check=True,
        )
        return float(out.stdout.strip().splitlines()[-1]), "SyMBac 0.5.2 convolve_rescale (CPU)"
    except (subprocess.SubprocessError, ValueError, IndexError) as err:
        stderr = getattr(err, "stderr", "") or ""
        return None, f"SyMBac run failed: {stderr.strip().splitlines()[-1:] or err}"


def main() -> None:
    microscope = Microscope()
    render = RenderSettings(upsample=3, psf_radius_px=50)
    trench = TrenchGeometry(length_um=15.84, width_um=1.4, margin_um=0.8)
    camera = Camera()
    rng = np.random.default_rng(0)

    scene = draw_scene(frame_cells(0.0), trench, microscope, render)
    assert scene.camera_shape == (256, 46), scene.camera_shape
    t_draw = best_of(lambda: draw_scene(frame_cells(0.0), trench, microscope, render))

    model = ForwardModel(microscope, render, camera)
    model.render(scene, rng)  # builds the kernel once
    scenes = [
        draw_scene(frame_cells(0.01 * k), trench, microscope, render) for k in range(REPEATS + 1)
    ]
    it = iter(scenes)
    t_cold = best_of(lambda: model.render(next(it), rng))

    tuned = model.with_render(dataclasses.replace(render, cell_intensity=1200.0))
    tuned.render(scene, rng)
    settings = [dataclasses.replace(render, cell_intensity=1000.0 + k) for k in range(REPEATS)]
    it2 = iter(settings)
    t_cached = best_of(lambda: model.with_render(next(it2)).render(scene, rng))

    frame = np.asarray(scene.cells, np.float32)
    t_fft = best_of(lambda: sp_fft.rfft2(frame, workers=-1))

    t_symbac, symbac_note = symbac_time(scene.shape)

    print(
        f"napari-symbac render benchmark (python {sys.version.split()[0]}, numpy {np.__version__})"
    )
    print(f"frame: camera {scene.camera_shape}, render {scene.shape}, upsample 3, PSF radius 50")
    print()
    print(f"{'step':<52}{'time (ms)':>12}")
    print("-" * 64)
    rows = [
        ("draw_scene (5 cells)", t_draw),
        ("render, cold (new frame: convolve changed components)", t_cold),
        ("render, cached (intensity changed: recombine + noise)", t_cached),
        ("one rfft2 of the render-resolution frame", t_fft),
    ]
    if t_symbac is not None:
        rows.append((symbac_note, t_symbac))
    for name, t in rows:
        print(f"{name:<52}{t * 1e3:>12.3f}")
    print()
    print(f"cached / single FFT: {t_cached / t_fft:.2f}  (goal <= 3)")
    if t_symbac is not None:
        print(f"SyMBac convolve step / our cold render: {t_symbac / t_cold:.1f}x  (goal >= 10)")
    else:
        print(f"SyMBac comparison not run: {symbac_note}")


if __name__ == "__main__":
    main()
