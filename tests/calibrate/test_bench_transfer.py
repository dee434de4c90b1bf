"""benchmarks/bench_transfer.py --quick: the whole protocol on tiny sizes, every row."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_transfer.py"


def _bench():
    if "bench_transfer" not in sys.modules:
        spec = importlib.util.spec_from_file_location("bench_transfer", BENCH)
        module = importlib.util.module_from_spec(spec)
        sys.modules["bench_transfer"] = module  # dataclasses look their module up there
        spec.loader.exec_module(module)
    return sys.modules["bench_transfer"]


def test_metrics_of_a_known_prediction():
    bench = _bench()
    truth = np.zeros((40, 40), np.int32)
    truth[5:15, 5:25] = 1
    truth[25:35, 5:25] = 2
    pred = np.zeros_like(truth)
    pred[5:15, 5:27] = 7  # 2 px longer: IoU 200 / 220
    pred[0:3, 30:33] = 8  # a false positive
    result = bench.match(truth, pred)
    assert (result["tp"], result["fp"], result["fn"]) == (1, 1, 1)
    assert result["ious"] == [pytest.approx(200 / 220)]
    assert result["dl_px"] == [pytest.approx(2.0, abs=0.3)]
    assert result["dw_px"] == [pytest.approx(0.0)]
    summary = bench.summarise([result], [0.1])
    assert summary["f1"] == pytest.approx(0.5)
    assert summary["length_bias_um"] == pytest.approx(0.2, abs=0.03)
    t = bench.targets(truth)
    assert set(np.unique(t).tolist()) == {0, 1, 2}
    assert t[10, 15] == 1  # interior
    assert t[5, 15] == 2  # boundary


def test_objects_touching_the_border_are_dropped():
    bench = _bench()
    labels = np.zeros((20, 30), np.int32)
    labels[0:4, 5:9] = 3  # touches the top edge
    labels[8:12, 26:30] = 4  # touches the right edge
    labels[8:12, 10:15] = 5  # inside
    labels[19, 0] = 6  # a corner pixel
    out = bench.drop_border_objects(labels)
    assert set(np.unique(out).tolist()) == {0, 5}
    assert (out[8:12, 10:15] == 5).all()
    assert labels[0, 5] == 3  # the input is not changed


def test_colicoords_annotations_hold_no_cell_cut_by_the_border(real_data_dir, monkeypatch):
    """The convention the benchmark's border rule rests on (docs/proof.md)."""
    monkeypatch.setenv("NAPARI_SYMBAC_REAL_DATA", str(real_data_dir))
    bench = _bench()
    images, _ = bench.load_colicoords(bench.Budget())
    assert len(images) == 10
    for im in images:
        assert not im.border_annotated
        assert (bench.drop_border_objects(im.masks) == im.masks).all()


def test_false_positives_and_their_gallery():
    bench = _bench()
    truth = np.zeros((60, 60), np.int32)
    truth[10:20, 10:30] = 1
    pred = np.zeros_like(truth)
    pred[10:20, 10:29] = 4  # matched (IoU 0.95)
    pred[40:46, 40:46] = 9  # false positive
    pred[10:20, 29:30] = 0
    assert bench.false_positives(truth, pred) == [9]
    image = np.random.default_rng(0).normal(10, 1, truth.shape)
    real = bench.RealImage("x", image, truth, 0.1)
    gallery = bench.false_positive_gallery([real], [pred], half_px=8)
    assert gallery.shape == (18, 18, 3)
    assert gallery.dtype == np.uint8
    red = (gallery[..., 0] == 255) & (gallery[..., 1] == 51)
    assert red.any()  # the false positive's outline
    blue = (gallery == (0, 153, 255)).all(axis=-1)
    assert not blue.any()  # no annotation within 8 px of it
    whole = bench.false_positive_gallery([real], [np.where(pred == 9, 0, pred)], half_px=40)
    assert whole is None  # the matched cell is no false positive


