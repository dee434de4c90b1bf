"""The simulation measuring functions of napari_symbac.bench.cases_sim (``napari-symbac
bench`` and benchmarks/bench_simulation.py) return what they promise; no timing is
asserted."""

from __future__ import annotations

import pytest

from napari_symbac.bench import cases_sim


@pytest.fixture(scope="module")
def bench():
    return cases_sim


def test_measure_trench(bench):
    row = bench.measure_trench(12, length_um=10.0)
    assert row["frames"] == 12
    assert row["seconds"] > 0
    assert row["frames_per_s"] == pytest.approx(12 / row["seconds"])
    assert row["final_cells"] >= 1
    assert row["cell_frames"] >= 12


def test_measure_colony(bench):
    row = bench.measure_colony(20, frames=2)
    assert row["n_cells"] == 20
    assert row["cells"] >= 20
    assert row["frames"] == 2
    assert row["final_cells"] >= row["cells"]
    assert row["cell_frames"] >= 2 * row["cells"]
    assert row["ms_per_cell_frame"] == pytest.approx(1e3 * row["seconds"] / row["cell_frames"])
    assert row["cpu_ms_per_cell_frame"] == pytest.approx(
        1e3 * row["cpu_seconds"] / row["cell_frames"]
    )


def test_measure_colony_scaling_times_every_size_from_the_same_state(bench):
    out = bench.measure_colony_scaling((40, 12), frames=1, rounds=2)
    assert list(out["sizes"]) == [12, 40]
    small, large = out["sizes"][12], out["sizes"][40]
    assert 12 <= small["cells"] < large["cells"]
    for row in (small, large):
        assert len(row["ms_per_cell_frame_rounds"]) == 2
        assert row["ms_per_cell_frame"] == min(row["ms_per_cell_frame_rounds"])
        assert 0 < row["cpu_ms_per_cell_frame"] <= row["cpu_ms_per_cell_frame_median"]
        # the render frame holds the colony's box and the PSF border of 50 px each side
        assert min(row["render_shape"]) > 100
    assert out["ratio"] == pytest.approx(large["ms_per_cell_frame"] / small["ms_per_cell_frame"])
    assert out["cpu_ratio"] == pytest.approx(
        large["cpu_ms_per_cell_frame"] / small["cpu_ms_per_cell_frame"]
    )


def test_measure_colony_rejects_an_empty_colony(bench):
    with pytest.raises(ValueError, match="n_cells"):
        bench.measure_colony(0)
