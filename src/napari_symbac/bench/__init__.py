"""``napari-symbac bench``: every benchmark of the project in one table.

Each row is a cost of this project (simulation frames/s, cold and cached render per
frame, slider latency, fit time, export images/s, peak memory), shown beside its ratio
to a plain FFT convolution of the same frame timed in the same round and, when an
interpreter with SyMBac 0.5.2 is given, SyMBac's cost at the same settings measured in
the same round (a subprocess: SyMBac is never a dependency). Rounds alternate which tool
runs first and the table shows the median and range over the rounds.

>>> from napari_symbac.bench import BenchConfig, run_rows
>>> result = run_rows(BenchConfig.make(quick=True))  # doctest: +SKIP

New measurements plug in through :func:`register` and :data:`ROWS` (see
:mod:`napari_symbac.bench.registry`).
"""

from __future__ import annotations

from collections.abc import Callable

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import BENCHMARKS, ROWS, Row, register
from napari_symbac.bench.run import BenchResult, RowResult, run_bench

__all__ = [
    "BENCHMARKS",
    "ROWS",
    "BenchConfig",
    "BenchResult",
    "Row",
    "RowResult",
    "register",
    "run_bench",
    "run_rows",
]


def run_rows(config: BenchConfig, log: Callable[[str], None] = print) -> BenchResult:
    """Run every row of the table (registers the benchmarks on first use)."""
    import napari_symbac.bench.rows  # noqa: F401  (fills ROWS)

    return run_bench(config, list(ROWS), log)
