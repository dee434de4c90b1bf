"""Render timings: one 256 x 46 frame at 3x upsampling with a radius-50 PSF.

Prints a table: drawing the scene, rendering it cold on the cached path (new
frame: the changed components are convolved and cached) and on the fast path
(``cache=False``: compose, convolve once), the camera-resolution masks (instance +
semantic, as ``pipeline.iter_render`` yields them with every image), the full
per-frame path (draw + fast render + masks), re-rendering after an intensity / noise
change (cached: no convolution), and, as the yardstick measured in the same run,
one real FFT of the render-resolution frame. If SyMBac 0.5.2 is installed in a
separate virtual environment (``SYMBAC_PYTHON``, default
``/tmp/symbac-venv-render/bin/python``), it is timed in the same run:

* its ``convolve_rescale`` step on a frame of our render size with its radius-50
  phase-contrast kernel (the convolution-step comparison);
* its full per-frame path: a small SyMBac simulation (256 x 46 camera px trench,
  resize 3) is run once, then each frame is drawn (``draw_scene_from_segments``)
  and rendered with ``Renderer.generate_test_comparison`` (OPL image, PSF, defocus,
  convolve + rescale, histogram matching, noise, masks), once with SyMBac's own
  automatic canvas expansion and once with the canvas cut to our render size.

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
import contextlib, io, sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
from SyMBac.PSF import PSF_generator
from SyMBac.drawing import draw_scene_from_segments
from SyMBac.renderer import Renderer, convolve_rescale
from SyMBac.simulation import Simulation

shape = (int(sys.argv[1]), int(sys.argv[2]))
camera = (int(sys.argv[3]), int(sys.argv[4]))
n_frames = int(sys.argv[5])
quiet = contextlib.redirect_stdout(io.StringIO())


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


psf = PSF_generator(radius=50, wavelength=0.65, NA=1.45, n=1.518, apo_sigma=20,
                    mode="phase contrast", condenser="Ph3", resize_amount=3,
                    pix_mic_conv=0.065)
psf.calculate_PSF()
image = np.random.default_rng(0).random(shape)
t_conv = median_time(lambda: convolve_rescale(image, psf.kernel, 1 / 3, rescale_int=True), 10)
print("conv", t_conv)

with quiet, contextlib.redirect_stderr(io.StringIO()):
    sim = Simulation(trench_length=15.0, trench_width=1.4, cell_max_length=6.65,
                     max_length_std=0.0, cell_width=1.0, width_std=0.0, lysis_p=0.0,
                     sim_length=n_frames + 20, pix_mic_conv=0.065, gravity=0, phys_iters=15,
                     resize_amount=3, save_dir="/tmp/symbac-bench-sim")
    sim.run_simulation(show_window=False)
    sim.draw_simulation_OPL(do_transformation=False, label_masks=True)
    real = np.random.default_rng(0).normal(1000, 50, camera).clip(0)
    renderer = Renderer(sim, psf, real)
    regions = renderer.auto_segment_regions()
    means = [renderer.real_resize[regions[k]].mean() for k in ("media", "cell", "device")]
    var = [renderer.real_resize[regions[k]].var() for k in ("media", "cell", "device")]
    renderer.image_params = (*means, np.mean(means), *var, np.mean(var))
frames = range(len(sim.OPL_scenes) - n_frames, len(sim.OPL_scenes))


def full_path(k):
    draw_scene_from_segments(
        sim.cell_timeseries_segments[k], sim._space_size, sim.offset, sim._label_masks
    )
    with contextlib.redirect_stdout(io.StringIO()):
        renderer.generate_test_comparison(scene_no=k)


def canvas():
    expanded, _, _ = renderer.generate_PC_OPL(
        sim.OPL_scenes[-1], sim.masks[-1], 75, 1.7, 29,
        renderer.y_border_expansion_coefficient, renderer.x_border_expansion_coefficient, 3.0)
    return expanded.shape


for label in ("auto", "matched"):
    if label == "matched":  # cut SyMBac's canvas to our render frame
        base = np.array(canvas()) / np.array(
            [renderer.y_border_expansion_coefficient, renderer.x_border_expansion_coefficient])
        renderer.y_border_expansion_coefficient = (shape[0] + 0.5) / base[0]
        renderer.x_border_expansion_coefficient = (shape[1] + 0.5) / base[1]
    full_path(frames[0])
    times = []
    for k in frames:
        t0 = time.perf_counter()
        full_path(k)
        times.append(time.perf_counter() - t0)
    print(label, float(np.median(times)), *canvas())
"""


