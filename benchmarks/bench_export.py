"""Export throughput: wall time, images per second with 1 and 2 workers, peak memory.

A thin script over the harness of ``napari-symbac bench`` (``napari_symbac.bench``):
each configuration exports ``--n`` trench images (omnipose TIFF pairs, 60-frame
simulation) in a fresh process (``napari_symbac.bench.export_child``), so its peak
memory is its own; rounds alternate the configurations (and SyMBac 0.5.2, when
``--symbac-python`` names an interpreter that has it) so that the ratios hold on a
shared machine. Prints the table of docs/export.md ("Throughput"): tool, workers, wall
s, images/s, steady images/s, peak main MiB, peak worker MiB and the 1-minute load
average when each run started; nothing is asserted.

    python benchmarks/bench_export.py --n 300 --rounds 3 --symbac-python venv/bin/python
"""

from __future__ import annotations

import argparse
import dataclasses
import os

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.run import trench_shapes
from napari_symbac.bench.subprocesses import check_symbac_python, export_run, symbac_run

SYMBAC = "SyMBac 0.5.2"
#: Columns after tool and workers: (header, key of a run's numbers, decimals).
COLUMNS = (
    ("wall s", "wall_s", 1),
    ("images/s", "rate", 1),
    ("steady images/s", "steady", 1),
    ("peak main MiB", "peak_main_mib", 0),
    ("peak worker MiB", "peak_worker_mib", 0),
    ("load", "load", 1),
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="images per run (default 300)")
    parser.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--symbac-python", help="python of a venv where SyMBac 0.5.2 is installed")
    args = parser.parse_args(argv)
    python = None if args.symbac_python is None else check_symbac_python(args.symbac_python)
    # SyMBac's run: a 60-frame simulation (as the export's), 2 frames of its render path
    config = dataclasses.replace(
        BenchConfig.make(quick=False, symbac_python=python),
        export_images=args.n,
        trench_frames=60,
        render_frames=2,
    )
    shapes = trench_shapes()
    rows: dict[str, list[dict[str, float | None]]] = {f"{w} worker(s)": [] for w in args.workers}
    rows[SYMBAC] = []
    for k in range(args.rounds):
        order = list(args.workers) + (["symbac"] if python else [])
        for what in order if k % 2 == 0 else order[::-1]:
            load = os.getloadavg()[0]
            if what == "symbac":
                result = symbac_run(config, *shapes)
                rows[SYMBAC].append(symbac_numbers(result, args.n, load))
            else:
                result = export_run(config, what)
                rows[f"{what} worker(s)"].append(export_numbers(result, load))
            print(f"round {k + 1} {what}: {result}", flush=True)
    print(f"\n{args.n} trench images per run, {args.rounds} round(s) (median, range)")
    print(table(rows))
    if python and rows[SYMBAC]:
        theirs = [r["rate"] for r in rows[SYMBAC]]
        for w in args.workers:
            ours = [r["rate"] for r in rows[f"{w} worker(s)"]]
            ratios = [a / b for a, b in zip(ours, theirs)]
            print(f"{w} worker(s) / SyMBac images/s, round by round: {_spread(ratios, 1)}")
    return 0


def export_numbers(result: dict[str, float], load: float) -> dict[str, float | None]:
    """The table's numbers of one ``export_run`` (``peak_worker_mib``: None in one process)."""
    return {
        "workers": result["workers"],
        "wall_s": result["wall_s"],
        "rate": 1 / result["image_s"],
        "steady": 1 / result["steady_image_s"],
        "peak_main_mib": result["peak_mib"],
        "peak_worker_mib": result.get("peak_worker_mib"),
        "load": load,
    }


def symbac_numbers(result: dict[str, float], n: int, load: float) -> dict[str, float | None]:
    """The table's numbers of one ``symbac_run`` of ``n`` images (one process, no workers).

    Its wall seconds are ``n`` times its overall cost per image: its simulation, OPL
    drawing and ``generate_training_data``, each timed in the run (its imports and PSF
    set-up are not counted); steady is its rendering and saving only.
    """
    return {
        "workers": 1.0,
        "wall_s": n * result["export_overall_s_per_image"],
        "rate": 1 / result["export_overall_s_per_image"],
        "steady": 1 / result["export_s_per_image"],
        "peak_main_mib": result["peak_mib"],
        "peak_worker_mib": None,
        "load": load,
    }


def table(rows: dict[str, list[dict[str, float | None]]]) -> str:
    """Markdown: one line per configuration run, median (range) over its rounds."""
    lines = [
        "| tool | workers | " + " | ".join(header for header, _, _ in COLUMNS) + " |",
        "|---" * (2 + len(COLUMNS)) + "|",
    ]
    for name, runs in rows.items():
        if not runs:
            continue
        tool = SYMBAC if name == SYMBAC else "napari-symbac"
        cells = [tool, _workers([r["workers"] for r in runs])]
        for _, key, decimals in COLUMNS:
            values = [r[key] for r in runs if r[key] is not None]
            cells.append(_spread(values, decimals) if values else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _workers(values: list[float | None]) -> str:
    """Workers that wrote (``2 (LocalCluster)``); several if the rounds differ."""
    counts = sorted({int(v) for v in values if v is not None})
    text = "/".join(map(str, counts))
    return f"{text} (LocalCluster)" if counts and counts[-1] > 1 else text


def _spread(values: list[float], decimals: int) -> str:
    median, low, high = (f"{v:.{decimals}f}" for v in (np.median(values), min(values), max(values)))
    return median if low == high else f"{median} ({low}-{high})"


if __name__ == "__main__":
    raise SystemExit(main())