def test_seed_means_pool_each_method_over_its_seeds():
    bench = _bench()
    rows = [
        {"method": "Otsu + watershed", "f1": 0.6, "width_bias_um": 0.0},
        {"method": "U-Net, real (seed 0)", "f1": 0.8, "width_bias_um": 0.1},
        {"method": "U-Net, real (seed 1)", "f1": 0.9, "width_bias_um": 0.3},
        {"method": "U-Net, synthetic (seed 3)", "f1": 0.7, "width_bias_um": -0.2},
    ]
    means = bench.seed_means(rows)
    assert [m["method"] for m in means] == ["U-Net, real"]  # one seed: no mean
    assert means[0]["seeds"] == 2
    assert means[0]["f1_mean"] == pytest.approx(0.85)
    assert means[0]["f1_sd"] == pytest.approx(0.1 / math.sqrt(2))
    assert means[0]["width_bias_mean_um"] == pytest.approx(0.2)
    assert "| U-Net, real | 2 | 0.850 (0.071) | +0.200 (0.141) |" in bench.seed_means_table(rows)
    assert bench.seed_means_table(rows[:1]) == ""
    unmatched = [{**r, "width_bias_um": math.nan} for r in rows[1:3]]
    (mean,) = bench.seed_means(unmatched)  # no cell matched: no width, no warning
    assert math.isnan(mean["width_bias_mean_um"])
    assert mean["f1_mean"] == pytest.approx(0.85)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("data", "baseline_seeds"), [("colicoords", ()), ("colicoords-brightfield", (0, 1))]
)
def test_quick_run_has_every_row(real_data_dir, tmp_path, monkeypatch, data, baseline_seeds):
    monkeypatch.setenv("NAPARI_SYMBAC_REAL_DATA", str(real_data_dir))
    bench = _bench()
    seeds_args = ["--baseline-seeds", *map(str, baseline_seeds)] if baseline_seeds else []
    rows = bench.main(["--quick", "--data", data, "--out", str(tmp_path), *seeds_args])
    methods = [r["method"] for r in rows]
    real = "U-Net, real annotations (leave-one-image-out)"
    real_rows = [
        f"{real}{fields}{f' (seed {seed})' if baseline_seeds else ''}"
        for seed in baseline_seeds or (0,)
        for fields in ("", ", fields 2-10")
    ]
    assert methods == [
        "Otsu + watershed",
        "Otsu + watershed, fields 2-10",
        *real_rows,
        "U-Net, calibrated synthetic only (seed 0)",
        "U-Net, calibrated synthetic only (seed 1)",
        "U-Net, calibrated with field 1's masks, fields 2-10 (seed 0)",
        "U-Net, calibrated with field 1's masks, fields 2-10 (seed 1)",
        "U-Net, tool defaults (modality switched)",
    ]
    assert "masks grown" in rows[len(real_rows) + 4]["note"]
    for row in rows:
        assert 0 <= row["f1"] <= 1
        assert 0 <= row["pixel_iou"] <= 1
        assert math.isfinite(row["seconds"])
    assert (tmp_path / f"results_{data}.json").is_file()
    # the versions the numbers came from (found: a rerun of one commit differed by 0.08)
    versions = json.loads((tmp_path / f"versions_{data}.json").read_text())
    assert versions["numpy"] == np.__version__
    assert set(versions) == set(bench.RESULT_PACKAGES)
    assert (tmp_path / f"transfer_{data}_prediction.png").is_file()
    table = bench.table(rows)
    assert table.count("\n") == len(rows) + 1


@pytest.mark.slow
def test_packing_table_measures_real_and_synthetic_colonies(real_data_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("NAPARI_SYMBAC_REAL_DATA", str(real_data_dir))
    bench = _bench()
    rows = bench.main(["--data", "omnipose", "--quick", "--packing", "--out", str(tmp_path)])
    assert len(rows) == 9  # 3 colonies x (real, uncompacted, calibrated)
    real, loose, calibrated = rows[3:6]
    assert real["data"] == "Sample000193 real"
    assert real["overlap_widths_p95"] is None
    for row in (real, loose, calibrated):
        assert row["cells"] > 0
        assert 0 < row["cell_fraction"] <= 1
        assert row["length_um"][0] <= row["length_um"][1] <= row["length_um"][2]
    assert calibrated["overlap_widths_p95"] >= 0
    assert (tmp_path / "packing_omnipose.json").is_file()
    assert bench.packing_table(rows).count("\n") == len(rows) + 1
