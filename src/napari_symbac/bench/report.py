"""The table of a benchmark run: markdown on the terminal, markdown + JSON in ``--out``."""

from __future__ import annotations

import json
from pathlib import Path

from napari_symbac.bench.run import BenchResult, RowResult, Spread

__all__ = ["markdown", "write_outputs"]

_SCALE = {"per_s": 1.0, "ms": 1e3, "s": 1.0, "MiB": 1.0, "ratio": 1.0}


def _value(spread: Spread | None, unit: str) -> str:
    if spread is None:
        return ""
    if unit == "per_s":  # a cost per unit shown as a rate: the range flips
        values = (1 / spread.median, 1 / spread.high, 1 / spread.low)
    else:
        values = tuple(v * _SCALE[unit] for v in (spread.median, spread.low, spread.high))
    median, low, high = (_fmt(v) for v in values)
    return median if low == high else f"{median} ({low}-{high})"


def _ratio(spread: Spread | None) -> str:
    if spread is None:
        return ""
    median, low, high = (_fmt(v) for v in (spread.median, spread.low, spread.high))
    return f"{median}x" if low == high else f"{median}x ({low}-{high})"


def _fmt(value: float) -> str:
    if value >= 100:
        return f"{value:.0f}"
    if value >= 10:
        return f"{value:.1f}"
    if value >= 0.1:
        return f"{value:.2f}"
    return f"{value:.2g}"


def _unit(row: RowResult) -> str:
    return row.rate_name if row.unit == "per_s" else row.unit


def markdown(result: BenchResult) -> str:
    """The table (one line per row) with a header naming the machine and the run."""
    m, c = result.machine, result.config
    lines = [
        f"napari-symbac {m['napari_symbac']} benchmarks ({'quick' if c.quick else 'full'}, "
        f"{c.repeats} round(s), {result.seconds:.0f} s): {m['cores']} cores, "
        f"{m['memory_gib']} GiB, {m['processor']}, Python {m['python']}, numpy {m['numpy']}, "
        f"scipy {m['scipy']}; load average {_load(m)}; {m['date_utc']} UTC",
        "",
        "| measurement | unit | napari-symbac | our cost / FFT floor | SyMBac 0.5.2 "
        "| SyMBac's cost / ours |",
        "|---|---|---|---|---|---|",
    ]
    for row in result.rows:
        ours = _value(row.ours, row.unit) if row.ours is not None else row.note
        symbac = _value(row.symbac, row.unit) if row.symbac is not None else row.symbac_note
        lines.append(
            f"| {row.label} | {_unit(row)} | {ours} | {_ratio(row.x_fft)} | {symbac} | "
            f"{_ratio(row.symbac_over_ours)} |"
        )
    lines += [
        "",
        "Median (range) over the rounds. Our cost / FFT floor: our cost / one plain FFT "
        "convolution of the same render-resolution frame with the PSF kernel "
        "(irfft2(rfft2(frame) * K), float32, fast transform lengths, the kernel's spectrum K "
        "precomputed, one thread), "
        "timed in the same round (above 1: slower than that floor). SyMBac's cost / ours: in the "
        "same round (above 1: napari-symbac is faster or smaller); rounds alternate which tool "
        "runs first.",
    ]
    return "\n".join(lines)


def _load(machine: dict) -> str:
    start, end = machine.get("load_average_start"), machine.get("load_average_end")
    if start is None:
        return "unknown"
    text = f"{start[0]:.1f} at the start"
    if end is not None:
        text += f", {end[0]:.1f} at the end (1-minute)"
    return text


def write_outputs(result: BenchResult, out_dir: str | Path) -> list[Path]:
    """``bench.md`` and ``bench.json`` in ``out_dir``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = out / "bench.md"
    md.write_text(markdown(result) + "\n", encoding="utf-8")
    js = out / "bench.json"
    js.write_text(json.dumps(result.to_json(), indent=1) + "\n", encoding="utf-8")
    return [md, js]
