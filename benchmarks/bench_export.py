"""Export throughput: images per second with 1 and 2 workers, and peak memory.

Exports ``--n`` (default 1,000) independent mother-machine trench images (about 256 x 46
pixels, default settings) as TIFF pairs (``omnipose`` format), once serially in one
process and once through a dask LocalCluster of 2 worker processes on 127.0.0.1. Each
configuration runs in a fresh subprocess so its peak memory (resident set, the process
and its children) is its own. Prints a table; nothing is asserted.

    python benchmarks/bench_export.py            # 1,000 images
    python benchmarks/bench_export.py --n 100    # quicker

Where SyMBac 0.5.2 is importable (``--symbac-python /path/to/python`` of a venv that has
it), its ``Renderer.generate_training_data`` on a comparable trench is timed too.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _child(n: int, workers: int, out: str) -> None:
    from napari_symbac.export import ExportSettings, export_dataset
    from napari_symbac.settings import PipelineSettings, SimulationSettings

    settings = ExportSettings(
        n_items=n,
        formats=["omnipose"],
        seed=0,
        first_frame=20,
        pipeline=PipelineSettings(simulation=SimulationSettings(n_frames=60)),
    )
    start = time.perf_counter()
    marks: list[tuple[float, int]] = []

    def progress(done: int, total: int) -> None:
        marks.append((time.perf_counter(), done))

    report = export_dataset(settings, out, workers=workers, progress=progress)
    wall = time.perf_counter() - start
    # steady state: from the first finished batch (simulation and cluster start done) to the end
    (t0, d0), (t1, d1) = next(m for m in marks if m[1] > 0), marks[-1]
    steady = (d1 - d0) / (t1 - t0) if t1 > t0 else float("nan")
    import tifffile

    first = next(Path(out, "omnipose").rglob("*_masks.tif"))
    shape = tifffile.imread(first).shape
    self_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print(
        json.dumps(
            {
                "n": report.n_written,
                "workers": report.workers,
                "wall_s": wall,
                "steady_images_per_s": steady,
                "shape": list(shape),
                "peak_main_mib": self_kb / 1024,
                "peak_worker_mib": children_kb / 1024,
            }
        )
    )


def _run(n: int, workers: int) -> dict:
    out = tempfile.mkdtemp(prefix="bench-export-")
    try:
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--child",
                "--n",
                str(n),
                "--workers",
                str(workers),
                "--out",
                out,
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        return json.loads(proc.stdout.strip().splitlines()[-1])
    finally:
        shutil.rmtree(out, ignore_errors=True)


# SyMBac 0.5.2: the same trench, microscope and camera; intensities set directly (no
# real-image matching), 10 % variation of intensities and PSF sigma as in its tutorials.
_SYMBAC_SNIPPET = r"""
import json, sys, time, tempfile, resource, types
import numpy as np
n = int(sys.argv[1])
from SyMBac.simulation import Simulation
from SyMBac.PSF import PSF_generator, Camera
from SyMBac.renderer import Renderer
sim = Simulation(trench_length=15, trench_width=1.4, cell_max_length=3.5, max_length_std=0.2,
                 cell_width=1.0, width_std=0.05, lysis_p=0.0, sim_length=60, pix_mic_conv=0.065,
                 gravity=0, phys_iters=15, resize_amount=3, save_dir=tempfile.mkdtemp())
t0 = time.perf_counter()
sim.run_simulation(show_window=False)
sim.draw_simulation_OPL(do_transformation=False, label_masks=True)
t_sim = time.perf_counter() - t0
psf = PSF_generator(radius=50, wavelength=0.65, NA=1.45, n=1.518, resize_amount=3,
                    pix_mic_conv=0.065, apo_sigma=10, mode="phase contrast", condenser="Ph3")
psf.calculate_PSF()
camera = Camera(baseline=100, sensitivity=2.9, dark_noise=8)
real = np.random.default_rng(0).normal(1000, 30, (258, 46)).astype(np.uint16)
renderer = Renderer(simulation=sim, PSF=psf, real_image=real, camera=camera)
m = real.mean(); v = real.var()
renderer.image_params = (m, m * 0.6, m * 0.4, np.array((m, 0.6 * m, 0.4 * m)),
                         v, v, v, np.array((v, v, v)))
