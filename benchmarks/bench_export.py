"""Export throughput: images per second with 1 and 2 workers, and peak memory.

A thin script over the harness of ``napari-symbac bench`` (``napari_symbac.bench``):
each configuration exports ``--n`` trench images (omnipose TIFF pairs, 60-frame
simulation) in a fresh process (``napari_symbac.bench.export_child``), so its peak
memory is its own; rounds alternate the configurations (and SyMBac 0.5.2, when
``--symbac-python`` names an interpreter that has it) so that the ratios hold on a
shared machine. Prints a table; nothing is asserted.

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
    rows: dict[str, list[dict]] = {f"{w} worker(s)": [] for w in args.workers}
    rows["SyMBac 0.5.2"] = []
    for k in range(args.rounds):
        order = list(args.workers) + (["symbac"] if python else [])
        for what in order if k % 2 == 0 else order[::-1]:
            load = os.getloadavg()[0]
            if what == "symbac":
                result = symbac_run(config, *shapes)
                rate = 1 / result["export_overall_s_per_image"]
                rows["SyMBac 0.5.2"].append(
                    {"rate": rate, "steady": 1 / result["export_s_per_image"],
                     "peak": result["peak_mib"], "load": load}
                )  # fmt: skip
            else:
                result = export_run(config, what)
                rows[f"{what} worker(s)"].append(
                    {"rate": 1 / result["image_s"], "steady": 1 / result["steady_image_s"],
                     "peak": result["peak_mib"], "load": load}
                )  # fmt: skip
            print(f"round {k + 1} {what}: {result}", flush=True)
    print(f"\n{args.n} trench images per run, {args.rounds} rounds (median, range)")
    print("| run | images/s overall | images/s steady | peak MiB (main process) | load |")
    print("|---|---|---|---|---|")
    for name, runs in rows.items():
        if not runs:
            continue
        cols = [_spread([r[key] for r in runs]) for key in ("rate", "steady", "peak", "load")]
        print(f"| {name} | " + " | ".join(cols) + " |")
    if python and rows["SyMBac 0.5.2"]:
        theirs = [r["rate"] for r in rows["SyMBac 0.5.2"]]
        for w in args.workers:
            ours = [r["rate"] for r in rows[f"{w} worker(s)"]]
            ratios = [a / b for a, b in zip(ours, theirs)]
            print(f"{w} worker(s) / SyMBac images/s, round by round: {_spread(ratios)}")
    return 0


def _spread(values: list[float]) -> str:
    return f"{np.median(values):.1f} ({min(values):.1f}-{max(values):.1f})"


if __name__ == "__main__":
    raise SystemExit(main())
