"""Render timings: one 256 x 46 frame at 3x upsampling with a radius-50 PSF.

Prints a table: drawing the scene, rendering it cold on the cached path (new
frame: the changed components are convolved and cached) and on the fast path
(``cache=False``: static layers once, the cells per frame), the camera-resolution
masks (instance + semantic, as ``pipeline.iter_render`` yields them with every image), the full
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

Issue 15's ratios are printed too, each against one plain FFT convolution of the
same render-resolution frame measured in the same run (the "FFT floor":
``irfft2(rfft2(frame) * K)`` at fast transform lengths, the kernel's spectrum ``K``
computed beforehand, one thread):

* the full per-frame path of the trench frame (draw + fast render with noise +
  masks, what ``pipeline.iter_render`` does per frame) / floor (goal <= 1.5);
* drawing a field (scene + instance and semantic masks) of 1024 x 1024 camera px
  with 360 cells and 2048 x 2048 with 1440 cells / floor (goal <= 0.3).

The measuring functions live in :mod:`napari_symbac.bench.cases_render`
(``measure_trench_frame``, ``measure_field_draw``, ``measure_cached_paths``; the floor
is :func:`napari_symbac.bench.timing.fft_floor`), shared with ``napari-symbac bench``;
this script prints their table and the SyMBac comparison. Steps are timed
interleaved (one of each in turn, medians of the rounds) in CPU time of the
calling thread (``time.thread_time``; every step timed is single-threaded), which a
shared, loaded machine disturbs less than wall time.

Run: ``python benchmarks/bench_render.py [--quick]``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

import numpy as np

from napari_symbac.bench.cases_render import (
    FIELD_CASES,
    measure_cached_paths,
    measure_field_draw,
    measure_trench_frame,
)

REPEATS = 30


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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="fewer rounds, no 2048 field, no SyMBac"
    )
    args = parser.parse_args(argv)
    rounds = 10 if args.quick else REPEATS
    trench = measure_trench_frame(rounds)
    cached = measure_cached_paths(rounds)
    fields = [
        measure_field_draw(size, n, rounds=3 if args.quick else 5)
        for size, n in FIELD_CASES[: 1 if args.quick else None]
    ]
    symbac, symbac_note = (
        ({}, "--quick")
        if args.quick
        else symbac_times(trench["render_shape"], trench["camera_shape"])
    )
    load = os.getloadavg()
    print(
        f"napari-symbac render benchmark (python {sys.version.split()[0]}, "
        f"numpy {np.__version__}); load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} "
        f"on {os.cpu_count()} cores"
    )
    print(
        f"trench frame: camera {trench['camera_shape']}, render {trench['render_shape']}, "
        "upsample 3, PSF radius 50; CPU time of this thread, medians of interleaved rounds"
    )
    print()
    width = 66
    print(f"{'step':<{width}}{'time (ms)':>12}{'/ floor':>9}")
    print("-" * (width + 21))
    floor = trench["fft_floor_s"]
    rows = [
        ("draw_scene (5 cells)", trench["draw_s"]),
        ("render, fast path: noise-free image (static layers + cells)", trench["clean_s"]),
        ("render, fast path: camera noise (eq. 17, uint16)", trench["noise_s"]),
        ("masks, Scene.camera_labels() + Scene.semantic_mask() (new scene)", trench["masks_s"]),
        ("draw + fast render + masks (our full per-frame path)", trench["frame_s"]),
        (
            "render, cold, cached path (convolve changed components + noise)",
            cached["cold_cached_s"],
        ),
        ("render, cached (intensity changed: recombine + noise)", cached["rerender_s"]),
        ("one rfft2 of the render-resolution frame", cached["rfft2_s"]),
        ("FFT floor: one FFT convolution of the render frame", floor),
    ]
    if "conv" in symbac:
        rows.append(("SyMBac convolve_rescale, our render frame size", symbac["conv"][0]))
    for key, what in (("matched", "canvas cut to our frame"), ("auto", "its own canvas")):
        if key in symbac:
            t, r, c = symbac[key]
            rows.append((f"SyMBac full per-frame path, {what} ({r} x {c})", t))
    for name, t in rows:
        print(f"{name:<{width}}{t * 1e3:>12.3f}{t / floor:>9.2f}")
    print()
    print(f"{'field: draw + masks':<{width}}{'time (ms)':>12}{'/ floor':>9}")
    print("-" * (width + 21))
    for f in fields:
        side = f["size_px"]
        what = f"{side} x {side} px, {f['n_cells']} cells (render {f['render_shape'][0]}^2)"
        for name, key in (
            ("draw_scene", "draw_s"),
            ("masks", "masks_s"),
            ("draw + masks", "draw_masks_s"),
            ("media, 1st read (renderer)", "media_s"),
            ("FFT floor", "fft_floor_s"),
        ):
            t = f[key]
            print(f"{what + ': ' + name:<{width}}{t * 1e3:>12.1f}{t / f['fft_floor_s']:>9.2f}")
    print()
    print(f"full per-frame path / FFT floor: {trench['frame_over_floor']:.2f}  (goal <= 1.5)")
    for f in fields:
        print(
            f"field {f['size_px']} x {f['size_px']}, {f['n_cells']} cells: draw + masks / FFT "
            f"floor: {f['draw_masks_over_floor']:.2f}  (goal <= 0.3)"
        )
    print(f"cached re-render / one rfft2: {cached['rerender_over_rfft2']:.2f}  (goal <= 3)")
    if not symbac:
        print(f"SyMBac comparison not run: {symbac_note}")
        return
    print("speed-up vs SyMBac 0.5.2 (goal >= 10x on the full per-frame path):")
    t_frame = trench["frame_s"]
    if "conv" in symbac:
        print(
            f"  convolution step: SyMBac convolve_rescale / our noise-free fast render: "
            f"{symbac['conv'][0] / trench['clean_s']:.1f}x"
        )
    for key, what in (("matched", "same canvas"), ("auto", "SyMBac's own canvas")):
        if key in symbac:
            print(
                f"  full per-frame path, {what}: SyMBac / ours (draw + fast render + masks): "
                f"{symbac[key][0] / t_frame:.1f}x"
            )


if __name__ == "__main__":
    main()
