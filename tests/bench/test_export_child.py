"""The export rows' child (``napari_symbac.bench.export_child``) and the table that
benchmarks/bench_export.py prints from it (the columns of docs/export.md)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from napari_symbac.bench import export_child

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_export.py"


def _bench():
    if "bench_export" not in sys.modules:
        spec = importlib.util.spec_from_file_location("bench_export", BENCH)
        module = importlib.util.module_from_spec(spec)
        sys.modules["bench_export"] = module
        spec.loader.exec_module(module)
    return sys.modules["bench_export"]


@pytest.mark.slow
def test_two_worker_export_reports_the_workers_peak_memory(monkeypatch):
    monkeypatch.setenv("NAPARI_SYMBAC_CLUSTER_START_S", "0")  # always start the cluster
    result = export_child.run(6, 2, "omnipose")
    assert result["workers"] == 2
    assert result["wall_s"] > 0
    assert result["wall_s"] == pytest.approx(6 * result["image_s"])
    assert 0 < result["peak_worker_mib"] < 10_000
    assert result["peak_mib"] > 0


def test_one_process_export_has_no_worker_peak():
    result = export_child.run(2, 1, "omnipose")
    assert result["workers"] == 1
    assert "peak_worker_mib" not in result


def test_table_has_the_columns_of_the_docs():
    bench = _bench()
    ours = {"image_s": 0.02, "steady_image_s": 0.016, "wall_s": 20.0, "workers": 1.0,
            "peak_mib": 280.4, "fft_s": 0.002}  # fmt: skip
    cluster = {**ours, "image_s": 0.04, "wall_s": 40.0, "workers": 2.0, "peak_worker_mib": 320.0}
    symbac = {"export_overall_s_per_image": 0.25, "export_s_per_image": 0.2, "peak_mib": 600.0}
    rows = {
        "1 worker(s)": [bench.export_numbers(ours, 1.0), bench.export_numbers(ours, 3.0)],
        "2 worker(s)": [bench.export_numbers(cluster, 1.5)],
        "SyMBac 0.5.2": [bench.symbac_numbers(symbac, 300, 2.0)],
    }
    lines = bench.table(rows).splitlines()
    assert lines[0] == (
        "| tool | workers | wall s | images/s | steady images/s | peak main MiB | "
        "peak worker MiB | load |"
    )
    assert lines[2] == "| napari-symbac | 1 | 20.0 | 50.0 | 62.5 | 280 | - | 2.0 (1.0-3.0) |"
    assert lines[3] == (
        "| napari-symbac | 2 (LocalCluster) | 40.0 | 25.0 | 62.5 | 280 | 320 | 1.5 |"
    )
    assert lines[4] == "| SyMBac 0.5.2 | 1 | 75.0 | 4.0 | 5.0 | 600 | - | 2.0 |"