renderer.params = types.SimpleNamespace(kwargs=dict(
    media_multiplier=75, cell_multiplier=1.7, device_multiplier=29, sigma=psf.min_sigma * 2,
    match_histogram=False, match_noise=False, match_fourier=False, noise_var=0.001, defocus=0,
    halo_top_intensity=0, halo_bottom_intensity=0, halo_start=0, halo_end=0,
    cell_texture_strength=0, cell_texture_scale=70, edge_floor_opl=0.0))
out = tempfile.mkdtemp()
t = time.perf_counter()
renderer.generate_training_data(
    sample_amount=0.1, randomise_hist_match=False, randomise_noise_match=False,
    burn_in=20, n_samples=n, save_dir=out, in_series=False)
wall = time.perf_counter() - t
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"n": n, "wall_s": wall + t_sim, "render_s": wall, "sim_s": t_sim,
                  "peak_main_mib": peak}))
"""


def _symbac(python: str, n: int) -> dict | str:
    try:
        proc = subprocess.run(
            [python, "-c", _SYMBAC_SNIPPET, str(n)],
            capture_output=True,
            text=True,
            timeout=1800,
        )
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"SyMBac run failed: {err}"
    if proc.returncode != 0:
        return "SyMBac run failed: " + proc.stderr.strip().splitlines()[-1][:200]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="images per run (default 1000)")
    parser.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    parser.add_argument("--symbac-python", help="python of a venv where SyMBac 0.5.2 is installed")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args.n, args.workers[0], args.out)
        return 0

    print(f"napari-symbac export benchmark: {args.n} trench images, format omnipose (TIFF pairs)")
    print(f"machine: {os.cpu_count()} cores, python {sys.version.split()[0]}")
    rows = []
    for workers in args.workers:
        result = _run(args.n, workers)
        rows.append(result)
    serial = rows[0]["n"] / rows[0]["wall_s"]
    print()
    header = f"{'tool':<14}{'workers':>8}{'images':>8}{'wall s':>9}{'images/s':>10}{'vs 1':>7}"
    header += f"{'steady im/s':>13}"
    header += f"{'peak main MiB':>15}{'peak worker MiB':>17}"
    print(header)
    print("-" * len(header))
    for r in rows:
        rate = r["n"] / r["wall_s"]
        print(
            f"{'napari-symbac':<14}{r['workers']:>8}{r['n']:>8}{r['wall_s']:>9.1f}{rate:>10.1f}"
            f"{rate / serial:>7.2f}{r['steady_images_per_s']:>13.1f}"
            f"{r['peak_main_mib']:>15.0f}{r['peak_worker_mib']:>17.0f}"
        )
    print(f"image shape: {tuple(rows[0]['shape'])}; wall time includes the simulation and,")
    print("for 2 workers, starting the LocalCluster (each worker simulates once); 'steady'")
    print("counts from the first finished batch to the end. Peak memory: resident set of the")
    print("main process and of its largest child (a dask worker).")
    python = args.symbac_python
    if python is None:
        candidate = Path("/tmp/symbac-venv-export/bin/python")
        python = str(candidate) if candidate.exists() else None
    if python is None:
        print("\nSyMBac 0.5.2 is not installed here: no comparison (pass --symbac-python).")
        return 0
    result = _symbac(python, args.n)
    if isinstance(result, str):
        print(f"\n{result}: no comparison.")
    else:
        rate = result["n"] / result["wall_s"]
        steady = result["n"] / result["render_s"]
        print(
            f"{'SyMBac 0.5.2':<14}{1:>8}{result['n']:>8}{result['wall_s']:>9.1f}{rate:>10.1f}"
            f"{rate / serial:>7.2f}{steady:>13.1f}{result['peak_main_mib']:>15.0f}{'-':>17}"
        )
        print(
            f"SyMBac: simulation + OPL drawing {result['sim_s']:.1f} s, rendering and saving "
            f"{result['render_s']:.1f} s ('steady' = rendering only); PNG image/mask pairs."
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
