"""Run every benchmark, interleaved with SyMBac 0.5.2, and aggregate the rounds."""

from __future__ import annotations

import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import BENCHMARKS, Row
from napari_symbac.bench.subprocesses import BenchSkipped, symbac_run

__all__ = ["BenchResult", "RowResult", "run_bench", "trench_shapes"]


@dataclass(frozen=True)
class Spread:
    """Median and range over the rounds."""

    median: float
    low: float
    high: float

    @classmethod
    def of(cls, values: list[float]) -> Spread | None:
        values = [v for v in values if np.isfinite(v)]
        if not values:
            return None
        return cls(float(np.median(values)), float(min(values)), float(max(values)))


@dataclass(frozen=True)
class RowResult:
    """One row: our cost, its ratio to the FFT floor, SyMBac's cost and SyMBac / ours."""

    label: str
    unit: str
    rate_name: str
    ours: Spread | None
    x_fft: Spread | None
    symbac: Spread | None
    symbac_over_ours: Spread | None
    note: str = ""
    symbac_note: str = ""


@dataclass
class BenchResult:
    """Everything a run measured: rows, the raw numbers of each round, the machine."""

    config: BenchConfig
    rows: list[RowResult]
    rounds: list[dict[str, Any]]
    machine: dict[str, Any]
    seconds: float = 0.0
    scaling: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "config": asdict(self.config),
            "machine": self.machine,
            "seconds": self.seconds,
            "rows": [asdict(r) for r in self.rows],
            "rounds": self.rounds,
            "scaling": self.scaling,
        }


def machine_info() -> dict[str, Any]:
    """Cores, memory, load average and versions of this machine."""
    import scipy

    from napari_symbac import __version__

    memory_gib = None
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            kib = int(handle.readline().split()[1])
        memory_gib = round(kib / 2**20, 1)
    except (OSError, ValueError, IndexError):
        pass
    return {
        "cores": os.cpu_count(),
        "memory_gib": memory_gib,
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "napari_symbac": __version__,
        "load_average_start": _load(),
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
    }


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def trench_shapes() -> tuple[tuple[int, int], tuple[int, int]]:
    from napari_symbac.bench.cases_render import TRENCH_256, trench_cells
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry

    render = RenderSettings(upsample=3, psf_radius_px=50)
    scene = draw_scene(trench_cells(0.0), TrenchGeometry(**TRENCH_256), Microscope(), render)
    return scene.shape, scene.camera_shape


def _measure(name: str, config: BenchConfig) -> dict[str, Any]:
    try:
        return BENCHMARKS[name](config)
    except BenchSkipped as skip:
        return {"skipped": str(skip)}
    except Exception as err:  # a failed benchmark is a row's note, not the end of the run
        return {"error": f"{type(err).__name__}: {err}"[:300]}


def run_bench(
    config: BenchConfig, rows: list[Row], log: Callable[[str], None] = print
) -> BenchResult:
    """Run ``config.repeats`` rounds of every benchmark of ``rows`` and SyMBac's run.

    Rounds alternate the order of the two tools (ours then SyMBac, SyMBac then ours)
    so that a change of load on a shared machine falls on both.
    """
    start = time.perf_counter()
    machine = machine_info()
    names = list(dict.fromkeys(row.benchmark for row in rows))
    shapes = trench_shapes()
    rounds = []
    for k in range(config.repeats):
        tools = ["ours", "symbac"] if k % 2 == 0 else ["symbac", "ours"]
        measured: dict[str, Any] = {}
        for tool in tools:
            if tool == "symbac":
                if config.symbac_python is None:
                    continue
                log(f"round {k + 1}/{config.repeats}: SyMBac 0.5.2")
                try:
                    measured["symbac"] = symbac_run(config, *shapes)
                except Exception as err:
                    measured["symbac"] = {"error": f"{type(err).__name__}: {err}"[:300]}
                continue
            for name in names:
                log(f"round {k + 1}/{config.repeats}: {name}")
                measured[name] = _measure(name, config)
        rounds.append(measured)
    machine["load_average_end"] = _load()
    return BenchResult(
        config=config,
        rows=[_aggregate(row, rounds, config) for row in rows],
        rounds=rounds,
        machine=machine,
        seconds=time.perf_counter() - start,
    )


def _aggregate(row: Row, rounds: list[dict[str, Any]], config: BenchConfig) -> RowResult:
    ours, x_fft, theirs, ratio, notes = [], [], [], [], []
    for measured in rounds:
        got = measured.get(row.benchmark, {})
        for key in ("skipped", "error"):
            if key in got:
                notes.append(got[key])
        value = got.get(row.key)
        if value is None:
            continue
        ours.append(value)
        if row.fft_key is not None and got.get(row.fft_key):
            x_fft.append(value / got[row.fft_key])
        symbac = measured.get("symbac", {})
        if row.symbac_key is not None and symbac.get(row.symbac_key) is not None:
            theirs.append(symbac[row.symbac_key])
            ratio.append(symbac[row.symbac_key] / value)
    symbac_errors = [m["symbac"]["error"] for m in rounds if "error" in m.get("symbac", {})]
    if row.symbac_key is None:
        symbac_note = row.symbac_note
    elif config.symbac_python is None:
        symbac_note = "not measured (no --symbac-python)"
    else:
        symbac_note = symbac_errors[0] if symbac_errors and not theirs else ""
    note = "; ".join(dict.fromkeys(notes))
    return RowResult(
        label=row.label.format(**asdict(config)),
        unit=row.unit,
        rate_name=row.rate_name,
        ours=Spread.of(ours),
        x_fft=Spread.of(x_fft),
        symbac=Spread.of(theirs),
        symbac_over_ours=Spread.of(ratio),
        note=note,
        symbac_note=symbac_note,
    )


def log_to_stderr(message: str) -> None:
    print(f"napari-symbac bench: {message}", file=sys.stderr, flush=True)
