"""``napari-symbac bench``: the quick run prints a table with every row."""

from __future__ import annotations

import json
import math

import pytest

from napari_symbac.bench import ROWS, BenchConfig
from napari_symbac.bench.report import markdown
from napari_symbac.bench.run import BenchResult, RowResult, Spread
from napari_symbac.cli import main


@pytest.mark.slow
def test_quick_bench_prints_every_row_and_writes_outputs(tmp_path, capsys):
    assert main(["bench", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    config = BenchConfig.make(quick=True)
    table = [line for line in out.splitlines() if line.startswith("| ")][1:]
    labels = [row.label.format(**config.__dict__) for row in ROWS]
    assert [line.split(" | ")[0][2:] for line in table] == labels
    document = json.loads((tmp_path / "bench.json").read_text())
    assert [row["label"] for row in document["rows"]] == labels
    gpu = _has_cuda()
    for spec, row in zip(ROWS, document["rows"], strict=True):
        if row["label"].startswith("GPU") and not gpu:
            assert row["ours"] is None
            assert row["note"] == "unmeasured: no CUDA GPU here"
            continue
        if spec.benchmark == "field_draw_2048":  # the 2048 field is not drawn with --quick
            assert row["ours"] is None
            assert row["note"] == "not run with --quick"
            continue
        # every other row measured (the gui extra is installed in the tests), costs positive
        assert row["ours"] is not None, row["note"]
        assert 0 < row["ours"]["low"] <= row["ours"]["median"] <= row["ours"]["high"]
        if spec.fft_key is not None:
            assert math.isfinite(row["x_fft"]["median"]), row
            assert row["x_fft"]["median"] > 0, row
        else:
            assert row["x_fft"] is None, row
        # no SyMBac interpreter given: no SyMBac figure, no ratio
        assert row["symbac"] is None
        assert row["symbac_over_ours"] is None
    assert (tmp_path / "bench.md").read_text().strip() in out
    scaling = document["scaling"]
    assert len(scaling["psf"]["frame_s"]) == len(scaling["psf"]["radius_px"]) == 4
    assert (tmp_path / "scaling.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _has_cuda() -> bool:
    from napari_symbac.bench.cases_gpu import available

    return ("torch:cuda", None) in available()


def test_table_shows_rates_skips_and_symbac_ratios():
    spread = Spread(0.01, 0.005, 0.02)
    rows = [
        RowResult("frames", "per_s", "frames/s", spread, Spread(2, 1, 3), spread, Spread(8, 7, 9)),
        RowResult(
            "slider", "ms", "", None, None, None, None, "skipped: no napari", "SyMBac has none"
        ),
    ]
    machine = {
        "napari_symbac": "0", "cores": 2, "memory_gib": 1, "processor": "x", "python": "3",
        "numpy": "2", "scipy": "1", "date_utc": "now", "load_average_start": [1.0, 1, 1],
        "load_average_end": [2.0, 2, 2],
    }  # fmt: skip
    text = markdown(BenchResult(BenchConfig.make(True), rows, [], machine))
    # a cost of 10 ms per frame (5-20 ms) is 100 frames/s (50-200)
    assert "| frames | frames/s | 100 (50.0-200) | 2.00x (1.00-3.00) | 100 (50.0-200) |" in text
    assert "| 8.00x (7.00-9.00) |" in text
    assert "| slider | ms | skipped: no napari |  | SyMBac has none |  |" in text


def test_bench_refuses_an_interpreter_without_symbac(tmp_path, capsys):
    fake = tmp_path / "python"
    fake.write_text("not a program")
    assert main(["bench", "--quick", "--symbac-python", str(fake)]) == 2
    err = capsys.readouterr().err
    assert "not an executable file" in err
    # how to make one, with or without a source checkout (found as a user: the script
    # the message named is not installed with the package)
    assert "python -m venv DIR && DIR/bin/pip install SyMBac==0.5.2" in err
    assert "tools/make-symbac-env.sh DIR in a source checkout" in err
