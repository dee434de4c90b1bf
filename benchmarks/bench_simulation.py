"""Speed and memory of the growth simulation (napari_symbac.sim), printed as a table.

Cases
-----
* ``trench-250`` / ``trench-500``: a 25 um mother-machine trench (1.4 um wide) for 250
  and 500 frames at the default settings (15 physics iterations per frame); their
  ratio checks that the cost is linear in the number of frames.
* ``colony``: an agar-pad monolayer (250 x 250 um field, one founder) grown to 400,
  1000 and 4000 cells; then a few frames from each size are timed, the sizes
  interleaved over several rounds (each round restarts from the same saved state), and
  the cost per cell-frame of the largest colony is given as a ratio to the smallest
  (1.0 is linear in cells).
* ``symbac-500``: SyMBac 0.5.2's own simulator at the trench settings, if it can be
  imported from ``/tmp/symbac-venv`` (a separate virtual environment); otherwise the
  table says why not.

Each case runs in a fresh subprocess so that its peak resident memory (``VmHWM``)
is its own. Run with ``python benchmarks/bench_simulation.py``.

The measuring functions live in :mod:`napari_symbac.bench.cases_sim`
(``measure_trench``, ``measure_colony``, ``measure_colony_scaling``), shared with
``napari-symbac bench``; this script runs them in subprocesses and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

from napari_symbac.bench.cases_sim import (
    COLONY_FIELD_UM,
    COLONY_SIZES,
    measure_colony_scaling,
    measure_trench,
)
from napari_symbac.bench.timing import peak_rss_mib

SYMBAC_PYTHON = Path("/tmp/symbac-venv/bin/python")


_SYMBAC_SCRIPT = r"""
import json, resource, tempfile, time
from SyMBac.simulation import Simulation
tmp = tempfile.mkdtemp()
# SyMBac 0.5.2 takes standard deviations: sqrt(0.04) = 0.2 um, sqrt(0.0025) = 0.05 um
sim = Simulation(trench_length=25, trench_width=1.4, cell_max_length=3.5, max_length_std=0.2,
                 cell_width=1.0, width_std=0.05, lysis_p=0.0, sim_length=FRAMES,
                 pix_mic_conv=0.065, gravity=0, phys_iters=15, resize_amount=3, save_dir=tmp)
