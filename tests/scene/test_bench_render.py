"""The render measuring functions of napari_symbac.bench.cases_render (``napari-symbac
bench`` and benchmarks/bench_render.py).

Structure and consistency only (no timing is asserted): every key is there, the
times are positive and the ratios are the quotients they claim to be.
"""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.bench import cases_render


@pytest.fixture(scope="module")
def bench():
    return cases_render


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
    assert result["media_s"] > 0  # the media image is made on its first read
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


def test_measure_cached_paths(bench):
    result = bench.measure_cached_paths(rounds=2)
    for key in ("cold_cached_s", "rerender_s", "rfft2_s", "fft_floor_s"):
        assert result[key] > 0, key
    assert result["rerender_over_rfft2"] == pytest.approx(result["rerender_s"] / result["rfft2_s"])


def test_trench_frame_at_another_psf_radius_has_a_larger_frame(bench):
    result = bench.measure_trench_frame(rounds=1, psf_radius_px=20)
    assert result["render_shape"] == (256 * 3 + 40, 46 * 3 + 40)
    assert result["fft_floor_s"] > 0
