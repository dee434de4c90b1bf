"""The trench frame's per-frame path: this checkout against another version and SyMBac 0.5.2.

Two interleaved comparisons (docs/benchmarks.md, "Trench frame: static layers and the
camera-noise rule"):

1. ``--old-src DIR`` (the ``src`` folder of another version, e.g. from ``git archive
   COMMIT src | tar -x -C /tmp/old``): old and new code alternate, ``--pairs`` times,
   each running :func:`~napari_symbac.bench.cases_render.measure_trench_frame` with
   ``--rounds`` rounds in a fresh process (CPU time of the thread, each step beside
   the FFT floor). Prints each step's median over the runs and its range.
2. ``--symbac-python PY`` (an interpreter with SyMBac==0.5.2, see
   tools/make-symbac-env.sh): three long-lived processes, SyMBac's per-frame path
   (``draw_scene_from_segments`` + ``generate_test_comparison`` with and without
   histogram matching, canvas cut to our 868 x 238 render frame, as in
   ``napari-symbac bench``) and ours (this checkout, and ``--old-src`` when given),
   asked in turn, ``--symbac-rounds`` rounds in alternating order; ``--frames`` of our
   frames and a tenth as many of SyMBac's (each with and without matching) per round.
   Process CPU time (every thread), and wall time. Prints SyMBac / ours per round.

Run: ``python benchmarks/compare_trench_frame.py --old-src /tmp/old/src
--symbac-python /work/symbac-venv/bin/python``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from napari_symbac.bench.symbac_script import RENDERER_SETUP

NEW_SRC = str(Path(__file__).resolve().parents[1] / "src")

MEASURE = (
    "import json; from napari_symbac.bench.cases_render import measure_trench_frame as m; "
    "print(json.dumps(m({rounds})))"
)

OURS = r"""
import json, sys, time
import numpy as np
from napari_symbac.bench.cases_render import trench_cells, trench_settings
from napari_symbac.bench.timing import fft_floor
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
microscope, render, trench, camera = trench_settings()
model = ForwardModel(microscope, render, camera)
rng = np.random.default_rng(0)
scene = draw_scene(trench_cells(0.0), trench, microscope, render)
model.render(scene, rng, cache=False)
floor = fft_floor(scene.cells, model.kernel())
def full_frame(cells):
    s = draw_scene(cells, trench, microscope, render)
    image = model.render(s, rng, cache=False)
    return image, s.camera_labels(), s.semantic_mask()
print(json.dumps({"ready": True}), flush=True)
k = 0
for line in sys.stdin:
    out = {"frame_cpu": [], "frame_wall": [], "floor_cpu": []}
    for _ in range(int(line)):
        k += 1
        cells = trench_cells(0.004 * k)
        c0, w0 = time.process_time(), time.perf_counter()
        full_frame(cells)
        out["frame_cpu"].append(time.process_time() - c0)
        out["frame_wall"].append(time.perf_counter() - w0)
        c0 = time.process_time()
        floor()
        out["floor_cpu"].append(time.process_time() - c0)
    print(json.dumps(out), flush=True)
"""

SYMBAC = r"""
import contextlib, io, json, sys, tempfile, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
quiet = io.StringIO()
with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
    from SyMBac.PSF import PSF_generator
    from SyMBac.drawing import draw_scene_from_segments
    from SyMBac.renderer import Renderer
    from SyMBac.simulation import Simulation
    sim = Simulation(trench_length=15, trench_width=1.4, cell_max_length=3.5, max_length_std=0.2,
                     cell_width=1.0, width_std=0.05, lysis_p=0.0, sim_length=40,
                     pix_mic_conv=0.065, gravity=0, phys_iters=15, resize_amount=3,
                     save_dir=tempfile.mkdtemp())
    sim.run_simulation(show_window=False)
    sim.draw_simulation_OPL(do_transformation=False, label_masks=True)
    shape, camera_shape = (868, 238), (256, 46)
""" + RENDERER_SETUP + r"""
def full_path(k, match):
    with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
        draw_scene_from_segments(
            sim.cell_timeseries_segments[k], sim._space_size, sim.offset, sim._label_masks)
        renderer.generate_test_comparison(scene_no=k, match_histogram=match)
ks = list(range(max(1, len(sim.OPL_scenes) - 10), len(sim.OPL_scenes)))
full_path(ks[0], True)
full_path(ks[0], False)
print(json.dumps({"ready": True}), flush=True)
for line in sys.stdin:
    out = {"match_cpu": [], "match_wall": [], "nomatch_cpu": [], "nomatch_wall": []}
    for i in range(int(line)):
        for match, key in ((True, "match"), (False, "nomatch")):
            c0, w0 = time.process_time(), time.perf_counter()
            full_path(ks[i % len(ks)], match)
            out[key + "_cpu"].append(time.process_time() - c0)
            out[key + "_wall"].append(time.perf_counter() - w0)
    print(json.dumps(out), flush=True)
