"""Time to fit a 256 x 46 trench and open fields of growing cell count.

Run: ``python benchmarks/bench_fit.py [--large] [--compare OLD_SRC]``. The reference is
the FFT floor (``napari_symbac.bench.timing.fft_floor``) of one render-resolution frame
(upsample 3 plus the PSF border) with the phase kernel, timed in the same run, so
the ratios travel between machines. The second table is the cost of
:func:`fit_scene` against the number of cells (fluorescence, open 256 x 256 field at
80 nm, camera estimated; ``--large``
adds a 512 x 512 field with 100 cells). The real trench (``../shared/data/real``,
or ``NAPARI_SYMBAC_REAL_DATA``) is timed when present. Prints tables; asserts
nothing.

``--compare OLD_SRC`` times the same fits with another checkout's ``src`` (e.g. one
unpacked by ``git archive``) and this one, alternately in fresh processes, so that
both see the same load: the before/after table of docs/fitting.md.

The measuring functions live in :mod:`napari_symbac.bench.cases_fit`
(``measure_fit_trench``, ``measure_fit_field``, ``measure_fit_parameters``), shared
with ``napari-symbac bench``; ``--compare`` needs them in both checkouts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from napari_symbac.bench.cases_fit import (
    measure_fit_field,
    measure_fit_parameters,
    measure_fit_trench,
)


def _in_process(src: str, call: str) -> dict:
    """Run ``call`` (an expression on this module) with ``src`` first on the path."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([src, str(Path(__file__).parent)]))
    code = f"import json, bench_fit; print(json.dumps(bench_fit.{call}))"
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(old_src: str, calls: tuple[str, ...]) -> list[tuple[str, dict, dict]]:
    """Each of ``calls`` with ``old_src`` and with this checkout, one after the other."""
    new_src = str(Path(__file__).resolve().parents[1] / "src")
    return [(call, _in_process(old_src, call), _in_process(new_src, call)) for call in calls]


def main() -> None:
    if "--compare" in sys.argv:
        old = sys.argv[sys.argv.index("--compare") + 1]
        calls = ["measure_fit_trench(bench_fit._real_trench())", "measure_fit_field(256, 36)"]
        if "--large" in sys.argv:
            calls.append("measure_fit_field(512, 100)")
        print(f"| {'measurement':<28} | {'key':<18} | {'before':>9} | {'after':>9} |")
        print(f"|{'-' * 30}|{'-' * 20}|{'-' * 11}|{'-' * 11}|")
        for call, before, after in compare(old, tuple(calls)):
            for key in after:
                b, a = before.get(key, float("nan")), after[key]
                if isinstance(a, list):  # render_shape
                    continue
                print(f"| {call:<28} | {key:<18} | {b:9.3f} | {a:9.3f} |")
        return
    fp = measure_fit_parameters()
    reference = fp["fft_s"]
    trench = measure_fit_trench(_real_trench())
    rows = [
        ("plain FFT convolution (reference)", reference, None),
        ("fit_parameters, pixel term (true scene)", fp["pixel_s"], fp["pixel_renders"]),
        ("fit_parameters, statistics terms", fp["statistics_s"], fp["statistics_renders"]),
        (
            f"fit_scene, synthetic (chi2 {trench['synthetic_chi2']:.2f})",
            trench["synthetic_s"],
            trench["synthetic_renders"],
        ),
    ]
    if "real_s" in trench:
        rows.append(
            (
                f"fit_scene, real trench ({trench['real_cells']} cells, chi2 "
                f"{trench['real_chi2']:.2f})",
                trench["real_s"],
                trench["real_renders"],
            )
        )
    print("256 x 46 trench\n")
    print(f"| {'step':<42} | {'seconds':>8} | {'x FFT':>8} | {'renders':>7} |")
    print(f"|{'-' * 44}|{'-' * 10}|{'-' * 10}|{'-' * 9}|")
    for label, seconds, renders in rows:
        n = "" if renders is None else str(renders)
        print(f"| {label:<42} | {seconds:8.3f} | {seconds / reference:8.0f} | {n:>7} |")
    print("\nfit_scene against the number of cells (fluorescence, open field, camera estimated)\n")
    print(f"| {'field':<10} | {'cells':>5} | {'found':>5} | {'seconds':>8} | {'chi2':>6} |")
    print(f"|{'-' * 12}|{'-' * 7}|{'-' * 7}|{'-' * 10}|{'-' * 8}|")
    sizes = [(256, 4), (256, 16), (256, 36)]
    if "--large" in sys.argv:
        sizes.append((512, 100))
    for side, count in sizes:
        row = measure_fit_field(side, count)
        print(
            f"| {side} x {side:<4} | {row['cells']:5d} | {row['found']:5d} | "
            f"{row['seconds']:8.1f} | {row['chi2']:6.2f} |"
        )


def _real_trench() -> np.ndarray | None:
    folder = os.environ.get("NAPARI_SYMBAC_REAL_DATA")
    root = Path(folder) if folder else Path(__file__).resolve().parents[2] / "shared/data/real"
    path = root / "ecoli_100x_oil_exponential.tiff"
    if not path.is_file():
        return None
    import tifffile

    return tifffile.imread(path)


if __name__ == "__main__":
    main()
