"""The benchmarks of ``napari-symbac bench``: a registry of measurements and the table's rows.

A *benchmark* is a callable ``fn(config) -> dict[str, float]`` that measures one thing of
this project (a simulation, a render path, a fit, an export) and returns plain numbers:
costs in seconds per unit (``"*_s"`` keys) or MiB, and, measured in the same call, the
seconds of one plain FFT convolution of the same frame (its *FFT floor*). A *row* of the
table picks one number of one benchmark, how to show it, and which number of the SyMBac
0.5.2 run it compares to.

Plugging in a measurement (e.g. another module's ``measure_*`` function)::

    from napari_symbac.bench import Row, register

    register("render_trench", lambda config: my_measure(quick=config.quick))
    ROWS.append(Row("my row", "render_trench", "frame_s", "ms", fft_key="fft_s"))

``register`` replaces a benchmark of the same name, so a better measurement of an
existing row only needs the ``register`` call (and the same keys).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from napari_symbac.bench.config import BenchConfig

__all__ = ["BENCHMARKS", "ROWS", "Benchmark", "Row", "register"]

Benchmark = Callable[[BenchConfig], dict[str, float]]
#: Benchmarks by name.
BENCHMARKS: dict[str, Benchmark] = {}

Unit = Literal["per_s", "ms", "s", "MiB", "ratio"]


def register(name: str, benchmark: Benchmark | None = None):
    """Register ``benchmark`` under ``name`` (usable as a decorator: ``@register(name)``)."""

    def add(fn: Benchmark) -> Benchmark:
        BENCHMARKS[name] = fn
        return fn

    return add if benchmark is None else add(benchmark)


@dataclass(frozen=True)
class Row:
    """One row of the table.

    Parameters
    ----------
    label
        What the row measures (sizes filled in from the config with ``str.format``:
        ``{colony_cells[0]}``...).
    benchmark
        Name in :data:`BENCHMARKS`.
    key
        The number of the benchmark's dict shown: a cost, seconds per unit or MiB.
    unit
        ``"per_s"`` shows ``1 / key`` (frames/s, images/s); ``"ms"`` / ``"s"`` a time;
        ``"MiB"`` memory; ``"ratio"`` a plain number (e.g. a cost at one size over
        another).
    rate_name
        Name of the unit of a ``per_s`` row (``"frames/s"``).
    fft_key
        Key of the FFT floor of the same frame in the benchmark's dict (``None``: the
        ratio does not apply, e.g. memory).
    symbac_key
        Key of SyMBac 0.5.2's cost at the same settings in the SyMBac run's dict
        (``None``: SyMBac has no such step).
    symbac_note
        Shown instead of a SyMBac figure when ``symbac_key`` is ``None``.
    """

    label: str
    benchmark: str
    key: str
    unit: Unit
    rate_name: str = ""
    fft_key: str | None = "fft_s"
    symbac_key: str | None = None
    symbac_note: str = "-"


#: The rows of the table, in order (filled by :mod:`napari_symbac.bench.cases`).
ROWS: list[Row] = []
