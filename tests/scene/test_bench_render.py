"""benchmarks/bench_render.py's measuring functions: the dicts a harness imports.

Structure and consistency only (no timing is asserted): every key is there, the
times are positive and the ratios are the quotients they claim to be.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    path = REPO_ROOT / "benchmarks" / "bench_render.py"
    spec = importlib.util.spec_from_file_location("bench_render", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_measure_trench_frame(bench):
    result = bench.measure_trench_frame(rounds=2)
    assert result["camera_shape"] == (256, 46)
    assert result["render_shape"] == (868, 238)
    for key in ("draw_s", "clean_s", "noise_s", "masks_s", "frame_s", "fft_floor_s"):
        assert result[key] > 0, key
    assert result["render_s"] == pytest.approx(result["clean_s"] + result["noise_s"])
    assert result["frame_over_floor"] == pytest.approx(result["frame_s"] / result["fft_floor_s"])


def test_measure_field_draw(bench):
    result = bench.measure_field_draw(128, 4, rounds=1)
    assert (result["size_px"], result["n_cells"]) == (128, 4)
    assert result["render_shape"] == (128 * 3 + 100, 128 * 3 + 100)
    assert result["draw_masks_s"] == pytest.approx(result["draw_s"] + result["masks_s"])
    assert result["draw_masks_over_floor"] == pytest.approx(
        result["draw_masks_s"] / result["fft_floor_s"]
    )


def test_colony_cells_fill_the_field_without_leaving_it(bench):
    cells, curvature, side = bench.colony_cells(256, 20, seed=3)
    assert side == pytest.approx(256 * 0.065)
    assert cells.ids.tolist() == list(range(1, 21))
    assert np.all((cells.x_um > 0) & (cells.x_um < side) & (cells.y_um > 0) & (cells.y_um < side))
    assert set(curvature) == set(cells.ids[::5].tolist())
    again, _, _ = bench.colony_cells(256, 20, seed=3)
    np.testing.assert_array_equal(again.angle_rad, cells.angle_rad)
    with pytest.raises(ValueError, match="fewer cells or a larger field"):
        bench.colony_cells(96, 12)