start = time.perf_counter()
sim.run_simulation(show_window=False)
seconds = time.perf_counter() - start
print(json.dumps({"frames": FRAMES, "seconds": seconds, "frames_per_s": FRAMES / seconds,
                  "cell_frames": None, "final_cells": None,
                  "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _run_symbac(frames: int) -> dict | str:
    if not SYMBAC_PYTHON.exists():
        return (
            f"not run: {SYMBAC_PYTHON} does not exist (SyMBac==0.5.2 could not be installed "
            "into /tmp/symbac-venv; see the docs)"
        )
    probe = subprocess.run(
        [str(SYMBAC_PYTHON), "-c", "import SyMBac.simulation"],
        capture_output=True,
        text=True,
    )
    if probe.returncode != 0:
        last = (probe.stderr.strip().splitlines() or ["?"])[-1]
        return f"not run: SyMBac does not import in /tmp/symbac-venv ({last})"
    done = subprocess.run(
        [str(SYMBAC_PYTHON), "-c", _SYMBAC_SCRIPT.replace("FRAMES", str(frames))],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        return f"not run: SyMBac's simulation failed ({last})"
    return json.loads(done.stdout.strip().splitlines()[-1])


def _subprocess(case: str, args: argparse.Namespace) -> dict:
    command = [sys.executable, __file__, "--case", case, "--rounds", str(args.rounds)]
    command += ["--colony-sizes", *map(str, args.colony_sizes)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _case(name: str, args: argparse.Namespace) -> dict:
    if name.startswith("trench-"):
        return measure_trench(int(name.split("-")[1]))
    if name == "colony":
        return measure_colony_scaling(tuple(args.colony_sizes), rounds=args.rounds)
    raise ValueError(f"unknown case {name}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", help=argparse.SUPPRESS)
    parser.add_argument("--no-symbac", action="store_true", help="skip the SyMBac comparison")
    parser.add_argument(
        "--symbac-frames",
        type=int,
        default=500,
        help="frames for the SyMBac comparison (default 500; SyMBac runs ~1-2 frames/s)",
    )
    parser.add_argument(
        "--colony-sizes",
        type=int,
        nargs="+",
        default=list(COLONY_SIZES),
        help="colony sizes (cells) to time (default 400 1000 4000)",
    )
    parser.add_argument(
        "--rounds", type=int, default=3, help="interleaved timing rounds per colony size"
    )
    args = parser.parse_args()
    if min(args.colony_sizes) < 1 or args.rounds < 1 or args.symbac_frames < 1:
        parser.error("--colony-sizes, --rounds and --symbac-frames must be >= 1")
    if args.case:
        result = _case(args.case, args)
        result["peak_mib"] = peak_rss_mib()
        print(json.dumps(result))
        return

    rows: dict[str, dict | str] = {}
    cases = ["trench-250", "trench-500"]
    compare = f"trench-{args.symbac_frames}"
    if not args.no_symbac and compare not in cases:
        cases.append(compare)
    for case in cases:
        rows[case] = _subprocess(case, args)
    if not args.no_symbac:
        rows[f"symbac-{args.symbac_frames} (SyMBac 0.5.2)"] = _run_symbac(args.symbac_frames)
    colony = _subprocess("colony", args)

    load = os.getloadavg()[0]
    print(
        f"napari-symbac growth simulation benchmark ({platform.processor() or platform.machine()}, "
        f"Python {platform.python_version()}, load average {load:.1f})"
    )
    header = (
        f"{'case':28s} {'frames':>7s} {'seconds':>8s} {'frames/s':>9s} {'final cells':>11s} "
        f"{'peak MiB':>9s}"
    )
    print(header)
    print("-" * len(header))
    for case, row in rows.items():
        if isinstance(row, str):
            print(f"{case:28s} {row}")
            continue
        final = "" if row["final_cells"] is None else str(row["final_cells"])
        print(
            f"{case:28s} {row['frames']:7d} {row['seconds']:8.2f} {row['frames_per_s']:9.1f} "
            f"{final:>11s} {row['peak_mib']:9.1f}"
        )
    t250, t500 = rows["trench-250"], rows["trench-500"]
    ratio = t500["seconds"] / t250["seconds"]
    print(f"\nlinear cost: time(500 frames) / time(250 frames) = {ratio:.2f} (2.00 is linear)")
    symbac = rows.get(f"symbac-{args.symbac_frames} (SyMBac 0.5.2)")
    if isinstance(symbac, dict):
        ours = rows[compare]
        print(
            f"napari-symbac / SyMBac frames/s, same trench settings and {args.symbac_frames} "
            f"frames: {ours['frames_per_s'] / symbac['frames_per_s']:.0f}x "
            "(SyMBac uses 100 physics substeps per frame)"
        )

    print(
        f"\nagar-pad colony ({COLONY_FIELD_UM:.0f} um field, {colony['frames']} frames timed "
        f"per size, {colony['rounds']} interleaved rounds; grown in "
        f"{colony['grow_seconds']:.0f} s; peak {colony['peak_mib']:.0f} MiB)"
    )
    header = f"{'cells':>7s} {'ms/cell-frame best':>19s} {'median':>8s} {'frames/s':>9s}"
    print(header)
    print("-" * len(header))
    for row in colony["sizes"].values():
        print(
            f"{row['cells']:7d} {row['ms_per_cell_frame']:19.3f} "
            f"{row['ms_per_cell_frame_median']:8.3f} {row['frames_per_s']:9.2f}"
        )
    sizes = sorted(colony["sizes"], key=int)
    print(
        f"cost per cell-frame, {sizes[-1]} / {sizes[0]} cells: {colony['ratio']:.2f} (best), "
        f"{colony['ratio_median']:.2f} (median); 1.00 is linear in cells"
    )


if __name__ == "__main__":
    main()
