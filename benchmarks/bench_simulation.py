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

Each case runs in a fresh subprocess so that its peak resident memory (``ru_maxrss``)
is its own. Run with ``python benchmarks/bench_simulation.py``.

The measuring functions return dicts and can be imported (``napari-symbac bench``):
:func:`measure_trench`, :func:`measure_colony`, :func:`measure_colony_scaling`.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

SYMBAC_PYTHON = Path("/tmp/symbac-venv/bin/python")
#: Side of the agar-pad field the benchmark colonies grow in: a 4000-cell colony
#: (about 75 um across) stays well inside it, so no cell leaves the field.
COLONY_FIELD_UM = 250.0
COLONY_SIZES = (400, 1000, 4000)


def _peak_rss_mib() -> float:
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024 if platform.system() != "Darwin" else rss / 2**20


def measure_trench(frames: int = 250, length_um: float = 25.0, seed: int = 0) -> dict:
    """Simulate a mother-machine trench (1.4 um wide) for ``frames`` frames.

    Returns
    -------
    dict
        ``frames``, ``seconds`` (wall time of the whole run), ``frames_per_s``,
        ``cell_frames`` (cells summed over frames), ``final_cells``.
    """
    from napari_symbac.settings import SimulationSettings, TrenchGeometry
    from napari_symbac.sim import Simulator

    settings = SimulationSettings(
        n_frames=frames, trench=TrenchGeometry(length_um=length_um, width_um=1.4), seed=seed
    )
    start = time.perf_counter()
    simulator = Simulator(settings)
    cells = 0
    for frame in simulator.iter_frames():
        cells += len(frame)
    seconds = time.perf_counter() - start
    return {
        "frames": frames,
        "seconds": seconds,
        "frames_per_s": frames / seconds,
        "cell_frames": cells,
        "final_cells": len(frame),
    }


def grow_colony(n_cells: int, seed: int = 0):
    """An agar-pad :class:`~napari_symbac.sim.Simulator` (one founder, a
    :data:`COLONY_FIELD_UM` square field) run until its colony has ``n_cells`` cells
    or more; returns ``(simulator, seconds)``."""
    from napari_symbac.settings import AgarPadGeometry, SimulationSettings
    from napari_symbac.sim import Simulator

    if n_cells < 1:
        raise ValueError(f"n_cells must be >= 1, got {n_cells}")
    settings = SimulationSettings(
        geometry="agar_pad",
        n_frames=100_000,
        agar_pad=AgarPadGeometry(COLONY_FIELD_UM, COLONY_FIELD_UM),
        seed=seed,
    )
    start = time.perf_counter()
    simulator = Simulator(settings)
    for frame in simulator.iter_frames():
        if len(frame) >= n_cells:
            break
    return simulator, time.perf_counter() - start


def _time_frames(simulator, frames: int) -> dict:
    cell_frames = 0
    start = time.perf_counter()
    for _ in range(frames):
        frame = simulator.step()
        cell_frames += len(frame)
    seconds = time.perf_counter() - start
    return {
        "frames": frames,
        "seconds": seconds,
        "cell_frames": cell_frames,
        "ms_per_cell_frame": 1e3 * seconds / cell_frames,
        "frames_per_s": frames / seconds,
        "final_cells": len(frame),
    }


def measure_colony(n_cells: int, frames: int = 3, seed: int = 0) -> dict:
    """Grow an agar-pad colony to ``n_cells`` cells (not timed), then time ``frames``
    more frames.

    Returns
    -------
    dict
        ``n_cells`` (asked), ``cells`` (when timing started), ``frames``, ``seconds``,
        ``cell_frames`` (cells summed over the timed frames), ``ms_per_cell_frame``,
        ``frames_per_s``, ``final_cells``, ``grow_seconds`` (the untimed growth).
    """
    simulator, grow_seconds = grow_colony(n_cells, seed)
    cells = len(simulator.result().frames[-1])
    row = _time_frames(simulator, frames)
    return {"n_cells": n_cells, "cells": cells, **row, "grow_seconds": grow_seconds}


def measure_colony_scaling(
    sizes: tuple[int, ...] = COLONY_SIZES, frames: int = 3, rounds: int = 3, seed: int = 0
) -> dict:
    """Cost per cell-frame of one agar-pad colony at several sizes, interleaved.

    The colony is grown once through all ``sizes``; its simulator is saved (pickled)
    when it first reaches each size. Then, ``rounds`` times, ``frames`` frames are
    timed from each saved state in turn, so that a change in the machine's load hits
    every size alike. (A restored simulator has the same cells and contacts, but pymunk
    rebuilds its spatial index, so its trajectory departs from an uninterrupted run's in
    the last bits; the work per frame is the same.)

    Returns
    -------
    dict
        ``sizes``: per size, ``cells`` (when timing started), ``ms_per_cell_frame``
        (best round), ``ms_per_cell_frame_median``, ``ms_per_cell_frame_rounds``,
        ``frames_per_s`` (best round); ``ratio``: best cost per cell-frame at the
        largest size over that at the smallest (1.0 is linear in cells);
        ``ratio_median``: the same from the medians; ``grow_seconds``.
    """
    sizes = tuple(sorted(sizes))
    simulator, grow_seconds = grow_colony(sizes[0], seed)
    saved: dict[int, bytes] = {}
    cells_at: dict[int, int] = {}
    cells = len(simulator.result().frames[-1])
    start = time.perf_counter()
    for size in sizes:
        while cells < size:
            cells = len(simulator.step())
        saved[size], cells_at[size] = pickle.dumps(simulator), cells
    grow_seconds += time.perf_counter() - start
    times: dict[int, list[dict]] = {size: [] for size in sizes}
    for _ in range(rounds):
        for size in sizes:
            times[size].append(_time_frames(pickle.loads(saved[size]), frames))
    out: dict = {"sizes": {}, "grow_seconds": grow_seconds, "frames": frames, "rounds": rounds}
    for size in sizes:
        per = [row["ms_per_cell_frame"] for row in times[size]]
        out["sizes"][size] = {
            "cells": cells_at[size],
            "ms_per_cell_frame": min(per),
            "ms_per_cell_frame_median": statistics.median(per),
            "ms_per_cell_frame_rounds": per,
            "frames_per_s": max(row["frames_per_s"] for row in times[size]),
        }
    small, large = out["sizes"][sizes[0]], out["sizes"][sizes[-1]]
    out["ratio"] = large["ms_per_cell_frame"] / small["ms_per_cell_frame"]
    out["ratio_median"] = large["ms_per_cell_frame_median"] / small["ms_per_cell_frame_median"]
    return out


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
        result["peak_mib"] = _peak_rss_mib()
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