def symbac_times(
    shape: tuple[int, int], camera: tuple[int, int], n_frames: int = 10
) -> tuple[dict[str, tuple], str]:
    """SyMBac's timings: ``{"conv": (s,), "auto": (s, rows, cols), "matched": (...)}``."""
    python = os.environ.get("SYMBAC_PYTHON", "/tmp/symbac-venv-render/bin/python")
    if not os.path.exists(python):
        return {}, f"SyMBac not installed ({python} missing; pip install SyMBac==0.5.2 there)"
    args = [*map(str, shape), *map(str, camera), str(n_frames)]
    try:
        out = subprocess.run(
            [python, "-c", SYMBAC_SCRIPT, *args],
            capture_output=True,
            text=True,
            timeout=600,
            check=True,
        )
    except subprocess.SubprocessError as err:
        stderr = getattr(err, "stderr", "") or ""
        return {}, f"SyMBac run failed: {stderr.strip().splitlines()[-1:] or err}"
    times: dict[str, tuple] = {}
    for line in out.stdout.splitlines():
        key, *values = line.split()
        if key in ("conv", "auto", "matched"):
            times[key] = (float(values[0]), *(int(v) for v in values[1:]))
    return times, "SyMBac 0.5.2 (CPU)"


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
    model.render(scene, rng)  # builds the kernel and its spectrum once
    model.render(scene, rng, cache=False)
    scenes = [
        draw_scene(frame_cells(0.01 * k), trench, microscope, render)
        for k in range(2 * REPEATS + 2)
    ]
    it = iter(scenes[: REPEATS + 1])
    t_cold = best_of(lambda: model.render(next(it), rng))
    it_fast = iter(scenes[REPEATS + 1 :])
    t_fast = best_of(lambda: model.render(next(it_fast), rng, cache=False))
    # Masks are computed once per scene: time them on scenes that have not computed
    # them yet (rendering does not).
    it_masks = iter(scenes[:REPEATS])

    def masks() -> tuple:
        mask_scene = next(it_masks)
        return mask_scene.camera_labels(), mask_scene.semantic_mask()

    t_masks = best_of(masks)

    def full_frame(k: int) -> tuple:
        frame_scene = draw_scene(frame_cells(0.005 * k), trench, microscope, render)
        return (
            model.render(frame_scene, rng, cache=False),
            frame_scene.camera_labels(),
            frame_scene.semantic_mask(),
        )

    it_frame = iter(range(REPEATS))
    t_frame = best_of(lambda: full_frame(next(it_frame)))

    tuned = model.with_render(dataclasses.replace(render, cell_intensity=1200.0))
    tuned.render(scene, rng)
    settings = [dataclasses.replace(render, cell_intensity=1000.0 + k) for k in range(REPEATS)]
    it2 = iter(settings)
    t_cached = best_of(lambda: model.with_render(next(it2)).render(scene, rng))

    frame = np.asarray(scene.cells, np.float32)
    t_fft = best_of(lambda: sp_fft.rfft2(frame, workers=-1))

    symbac, symbac_note = symbac_times(scene.shape, scene.camera_shape)

    print(
        f"napari-symbac render benchmark (python {sys.version.split()[0]}, numpy {np.__version__})"
    )
    print(f"frame: camera {scene.camera_shape}, render {scene.shape}, upsample 3, PSF radius 50")
    print()
    width = 66
    print(f"{'step':<{width}}{'time (ms)':>12}")
    print("-" * (width + 12))
    rows = [
        ("draw_scene (5 cells)", t_draw),
        ("render, cold, cached path (convolve changed components + noise)", t_cold),
        ("render, cold, fast path (cache=False: compose, convolve once)", t_fast),
        ("masks, Scene.camera_labels() + Scene.semantic_mask() (new scene)", t_masks),
        ("draw + fast render + masks (our full per-frame path)", t_frame),
        ("render, cached (intensity changed: recombine + noise)", t_cached),
        ("one rfft2 of the render-resolution frame", t_fft),
    ]
    if "conv" in symbac:
        rows.append(("SyMBac convolve_rescale, our render frame size", symbac["conv"][0]))
    for key, what in (("matched", "canvas cut to our frame"), ("auto", "its own canvas")):
        if key in symbac:
            t, r, c = symbac[key]
            rows.append((f"SyMBac full per-frame path, {what} ({r} x {c})", t))
    for name, t in rows:
        print(f"{name:<{width}}{t * 1e3:>12.3f}")
    print()
    print(f"cached / single FFT: {t_cached / t_fft:.2f}  (goal <= 3)")
    if not symbac:
        print(f"SyMBac comparison not run: {symbac_note}")
        return
    print("speed-up vs SyMBac 0.5.2 (goal >= 10x on the full per-frame path):")
    if "conv" in symbac:
        conv = symbac["conv"][0]
        print(
            f"  convolution step: SyMBac convolve_rescale / our cold render (fast path): "
            f"{conv / t_fast:.1f}x, (cached path): {conv / t_cold:.1f}x"
        )
    for key, what in (("matched", "same canvas"), ("auto", "SyMBac's own canvas")):
        if key in symbac:
            full = symbac[key][0]
            print(
                f"  full per-frame path, {what}: SyMBac / ours (draw + fast render + "
                f"masks): {full / t_frame:.1f}x; / ours (draw + cached-path cold render "
                f"+ masks): {full / (t_draw + t_cold + t_masks):.1f}x"
            )


if __name__ == "__main__":
    main()