"""


def _env(src: str) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": src}


def fresh_runs(old_src: str, pairs: int, rounds: int) -> None:
    """Old and new ``measure_trench_frame`` alternating in fresh processes."""
    runs: dict[str, list[dict]] = {"old": [], "new": []}
    load = os.getloadavg()[0]
    for k in range(pairs):
        for name in ("old", "new") if k % 2 == 0 else ("new", "old"):
            src = old_src if name == "old" else NEW_SRC
            out = subprocess.run(
                [sys.executable, "-c", MEASURE.format(rounds=rounds)],
                env=_env(src), capture_output=True, text=True, check=True,
            ).stdout
            runs[name].append(json.loads(out.strip().splitlines()[-1]))
    print(f"load average {load:.1f} -> {os.getloadavg()[0]:.1f}; {pairs} pairs, {rounds} rounds")
    print("| step | old ms | old / floor | new ms | new / floor |\n|---|---|---|---|---|")
    for key in ("draw_s", "clean_s", "noise_s", "masks_s", "frame_s", "fft_floor_s"):
        cells = []
        for name in ("old", "new"):
            v = np.array([r[key] for r in runs[name]])
            ratio = v / np.array([r["fft_floor_s"] for r in runs[name]])
            cells += [
                f"{np.median(v) * 1e3:.3g}",
                f"{np.median(ratio):.3g} ({ratio.min():.3g}-{ratio.max():.3g})",
            ]
        print(f"| {key} | " + " | ".join(cells) + " |")


def _start(command: list[str], env: dict[str, str] | None = None) -> subprocess.Popen:
    process = subprocess.Popen(
        command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
    )
    if not json.loads(process.stdout.readline()).get("ready"):  # type: ignore[union-attr]
        raise RuntimeError(f"{command[0]} did not start")
    return process


def _ask(process: subprocess.Popen, n: int) -> dict[str, list[float]]:
    process.stdin.write(f"{n}\n")  # type: ignore[union-attr]
    process.stdin.flush()  # type: ignore[union-attr]
    return json.loads(process.stdout.readline())  # type: ignore[union-attr]


def beside_symbac(symbac_python: str, old_src: str | None, rounds: int, frames: int) -> None:
    """SyMBac's and our per-frame paths, long-lived processes asked in turn."""
    load = os.getloadavg()[0]
    processes = {"symbac": _start([symbac_python, "-c", SYMBAC])}
    for name, src in (("new", NEW_SRC), ("old", old_src)):
        if src is not None:
            processes[name] = _start([sys.executable, "-c", OURS], env=_env(src))
    medians: dict[str, dict[str, list[float]]] = {name: {} for name in processes}
    try:
        for r in range(rounds):
            order = list(processes.items())
            for name, process in order if r % 2 == 0 else order[::-1]:
                n = max(1, frames // 10) if name == "symbac" else frames
                for key, values in _ask(process, n).items():
                    medians[name].setdefault(key, []).append(float(np.median(values)))
    finally:
        for process in processes.values():
            process.stdin.close()  # type: ignore[union-attr]
            process.wait()
    print(f"load average {load:.1f} -> {os.getloadavg()[0]:.1f}; {rounds} rounds")
    for name, keys in medians.items():
        for key, values in keys.items():
            print(f"{name} {key}: median {np.median(values) * 1e3:.3g} ms "
                  f"({min(values) * 1e3:.3g}-{max(values) * 1e3:.3g})")
    for name in ("new", "old"):
        if name not in medians:
            continue
        ours = np.array(medians[name]["frame_cpu"])
        floor = np.array(medians[name]["floor_cpu"])
        print(f"{name}: frame / floor per round {np.round(ours / floor, 3).tolist()}")
        for match in ("match", "nomatch"):
            ratio = np.array(medians["symbac"][f"{match}_cpu"]) / ours
            wall = np.array(medians["symbac"][f"{match}_wall"]) / np.array(
                medians[name]["frame_wall"]
            )
            print(f"{name}, SyMBac {match}: SyMBac / ours CPU {np.round(ratio, 1).tolist()} "
                  f"(median {np.median(ratio):.1f}), wall {np.round(wall, 1).tolist()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--old-src", help="src folder of the version to compare with")
    parser.add_argument("--symbac-python", help="python of a venv with SyMBac==0.5.2")
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--symbac-rounds", type=int, default=6)
    parser.add_argument("--frames", type=int, default=40)
    args = parser.parse_args()
    if args.old_src is None and args.symbac_python is None:
        parser.error("give --old-src, --symbac-python or both")
    if args.old_src is not None:
        if not (Path(args.old_src) / "napari_symbac").is_dir():
            parser.error(f"--old-src {args.old_src}: no napari_symbac package there")
        fresh_runs(args.old_src, args.pairs, args.rounds)
    if args.symbac_python is not None:
        beside_symbac(args.symbac_python, args.old_src, args.symbac_rounds, args.frames)


if __name__ == "__main__":
    main()
