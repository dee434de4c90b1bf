"""Speed and memory of the growth simulation (napari_symbac.sim), printed as a table.

Cases
-----
* ``trench-250`` / ``trench-500``: a 25 um mother-machine trench (1.4 um wide) for 250
  and 500 frames at the default settings (15 physics iterations per frame); their
  ratio checks that the cost is linear in the number of frames.
* ``colony-500``: an agar-pad monolayer grown from one cell to 500 cells.
* ``symbac-500``: SyMBac 0.5.2's own simulator at the trench settings, if it can be
  imported from ``/tmp/symbac-venv`` (a separate virtual environment); otherwise the
  table says why not.

Each case runs in a fresh subprocess so that its peak resident memory (``ru_maxrss``)
is its own. Run with ``python benchmarks/bench_simulation.py``.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

SYMBAC_PYTHON = Path("/tmp/symbac-venv/bin/python")


def _peak_rss_mib() -> float:
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024 if platform.system() != "Darwin" else rss / 2**20


def _case(name: str) -> dict:
    from napari_symbac.settings import AgarPadGeometry, SimulationSettings, TrenchGeometry
    from napari_symbac.sim import Simulator

    if name.startswith("trench"):
        frames = int(name.split("-")[1])
        settings = SimulationSettings(
            n_frames=frames, trench=TrenchGeometry(length_um=25.0, width_um=1.4), seed=0
        )
        start = time.perf_counter()
        simulator = Simulator(settings)
        for _ in simulator.iter_frames():
            pass
        seconds = time.perf_counter() - start
        sim = simulator.result()
        cells = int(sum(len(f) for f in sim.frames))
        return {
            "frames": frames,
            "seconds": seconds,
            "cell_frames": cells,
            "final_cells": len(sim.frames[-1]),
        }
    if name == "colony-500":
        settings = SimulationSettings(
            geometry="agar_pad", n_frames=10_000, agar_pad=AgarPadGeometry(90.0, 90.0), seed=0
        )
        start = time.perf_counter()
        simulator = Simulator(settings)
        cells = 0
        for frame in simulator.iter_frames():
            cells += len(frame)
            if len(frame) >= 500:
                break
        seconds = time.perf_counter() - start
        return {
            "frames": simulator.frames_done,
            "seconds": seconds,
            "cell_frames": cells,
            "final_cells": len(frame),
        }
    raise ValueError(f"unknown case {name}")


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
print(json.dumps({"frames": FRAMES, "seconds": seconds, "cell_frames": None,
                  "final_cells": None,
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
    args = parser.parse_args()
    if args.case:
        result = _case(args.case)
        result["peak_mib"] = _peak_rss_mib()
        print(json.dumps(result))
        return

    rows: dict[str, dict | str] = {}
    cases = ["trench-250", "trench-500", "colony-500"]
    compare = f"trench-{args.symbac_frames}"
    if not args.no_symbac and compare not in cases:
        cases.append(compare)
    for case in cases:
        done = subprocess.run(
            [sys.executable, __file__, "--case", case], capture_output=True, text=True, check=True
        )
        rows[case] = json.loads(done.stdout.strip().splitlines()[-1])
    if not args.no_symbac:
        rows[f"symbac-{args.symbac_frames} (SyMBac 0.5.2)"] = _run_symbac(args.symbac_frames)

    print(
        f"napari-symbac growth simulation benchmark ({platform.processor() or platform.machine()}, "
        f"Python {platform.python_version()})"
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
        fps = row["frames"] / row["seconds"]
        final = "" if row["final_cells"] is None else str(row["final_cells"])
        print(
            f"{case:28s} {row['frames']:7d} {row['seconds']:8.2f} {fps:9.1f} {final:>11s} "
            f"{row['peak_mib']:9.1f}"
        )
    t250, t500 = rows["trench-250"], rows["trench-500"]
    ratio = t500["seconds"] / t250["seconds"]
    per_cell = (t500["seconds"] / t500["cell_frames"]) / (t250["seconds"] / t250["cell_frames"])
    print()
    print(
        f"linear cost: time(500 frames) / time(250 frames) = {ratio:.2f} (2.00 is linear); "
        f"time per cell-frame ratio = {per_cell:.2f}"
    )
    symbac = rows.get(f"symbac-{args.symbac_frames} (SyMBac 0.5.2)")
    if isinstance(symbac, dict):
        ours = rows[compare]
        speedup = (ours["frames"] / ours["seconds"]) / (symbac["frames"] / symbac["seconds"])
        print(
            f"napari-symbac / SyMBac frames/s, same trench settings and {args.symbac_frames} "
            f"frames: {speedup:.0f}x (SyMBac uses 100 physics substeps per frame)"
        )


if __name__ == "__main__":
    main()
